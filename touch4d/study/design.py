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

A task's `kind:` names its class (a msgspec tagged union over every subclass of `Task`:
FrontElementTask, LookAlikesTask, TiltTask), which holds what is the kind's own: its keys, their
checks, its stimuli and their scenes, the turns a stimulus adds, whether its levels get a psychometric
fit. A new kind is one more subclass.

Scene paths are found like every path (`touch4d.configfile.resolve_path`, relative to the study
file first, then the packaged `config/`).
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, ClassVar, Generic, Literal, NamedTuple, TypeVar, Union

import msgspec

from touch4d import schema
from touch4d.configfile import COMMAND_LINE, PathNotFound, resolve_path
from touch4d.errors import ConfigError
from touch4d.geometry.rotation import PLANES, plane_axes

from .conditions import ALL_CONDITIONS, CONDITIONS

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


class Stimulus(NamedTuple):
    """A stimulus as planned: its name in tables, its level (a tilt's signed degrees; NaN for a kind
    without levels) and its correct answer."""

    name: str
    level: float
    answer: str


class Task(msgspec.Struct, forbid_unknown_fields=True, frozen=True, tag_field="kind"):
    """A task: what is asked (prompt, options) and how its stimuli vary (jitter); its `kind` is its class.

    A kind is one subclass naming its tag (`class TiltTask(Task, tag="tilt")`), the one place of what
    is its own: its keys (fields) and their checks (`__post_init__`), its stimuli (`stimulus_set`), the
    scene files behind them (`scene_files`, `scene_of`), the turns a stimulus adds (`turns`) and whether
    the analysis fits a psychometric function over its levels (`psychometric`). Study files read every
    kind defined (`task_kinds`); a class that is only a base of kinds says so (`kind_base`)."""

    id: Name
    prompt: str
    options: Annotated[list[Name], msgspec.Meta(min_length=2)]
    jitter_deg: Degrees = 0.0           # each jitter plane turned by a uniform angle in [-jitter, +jitter]
    jitter_planes: list[str] = msgspec.field(default_factory=lambda: list(PLANES))
    repetitions: Positive | None = None  # per stimulus per condition (default: the study's)
    time_limit_s: Seconds | None = None  # default: the study's

    kind_base: ClassVar[bool] = True    # not a kind itself (read from the class's own body only)
    psychometric: ClassVar[bool] = False  # its levels one signed quantity: a psychometric fit per condition

    def __post_init__(self):
        if len(set(self.options)) != len(self.options):
            raise schema.Invalid("each option once", list(self.options), "options")
        for j, plane in enumerate(self.jitter_planes):
            _check_plane(plane, f"jitter_planes[{j}]")

    @property
    def kind(self) -> str:
        """The kind's name, as study files and trial tables write it (the class's tag)."""
        return type(self).__struct_config__.tag

    def stimulus_set(self) -> list[Stimulus]:
        """The task's stimuli: name, level and correct answer of each, in the task's order."""
        raise NotImplementedError(_untold(self, "stimulus_set"))

    def scene_files(self) -> list[tuple[str, str]]:
        """(key below the task, path) of every scene file the task names, for checking them."""
        raise NotImplementedError(_untold(self, "scene_files"))

    def scene_of(self, stimulus: str) -> tuple[str, str] | None:
        """(key below the task, path) of the scene file behind the stimulus named `stimulus`; None if
        the task shows none of that name."""
        raise NotImplementedError(_untold(self, "scene_of"))

    def turns(self, level: float) -> list[list]:
        """The turns ([plane, degrees]) a stimulus of `level` adds to every object before the jitter."""
        return []

    def stimulus_names(self) -> list[str]:
        """The task's stimuli by name, in the task's order."""
        return [s.name for s in self.stimulus_set()]


