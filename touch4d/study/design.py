"""Study files (config/studies/*.yaml): tasks, their stimuli and response options, conditions,
repetitions, practice, breaks, time limits, the run constraint and the study's seed.

Declared once as msgspec Structs and read with `touch4d.schema`, so a mistake is a ConfigError
naming the file, the key path, what was expected and what was there, as for a scene file::

    name: paper
    conditions: [visual, touch, visual+touch]   # each may name a view: slice-visual, both-touch, ...
    counterbalance: all          # all orders (default while there are <= 6), or latin
    repetitions: 4               # per stimulus per condition
    practice: 3                  # flagged trials at the start of each block
    break_every: 24              # a pause offered every 24 trials
    time_limit_s: 20
    max_run: 3                   # never more than 3 trials in a row with the same correct answer
    seed: 20260101
    tasks:
      - id: front
        kind: front-element
        prompt: What is in front?
        options: [face, edge, vertex]
        jitter_deg: 3
        stimuli:
          - {answer: face, scene: config/scenes/hypercube-face.yaml}
      - id: tilt
        kind: tilt
        prompt: Which way is the front cell tilted?
        options: [left, right]
        scene: config/scenes/hypercube.yaml
        plane: xw
        angles_deg: [2, 4, 8, 16]     # each with both signs: +a answers `positive`, -a the other
        positive: right

Scene paths are found like every path (`touch4d.configfile.resolve_path`, relative to the study
file first, then the packaged `config/`).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import msgspec

from touch4d import schema
from touch4d.configfile import COMMAND_LINE, PathNotFound, resolve_path
from touch4d.errors import ConfigError
from touch4d.geometry.rotation import PLANES, plane_axes

from .conditions import ALL_CONDITIONS, CONDITIONS

KINDS = ("front-element", "look-alikes", "tilt")
STUDIES = "config/studies"                  # where a study named by its bare name lives
DEFAULT_STUDY = f"{STUDIES}/paper.yaml"
ALL_ORDERS_UP_TO = 6          # counterbalance: all orders while n! <= this, else a balanced Latin square

Name = Annotated[str, msgspec.Meta(min_length=1, pattern=r"^[A-Za-z0-9_.+-]+$",
                                    description="a name of letters, digits and _ . + - (no spaces)")]
Count = Annotated[int, msgspec.Meta(ge=0, description="an integer >= 0")]
Positive = Annotated[int, msgspec.Meta(ge=1, description="an integer >= 1")]
Seconds = schema.Positive
Degrees = Annotated[float, msgspec.Meta(ge=0, le=45, description="an angle in degrees, 0..45")]
Tilt = Annotated[float, msgspec.Meta(gt=0, le=45, description="an angle in degrees, > 0 and <= 45")]


class StimulusSpec(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """One stimulus of a task: its correct answer and the scene that shows it."""

    answer: str
    scene: str
    name: Name | None = None            # the stimulus's name in tables (default: the answer)

    @property
    def label(self) -> str:
        return self.name or self.answer


class Task(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """A task: what is asked (prompt, options), how the stimuli vary (jitter), and its stimuli: listed
    (front-element, look-alikes) or generated from angles (tilt)."""

    id: Name
    kind: Literal["front-element", "look-alikes", "tilt"]
    prompt: str
    options: Annotated[list[Name], msgspec.Meta(min_length=2)]
    stimuli: list[StimulusSpec] = []
    jitter_deg: Degrees = 0.0           # each jitter plane turned by a uniform angle in [-jitter, +jitter]
    jitter_planes: list[str] = msgspec.field(default_factory=lambda: list(PLANES))
    repetitions: Positive | None = None  # per stimulus per condition (default: the study's)
    time_limit_s: Seconds | None = None  # default: the study's
    # tilt only: the untilted scene, the plane of the tilt, the angles (each shown with both signs)
    # and the option that a positive angle answers (the other option answers a negative one)
    scene: str | None = None
    plane: str = "xw"
    angles_deg: list[Tilt] = []
    positive: str | None = None

    def stimulus_names(self) -> list[str]:
        """The task's stimuli by name, in file order (tilt: -largest .. -smallest, +smallest .. +largest)."""
        if self.kind == "tilt":
            return [tilt_name(-a) for a in sorted(self.angles_deg, reverse=True)] + \
                   [tilt_name(a) for a in sorted(self.angles_deg)]
        return [s.label for s in self.stimuli]

    def levels(self) -> list[float]:
        """The signed tilt levels (degrees) of a tilt task, in stimulus order; [] otherwise."""
        if self.kind != "tilt":
            return []
        return [-a for a in sorted(self.angles_deg, reverse=True)] + sorted(self.angles_deg)

    def answer_of(self, level: float) -> str:
        """The correct option for a signed tilt level."""
        positive = self.positive or self.options[0]
        negative = next(o for o in self.options if o != positive)
        return positive if level > 0 else negative


