// The lesson's page (touch4d.web.lesson): the WebXR page (main.js, which touches and pulses on its own)
// and, over it, the lesson's panel: a student's name, their own slice and view (unless the teacher
// locks them); the teacher's commands and the class (who is connected, with what haptics, who touches
// what; a student's hand in the spotlight, a student driving). It hears the node's frames through
// main.js's hook and sends through its link.

import { hooks } from './main.js';

const SLICE_STEP = 0.05;    // w per press, as the scene's own slice up / down (touch4d.tracking.scene_control)
const VIEWS = ['projection', 'slice', 'both'];
const panel = document.getElementById('lesson');

// What tests read (window.touch4d.lesson); the functions are what the panel's buttons do.
const lesson = (window.touch4d.lesson = {
  role: null, name: '', locked: false, driver: 'teacher', spotlight: null, own: { view: null, slice: null }, roster: [],
  results: [], lessonFrames: 0,
  arrived: {},   // scene revision -> when its first frame arrived (page clock, ms since the epoch)
  // a student's own slice and view (null: the class's); refused while locked
  setOwn(view, slice) { hooks.send({ type: 'own', view, slice }); },
  moveSlice(step) {
    const f = window.touch4d.frame;
    const w = (lesson.own.slice ?? (f ? f.slice_w : 0)) + step;
    lesson.setOwn(lesson.own.view ?? (f && f.view !== 'projection' ? f.view : 'slice'), Math.round(w * 1000) / 1000);
  },
  nextView() {
    const f = window.touch4d.frame;
    const now = lesson.own.view ?? (f ? f.view : 'projection');
    lesson.setOwn(VIEWS[(VIEWS.indexOf(now) + 1) % VIEWS.length], lesson.own.slice);
  },
  follow() { lesson.setOwn(null, null); },
  hello(name) { hooks.send({ type: 'hello', name }); },
  command(verb, argument = '') { hooks.send({ type: 'command', verb, argument }); },
});

function el(tag, text, attrs = {}) {
  const node = document.createElement(tag);
  if (text !== undefined) node.textContent = text;
  Object.assign(node, attrs);
  return node;
}

function button(text, action) {
  const b = el('button', text);
  b.addEventListener('click', action);
  return b;
}

const info = el('div');
const controls = el('div', undefined, { className: 'row' });
const classList = el('table');

function studentControls() {
  const name = el('input', undefined, { placeholder: 'your name (optional)', maxLength: 32 });
  controls.replaceChildren(name, button('set name', () => lesson.hello(name.value)),
                           button('slice −', () => lesson.moveSlice(-SLICE_STEP)),
                           button('slice +', () => lesson.moveSlice(SLICE_STEP)),
                           button('view', () => lesson.nextView()), button('follow the class', () => lesson.follow()));
}

function teacherControls() {
  const c = (verb, argument) => () => lesson.command(verb, argument);
  controls.replaceChildren(button('next object', c('next')), button('view', c('view', 'next')),
                           button('slice −', c('slice', 'down')), button('slice +', c('slice', 'up')),
                           button('turn xw 15°', c('rotate', 'xw 15')), button('reset', c('reset')),
                           button('lock', c('lock')), button('unlock', c('unlock')), button('drive', c('drive', 'teacher')));
}

function showRoster() {
  const head = el('tr');
  for (const title of ['who', 'haptics', 'touches', 'own view', '']) head.append(el('th', title));
  const rows = lesson.roster.map((m) => {
    const row = el('tr', undefined, { className: m.touching ? 'touching' : '' });
    const own = m.view || m.slice !== null ? `${m.view || ''} ${m.slice ?? ''}`.trim() : '';
    row.append(el('td', `${m.name}${m.role === 'teacher' ? ' (teacher)' : ''}`), el('td', m.haptics),
               el('td', m.touching ? `${m.near} (${m.level})` : m.tracking ? '—' : 'no hand'), el('td', own));
    if (m.role === 'student') {
      const lit = lesson.spotlight === m.name;
      row.append(el('td', undefined), el('td', undefined));
      row.lastChild.append(button(lit ? 'spotlight off' : 'spotlight', () => lesson.command('spotlight', lit ? 'off' : m.name)),
                           button('drive', () => lesson.command('drive', m.name)));
    }
    return row;
  });
  classList.replaceChildren(head, ...rows);
}

function show() {
  const who = lesson.role === 'teacher' ? 'teacher' : `student · ${lesson.name}`;
  const lock = lesson.locked ? ' · the teacher shows everyone the same view' : '';
  const lit = lesson.spotlight ? ` · ${lesson.spotlight}'s hand in the spotlight` : '';
  info.textContent = `lesson · ${who} · ${lesson.driver} turns the object${lock}${lit}`;
  if (lesson.role === 'student') {
    for (const b of controls.querySelectorAll('button')) if (b.textContent !== 'set name') b.disabled = lesson.locked;
  }
}

hooks.frames.push(({ header }) => {
  if (header.kind === 'frame' && header.revision !== undefined && !(header.revision in lesson.arrived)) {
    lesson.arrived[header.revision] = performance.timeOrigin + performance.now();
  } else if (header.kind === 'lesson') {
    const first = lesson.role === null || lesson.role !== header.role;
    Object.assign(lesson, { role: header.role, name: header.name, locked: header.locked, driver: header.driver,
                            spotlight: header.spotlight, own: header.own, roster: header.roster || [] });
    lesson.lessonFrames++;
    if (first) {
      if (header.role === 'teacher') teacherControls();
      else studentControls();
      panel.replaceChildren(info, controls, classList);
    }
    if (header.role === 'teacher') showRoster();
    show();
  } else if (header.kind === 'result') {
    lesson.results.push({ ok: header.ok, text: header.text });
    info.title = header.text;
  }
});

document.addEventListener('keydown', (event) => {
  if (lesson.role !== 'student' || event.target instanceof HTMLInputElement) return;
  if (event.key === '[') lesson.moveSlice(-SLICE_STEP);
  else if (event.key === ']') lesson.moveSlice(SLICE_STEP);
  else if (event.key === 'v') lesson.nextView();
});