class ListedTask(Task, kw_only=True):
    """The base of kinds whose stimuli a file lists, each an answer and the scene that shows it."""

    stimuli: Annotated[list[StimulusSpec], msgspec.Meta(
        min_length=2, description="at least two stimuli (answer and scene each)")]

    kind_base: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        labels = [s.label for s in self.stimuli]
        for j, stim in enumerate(self.stimuli):
            if stim.answer not in self.options:
                raise schema.Invalid(f"one of the options ({', '.join(self.options)})", stim.answer,
                                     f"stimuli[{j}].answer", choices=self.options)
            if labels.index(stim.label) != j:
                raise schema.Invalid("a stimulus name not used by an earlier stimulus (give `name:` to tell two "
                                     "of the same answer apart)", stim.label, f"stimuli[{j}].name")

    def stimulus_set(self) -> list[Stimulus]:
        return [Stimulus(s.label, math.nan, s.answer) for s in self.stimuli]

    def scene_files(self) -> list[tuple[str, str]]:
        return [(f"stimuli[{j}].scene", s.scene) for j, s in enumerate(self.stimuli)]

    def scene_of(self, stimulus: str) -> tuple[str, str] | None:
        return next(((f"stimuli[{j}].scene", s.scene) for j, s in enumerate(self.stimuli) if s.label == stimulus),
                    None)


class FrontElementTask(ListedTask, tag="front-element"):
    """Which element of an object is nearest the viewer (paper Fig. 19): a face, an edge or a vertex."""


class LookAlikesTask(ListedTask, tag="look-alikes"):
    """Objects that look alike from the front, told apart (paper Fig. 20-21): convex, flat or concave."""


class TiltTask(Task, tag="tilt", kw_only=True):
    """Which way the front cell is tilted (paper Fig. 18): one scene turned in `plane` by each of
    `angles_deg`, each with both signs; a positive angle answers `positive`, a negative one the other
    option. Its levels are one signed quantity, so the analysis fits a psychometric function."""

    options: Annotated[list[Name], msgspec.Meta(
        min_length=2, max_length=2, description="two options for a tilt task (a two-alternative choice)")]
    scene: Annotated[str, msgspec.Meta(description="the untilted scene of a tilt task (a scene file)")]
    plane: str = "xw"
    angles_deg: Annotated[list[Tilt], msgspec.Meta(
        min_length=1, description="a non-empty list of tilt angles in degrees (each shown with both signs)")]
    positive: str | None = None         # the option a positive angle answers (default: the first)

    psychometric: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        if len(set(self.angles_deg)) != len(self.angles_deg):
            raise schema.Invalid("each angle once", list(self.angles_deg), "angles_deg")
        _check_plane(self.plane, "plane")
        if self.positive is not None and self.positive not in self.options:
            raise schema.Invalid(f"one of the options ({', '.join(self.options)})", self.positive, "positive",
                                 choices=self.options)

    def levels(self) -> list[float]:
        """The signed tilt levels (degrees), in stimulus order: -largest .. -smallest, +smallest .. +largest."""
        return [-a for a in sorted(self.angles_deg, reverse=True)] + sorted(self.angles_deg)

    def answer_of(self, level: float) -> str:
        """The correct option for a signed tilt level."""
        positive = self.positive or self.options[0]
        negative = next(o for o in self.options if o != positive)
        return positive if level > 0 else negative

    def stimulus_set(self) -> list[Stimulus]:
        return [Stimulus(tilt_name(level), float(level), self.answer_of(level)) for level in self.levels()]

    def scene_files(self) -> list[tuple[str, str]]:
        return [("scene", self.scene)]

    def scene_of(self, stimulus: str) -> tuple[str, str] | None:
        return ("scene", self.scene)    # any stimulus: its level is the turn

    def turns(self, level: float) -> list[list]:
        return [] if math.isnan(level) else [[self.plane, float(level)]]


def tilt_name(level: float) -> str:
    """The stimulus name of a signed tilt level: tilt+8, tilt-2.5."""
    return f"tilt{level:+g}"