class Study(msgspec.Struct, forbid_unknown_fields=True, frozen=True, dict=True):
    """A study file. `path` (set by `load_study`) is the file it came from, for errors and paths."""

    name: Name
    tasks: Annotated[list[Task], msgspec.Meta(min_length=1)]
    description: str = ""
    conditions: Annotated[list[Literal[ALL_CONDITIONS]], msgspec.Meta(min_length=1)] = \
        msgspec.field(default_factory=lambda: list(CONDITIONS))
    counterbalance: Literal["latin", "all"] | None = None
    repetitions: Positive = 1
    practice: Count = 0
    break_every: Count = 0              # 0: no breaks but between blocks (none with < break_every/2 left)
    time_limit_s: Seconds = 30.0
    max_run: Positive = 3
    seed: Annotated[int, msgspec.Meta(ge=0, description="an integer >= 0")] = 0
    # What a participant who joins by a link reads first (`touch4d study serve`): the consent they
    # give by joining, and how to take part. Plain text; blank lines separate paragraphs.
    consent: str = ""
    instructions: str = ""
    # A joining browser that cannot vibrate (no immersive session, no gamepad rumble; the welcome page
    # checks before consent): `refuse` it with a page that says why, or `allow` it (its touch trials
    # are then felt by no one: for studies where touch is not what is measured). Either way the
    # experimenter's page shows what each participant's browser could do.
    without_vibration: Literal["refuse", "allow"] = "refuse"

    @property
    def path(self) -> str:
        return self.__dict__.get("_path", "<input>")

    def task(self, task_id: str) -> Task:
        for task in self.tasks:
            if task.id == task_id:
                return task
        schema.fail(self.path, "tasks", f"a task with id {task_id!r}", got=task_id,
                    choices=[t.id for t in self.tasks])

    def counterbalancing(self) -> str:
        """`all` or `latin`: the file's choice, else all orders when there are few."""
        if self.counterbalance:
            return self.counterbalance
        return "all" if math.factorial(len(self.conditions)) <= ALL_ORDERS_UP_TO else "latin"

    def repetitions_of(self, task: Task) -> int:
        return task.repetitions or self.repetitions

    def time_limit_of(self, task: Task) -> float:
        return task.time_limit_s or self.time_limit_s


def replace_study(study: Study, **fields) -> Study:
    """A copy of `study` with some fields replaced, still knowing its file (for paths and errors)."""
    out = msgspec.structs.replace(study, **fields)
    out.__dict__["_path"] = study.path
    return out


def tilt_name(level: float) -> str:
    """The stimulus name of a signed tilt level: tilt+8, tilt-2.5."""
    return f"tilt{level:+g}"


