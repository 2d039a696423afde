// The welcome page of a served study: the link's token out of the address bar and the history (the
// cookie carries on); then, before consent, what this browser can vibrate, told to the server, which
// answers what the participant reads and whether Join stays open (the study's without_vibration).
"use strict";
history.replaceState(null, "", "/");

// An immersive session's controllers carry the actuator (`pulse`; the page checks it again in the
// session); a desktop gamepad rumbles with `playEffect` (it shows only after one of its buttons is pressed).
async function device() {
  let immersive = false;
  try {
    immersive = Boolean(navigator.xr) && await navigator.xr.isSessionSupported("immersive-vr");
  } catch (err) {
    immersive = false;   // no WebXR here (or not allowed): not a headset
  }
  const pads = navigator.getGamepads ? Array.from(navigator.getGamepads()).filter(Boolean) : [];
  const rumble = pads.some((pad) => pad.vibrationActuator && typeof pad.vibrationActuator.playEffect === "function");
  return { immersive, rumble };
}

async function check() {
  const response = await fetch("/device", {
    method: "POST", credentials: "same-origin", headers: { "Content-Type": "application/json" },
    body: JSON.stringify(await device()),
  });
  if (!response.ok) return;
  const said = await response.json();
  const note = document.getElementById("vibration");
  const join = document.getElementById("join");
  note.textContent = said.text;
  note.hidden = !said.text;
  join.disabled = said.refused;
  document.body.dataset.vibration = said.vibration;   // what was found: headset, gamepad or none
}

check();
window.addEventListener("gamepadconnected", check);