def _check_plane(plane: str, key: str) -> None:
    """Refuse (schema.Invalid at `key`) what is not a rotation plane."""
    try:
        plane_axes(plane)
    except ValueError:
        raise schema.Invalid("a rotation plane (two of x, y, z, w)", plane, key, choices=PLANES) from None


KIND_METHODS = ("stimulus_set", "scene_files", "scene_of")   # what every kind says of itself


def _untold(task, method: str) -> str:
    return (f"task kind {type(task).__name__} defines no {method} (every kind defines "
            f"{', '.join(KIND_METHODS)}: docs/code-map.md, \"A study's task kind\")")


def task_kinds() -> dict[str, type[Task]]:
    """Every task kind defined, by name: the subclasses of Task below it (those not `kind_base`), in the
    order their classes were defined (a base's kinds in its place). A kind that does not define
    KIND_METHODS is a TypeError naming it and them, before any study file is read with it."""
    out: dict[str, type[Task]] = {}

    def walk(cls):
        for sub in cls.__subclasses__():
            if not vars(sub).get("kind_base"):
                missing = [m for m in KIND_METHODS if getattr(sub, m) is getattr(Task, m)]
                if missing:
                    raise TypeError(f"task kind {sub.__name__} ({sub.__struct_config__.tag!r}) defines no "
                                    f"{', '.join(missing)}: every kind defines {', '.join(KIND_METHODS)} "
                                    "(docs/code-map.md, \"A study's task kind\")")
                out[sub.__struct_config__.tag] = sub
            walk(sub)

    walk(Task)
    return out


def kind_class(name: str) -> type[Task] | None:
    """The class of the kind named `name` (as a trial table writes it), or None for one not defined."""
    return task_kinds().get(name)


TaskT = TypeVar("TaskT", bound=Task)


class DeviceCheck(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    """The welcome page's device check before consent (`touch4d study serve`): `trials` vibrations at
    random times and `catch` trials without one, each answered felt or not felt; a device passes with
    at least `min_hits` felt vibrations, at most `max_false_alarms` catch trials said felt, and its
    frame rate at least `min_fps`."""

    trials: Positive = 8
    catch: Count = 4
    min_hits: Count = 6
    max_false_alarms: Count = 1
    min_fps: Annotated[float, msgspec.Meta(ge=0, description="frames per second, >= 0")] = 45.0

    def __post_init__(self):
        if self.min_hits > self.trials:
            raise schema.Invalid(f"at most trials ({self.trials})", self.min_hits, "min_hits")
        if self.max_false_alarms > self.catch:
            raise schema.Invalid(f"at most catch ({self.catch})", self.max_false_alarms, "max_false_alarms")



class Study(msgspec.Struct, Generic[TaskT], forbid_unknown_fields=True, frozen=True, dict=True):
    """A study file. `path` (set by `load_study`) is the file it came from, for errors and paths. Read
    as `Study[kinds]` (`parse_study`), its tasks each of the kind their `kind:` names."""

    name: Name
    tasks: Annotated[list[TaskT], msgspec.Meta(min_length=1)]
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
    # The welcome page's vibration test and frame rate before consent (DeviceCheck); None: none.
    device_check: DeviceCheck | None = None

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
    kinds = tuple(task_kinds().values())
    study = schema.convert(data, Study[Union[kinds]], file)
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
    """What no type expresses across tasks (each kind checks its own keys: `Task.__post_init__`): unique
    ids and conditions, and every scene file a task names readable as a scene."""
    from touch4d.geometry.scene import load_scene

    if len(set(study.conditions)) != len(study.conditions):
        schema.fail(file, "conditions", "each condition once", got=list(study.conditions))
    ids = [t.id for t in study.tasks]
    for i, task in enumerate(study.tasks):
        if ids.index(task.id) != i:
            schema.fail(file, f"tasks[{i}].id", "a task id not used by an earlier task", got=task.id)
        for key, path in task.scene_files():
            load_scene(scene_path(study, f"tasks[{i}].{key}", path))