def study_file_path(name, named_in=COMMAND_LINE, *, key: str = "STUDY") -> Path:
    """The study file a user named: a path, or a bare name such as `paper` for
    `config/studies/paper.yaml` (a path wins when it exists; the name is then found like any path,
    yours first, else the packaged one), as `touch4d launch demo` finds launch/demo.yaml. The one
    place a study's name becomes its file: every command and node that takes a study goes through it."""
    given = Path(name) if isinstance(name, (str, Path)) else None
    if given is not None and len(given.parts) == 1 and not given.suffix and not given.exists():
        try:
            return resolve_path(f"{STUDIES}/{name}.yaml", named_in, key=key, what="study file")
        except PathNotFound as exc:
            near = [Path(n).stem for n in exc.near]
            raise ConfigError(named_in, key, f"a study file: a path, or the name of one in {STUDIES}/ "
                              f"({', '.join(study_names()) or 'none found'})", got=name, detail=exc.detail,
                              hint=f"did you mean {' or '.join(repr(n) for n in near)}?" if near else None) from None
    return resolve_path(name, named_in, key=key, what="study file")


def study_names() -> list[str]:
    """The bare names `touch4d study run NAME` takes: config/studies/*.yaml here and packaged."""
    from touch4d.defaults import ROOT

    return sorted({p.stem for folder in (Path(STUDIES), ROOT / STUDIES) if folder.is_dir()
                   for p in folder.glob("*.yaml")})


def load_study(path=None, named_in=COMMAND_LINE, *, key: str = "STUDY") -> Study:
    """Read and check a study file (default: the paper's study): a path or a packaged study's name,
    found by `study_file_path` (`named_in`, `key`: who named it, for errors)."""
    path = study_file_path(path if path is not None else DEFAULT_STUDY, named_in, key=key)
    return parse_study(schema.read_yaml(path, "study file"), path)


def parse_study(data, file=None) -> Study:
    """A Study from the parsed YAML `data`; every problem a ConfigError naming `file` and the key."""
    study = schema.convert(data, Study, file)
    study.__dict__["_path"] = str(file) if file is not None else "<input>"
    _check(study, file)
    return _fill_texts(study)


# What a participant reads (consent, instructions) may name figures the plan decides; written as these
# placeholders they are filled from the plan when the file is read, so the text cannot disagree with it.
PLACEHOLDERS = ("{minutes}", "{answers}")


def session_minutes(study: Study) -> int:
    """A session's minutes at most, breaks aside: every trial at its time limit (each stimulus
    `repetitions` times per condition, and `practice` trials a block at the longest limit, since
    they are drawn from any task): `study check`'s estimate and a consent text's `{minutes}`."""
    main = sum(len(t.stimulus_names()) * study.repetitions_of(t) * study.time_limit_of(t) for t in study.tasks)
    practice = study.practice * max(study.time_limit_of(t) for t in study.tasks)
    return round(len(study.conditions) * (main + practice) / 60)


def answers_text(study: Study) -> str:
    """Each task's options as a participant reads them, `{answers}`: face, edge or vertex; left or right."""
    return "; ".join(", ".join(t.options[:-1]) + " or " + t.options[-1] for t in study.tasks)


def _fill_texts(study: Study) -> Study:
    """The study with PLACEHOLDERS in its consent and instructions replaced by the plan's figures."""
    if not any(p in study.consent or p in study.instructions for p in PLACEHOLDERS):
        return study
    values = {"{minutes}": str(session_minutes(study)), "{answers}": answers_text(study)}

    def fill(text: str) -> str:
        for key, value in values.items():
            text = text.replace(key, value)
        return text

    return replace_study(study, consent=fill(study.consent), instructions=fill(study.instructions))


def study_text_warnings(study: Study) -> list[str]:
    """What a participant would read wrong: a consent or instructions that name a number of minutes
    other than `session_minutes`, or fewer answer buttons (`the A and B buttons`) than a task has
    options. `study check` prints them; the fix is the placeholders (PLACEHOLDERS)."""
    import re

    out = []
    minutes = session_minutes(study)
    for key in ("consent", "instructions"):
        for said in re.finditer(r"\b(\d+)\s*(?:minutes|min)\b", getattr(study, key)):
            if int(said.group(1)) != minutes:
                out.append(f"{study.path}: {key} says '{said.group(0)}', a session's trials take at most {minutes} "
                           "minutes (each at its time limit): write {minutes} to have the figure filled in")
    widest = max(study.tasks, key=lambda t: len(t.options))
    for said in re.finditer(r"((?:\w+(?:, | and | or ))+\w+) buttons", study.instructions):
        named = re.split(r", | and | or ", said.group(1))
        if len(named) < len(widest.options):
            out.append(f"{study.path}: instructions name {len(named)} answer buttons ('{said.group(0)}'), task "
                       f"{widest.id} has {len(widest.options)} options ({', '.join(widest.options)}): name as many, "
                       "or write {answers} for each task's options")
    return out


def scene_path(study: Study, key: str, path: str) -> Path:
    """The file a study names at `key` (relative to the study file first)."""
    named_in = Path(study.path) if study.path != "<input>" else None
    return resolve_path(path, named_in, key=key, what="scene file")


def _check(study: Study, file) -> None:
    """What no type expresses: unique ids and conditions, answers among options, a tilt's generator."""
    from touch4d.geometry.scene import load_scene

    if len(set(study.conditions)) != len(study.conditions):
        schema.fail(file, "conditions", "each condition once", got=list(study.conditions))
    ids = [t.id for t in study.tasks]
    for i, task in enumerate(study.tasks):
        key = f"tasks[{i}]"
        if ids.index(task.id) != i:
            schema.fail(file, f"{key}.id", "a task id not used by an earlier task", got=task.id)
        if len(set(task.options)) != len(task.options):
            schema.fail(file, f"{key}.options", "each option once", got=list(task.options))
        for j, plane in enumerate(task.jitter_planes):
            try:
                plane_axes(plane)
            except ValueError:
                schema.fail(file, f"{key}.jitter_planes[{j}]", "a rotation plane (two of x, y, z, w)", got=plane,
                            choices=PLANES)
        if task.kind == "tilt":
            for name in ("stimuli",):
                if getattr(task, name):
                    schema.fail(file, f"{key}.{name}", "no listed stimuli for a tilt task (it makes them from "
                                "scene, plane and angles_deg)", got="a list")
            if task.scene is None:
                schema.fail(file, f"{key}.scene", "the untilted scene of a tilt task (a scene file)")
            if not task.angles_deg:
                schema.fail(file, f"{key}.angles_deg", "a non-empty list of tilt angles in degrees (each shown "
                            "with both signs)")
            if len(set(task.angles_deg)) != len(task.angles_deg):
                schema.fail(file, f"{key}.angles_deg", "each angle once", got=list(task.angles_deg))
            if len(task.options) != 2:
                schema.fail(file, f"{key}.options", "two options for a tilt task (a two-alternative choice)",
                            got=list(task.options))
            try:
                plane_axes(task.plane)
            except ValueError:
                schema.fail(file, f"{key}.plane", "a rotation plane (two of x, y, z, w)", got=task.plane,
                            choices=PLANES)
            if task.positive is not None and task.positive not in task.options:
                schema.fail(file, f"{key}.positive", f"one of the options ({', '.join(task.options)})",
                            got=task.positive, choices=task.options)
            load_scene(scene_path(study, f"{key}.scene", task.scene))
            continue
        for name in ("scene", "angles_deg", "positive"):
            if getattr(task, name):
                schema.fail(file, f"{key}.{name}", f"no {name} for a {task.kind} task (tilt tasks only)",
                            got=getattr(task, name))
        if len(task.stimuli) < 2:
            schema.fail(file, f"{key}.stimuli", "at least two stimuli (answer and scene each)",
                        got=len(task.stimuli))
        labels = [s.label for s in task.stimuli]
        for j, stim in enumerate(task.stimuli):
            if stim.answer not in task.options:
                schema.fail(file, f"{key}.stimuli[{j}].answer", f"one of the options ({', '.join(task.options)})",
                            got=stim.answer, choices=task.options)
            if labels.index(stim.label) != j:
                schema.fail(file, f"{key}.stimuli[{j}].name", "a stimulus name not used by an earlier stimulus "
                            "(give `name:` to tell two of the same answer apart)", got=stim.label)
            load_scene(scene_path(study, f"{key}.stimuli[{j}].scene", stim.scene))
