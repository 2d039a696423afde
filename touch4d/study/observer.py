"""Model observers: simulated participants that answer from what they receive.

Touch: the glove's motor pattern (paper eq. 1-3, computed by `touch4d.tactile.compute_stimulus`) at
each hand position its scripted hand visits, plus Gaussian sensory noise on every motor, in units of
full drive: `noise` (the fingertip's) on a finger, noise x `THENAR_RATIO` on the palm's side of the
palm, whose skin discriminates finer, and `noise` elsewhere (`psychophysics.motor_noise`; training
and trials alike). Vision: the projected geometry, i.e. what the view shows: which points of the
3D screen the object's projection covers, on a grid, plus noise (`visual_noise`). The view does not
show how far each point lies in w, which is the depth the paper adds by touch. In a slice view the
observer moves the slice through the object and sees, at each c it explores (`SLICE_OFFSETS` about
the scene's slice_w), which grid points the cross-section covers; with touch it presses the section
at slice_w (the scene's slice_touch). Its cues are trained per view.

Per task the observer is trained once, on stimuli with the task's jitter and hand positions drawn
at random, with scikit-learn's linear discriminant analysis (a shrinkage covariance keeps 247
motors as well conditioned as 30), its posteriors tempered on held-out scenes so that a cue that
cannot tell the options apart adds nothing. On a trial it adds the log posteriors of every pattern
it felt and of the view it saw (independent cues, uniform prior) and answers the best option; with
probability `lapse` it answers at random instead.

`explore(trial, rng)` gives the positions of the scripted hand (screen units); `respond(trial,
patterns, scene, rng)` the answer, where `patterns` is None in the visual condition (motors held
off) and `scene` None in the touch condition (nothing drawn). Where it feels a vibration
(`localisation_mm`, `localisation()`) is set from the palm's published localisation
(`psychophysics`); identifying a stimulus does not need it, the motors' places being known.
"""
from __future__ import annotations

import copy
import hashlib
from dataclasses import dataclass, replace

import numpy as np
from scipy.special import log_softmax

from touch4d.errors import ConfigError, Unavailable
from touch4d.geometry.raycast import RayCaster
from touch4d.geometry.scene import Scene
from touch4d.geometry.section import SectionCaster
from touch4d.tactile import Glove, compute_stimulus

from .conditions import split_condition
from .design import Study, Task
from .plan import Trial, draw_jitter, stimuli_of
from .psychophysics import HUMAN_NOISE, LOCALISATION_MM, motor_noise, vibration_localisation
from .stimuli import in_view, stimulus_scene

FACING = np.array([0.0, 0.0, 0.0, 1.0])   # the hand's identity pose: palm toward -z, fingers up (+y)
VIEW_GRID = 7                               # the view as a 7^3 grid of screen points (1/3 unit apart)
SLICE_OFFSETS = (-0.3, -0.15, 0.0, 0.15, 0.3)   # where a slice observer cuts, about the scene's slice_w (w)


def every_sample_glove(glove: Glove) -> Glove:
    """`glove` with a motor at every one of its sample points (the tactile model only: the CAN layout
    is nominal, eight motors a board): the finest actuator resolution its samples allow (paper §7)."""
    n = len(glove.samples)
    index = np.arange(n)
    return replace(glove, path=f"{glove.path} (a motor at every sample)",
                   motor_names=[f"sample-{i}" for i in index], motor_positions=glove.samples.copy(),
                   motor_sample=index, motor_board=1 + index // 8, motor_channel=index % 8,
                   motor_weights=None)


@dataclass
class Exploration:
    """How the scripted hand explores: `touches` positions, uniform in a box of half-size `reach`
    (screen units) around `centre`, the palm facing the screen (the time it takes is the
    simulation's `Timing`)."""

    touches: int = 6
    reach: tuple[float, float, float] = (0.25, 0.25, 0.3)
    centre: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def positions(self, rng: np.random.Generator, count: int | None = None) -> np.ndarray:
        count = self.touches if count is None else count
        return np.asarray(self.centre) + rng.uniform(-1.0, 1.0, (count, 3)) * np.asarray(self.reach)


def patterns_at(glove: Glove, scene: Scene, positions: np.ndarray, caster=None) -> np.ndarray:
    """The motor intensities (K, M) with the hand at each of `positions` (K, 3), facing the screen."""
    caster = scene.ray_caster() if caster is None else caster
    return np.array([compute_stimulus(glove, caster, p, FACING).V for p in positions])


def view_features(scene: Scene, caster=None, grid: int = VIEW_GRID) -> np.ndarray:
    """What the view shows: 1 where the object's projection covers a screen point of a grid^3 grid, else
    0; in a slice view the same for its cross-section at each c the observer explores (both: the two)."""
    axis = np.linspace(-1.0, 1.0, grid)
    points = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1).reshape(-1, 3)
    seen = []
    if scene.view != "slice":
        projection = RayCaster(scene.world_parts(), scene.perspective_eye) if caster is None else caster
        seen.append(np.isfinite(projection.cast(points)[0]))
    if scene.view != "projection":
        parts = scene.world_parts()
        for offset in SLICE_OFFSETS:
            section = SectionCaster(parts, scene.slice_w + offset, scene.perspective_eye)
            seen.append(section.cast(points)[1] >= 0)
    return np.concatenate(seen).astype(float)


def touch_examples(glove: Glove, study: Study, task: Task, rng: np.random.Generator, *, scenes: int,
                   positions: int, exploration: Exploration | None = None, view: str = "projection"
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free motor patterns of a task's stimuli in `view`, `scenes` jittered versions each, the hand
    at `positions` random places on each: (patterns (S*scenes*positions, M), stimulus index per row,
    scene number per row)."""
    exploration = exploration or Exploration()
    rows, labels, groups = [], [], []
    for k, (name, level, _) in enumerate(stimuli_of(task)):
        for j in range(scenes):
            scene = in_view(stimulus_scene(study, task.id, name, level, draw_jitter(task, rng)), view)
            rows.append(patterns_at(glove, scene, exploration.positions(rng, positions)))
            labels.append(np.full(positions, k))
            groups.append(np.full(positions, j))
    return np.vstack(rows), np.concatenate(labels), np.concatenate(groups)


def view_examples(study: Study, task: Task, rng: np.random.Generator, *, scenes: int, view: str = "projection"
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Noise-free view features of a task's stimuli in `view`, `scenes` jittered versions each:
    (features, stimulus index, scene number) per row."""
    rows, labels, groups = [], [], []
    for k, (name, level, _) in enumerate(stimuli_of(task)):
        for j in range(scenes):
            scene = in_view(stimulus_scene(study, task.id, name, level, draw_jitter(task, rng)), view)
            rows.append(view_features(scene))
            labels.append(k)
            groups.append(j)
    return np.array(rows), np.array(labels), np.array(groups)


def classifier():
    """The observer's learner: LDA with Ledoit-Wolf shrinkage (a standard, well-conditioned linear rule)."""
    try:
        from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
    except ImportError:
        raise Unavailable("model observers need scikit-learn: pip install 'touch4d[study]'") from None
    return LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto")


class _Cue:
    """One trained cue (touch or view) of one task: a classifier over the task's options, its log
    posteriors divided by a temperature fitted on held-out examples (temperature scaling, Guo et al.
    2017), so that a cue that cannot tell the options apart says so (near-uniform posteriors) instead
    of adding confident noise to the other cue."""

    def __init__(self, features: np.ndarray, answers: np.ndarray, groups: np.ndarray, options: list[str],
                 setting: str = "train_scenes"):
        from scipy.optimize import minimize_scalar

        classes = len(np.unique(answers))

        def fits(rows: np.ndarray) -> bool:           # LDA needs every answer and more examples than answers
            return rows.sum() > classes and len(np.unique(answers[rows])) == classes

        held = groups % 3 == 0                        # every third scene is held out for the temperature
        if not held.any() or not fits(~held):
            held = np.zeros(len(answers), bool)
        if not fits(~held):
            raise ConfigError("model observer", setting, f"enough scenes for more training examples than the "
                              f"{classes} answers", got=f"{len(answers)} examples")
        fit = classifier().fit(features[~held], answers[~held])
        self.temperature = 1.0
        if held.any():
            logp = fit.predict_log_proba(features[held])
            truth = np.searchsorted(fit.classes_, answers[held])

            def loss(log_t):
                z = log_softmax(logp / np.exp(log_t), axis=1)
                return -float(np.mean(z[np.arange(len(z)), truth]))

            self.temperature = float(np.exp(minimize_scalar(loss, bounds=(-3.0, 7.0), method="bounded").x))
        self.model = classifier().fit(features, answers)
        self.columns = [list(self.model.classes_).index(o) if o in self.model.classes_ else None for o in options]

    def log_posterior(self, features: np.ndarray) -> np.ndarray:
        """Summed (tempered) log posterior of each option over the rows of `features` (K, D)."""
        return self.log_posteriors(np.atleast_2d(features)[None])[0]

    def log_posteriors(self, features: np.ndarray) -> np.ndarray:
        """`log_posterior` of each of B trials at once: features (B, K, D) -> (B, options)."""
        b, k, d = features.shape
        z = log_softmax(self.model.predict_log_proba(features.reshape(b * k, d)) / self.temperature, axis=1)
        total = z.reshape(b, k, -1).sum(axis=1)
        missing = np.full((b, 1), -np.inf)
        return np.hstack([total[:, [c]] if c is not None else missing for c in self.columns])


class ModelObserver:
    """A simulated participant for a study and a glove (see the module's docstring)."""

    def __init__(self, glove: Glove, study: Study, *, noise: float = HUMAN_NOISE, visual_noise: float = 0.5,
                 lapse: float = 0.03, seed: int = 0, exploration: Exploration | None = None,
                 train_scenes: int = 12, train_positions: int = 20, view_scenes: int = 30,
                 localisation_mm: float = LOCALISATION_MM):
        for key, value, ok in (("noise", noise, noise >= 0), ("visual_noise", visual_noise, visual_noise >= 0),
                               ("localisation_mm", localisation_mm, localisation_mm >= 0),
                               ("lapse", lapse, 0 <= lapse <= 1)):
            if not ok:
                raise ConfigError("model observer", key, "a number in 0..1" if key == "lapse" else "a number >= 0",
                                  got=value)
        self.glove, self.study = glove, study
        self.noise, self.visual_noise, self.lapse = float(noise), float(visual_noise), float(lapse)
        self.localisation_mm = float(localisation_mm)   # where a vibration is felt (psychophysics)
        self._skin = motor_noise(glove, 1.0)             # each motor's noise over the fingertip's
        self.exploration = exploration or Exploration()
        self.train_scenes, self.train_positions, self.view_scenes = train_scenes, train_positions, view_scenes
        self.seed = int(seed)
        self._touch: dict[tuple[str, str], _Cue] = {}     # by (task, view)
        self._view: dict[tuple[str, str], _Cue] = {}

    # -- what the node (or the offline simulation) calls --------------------------------------------

    def explore(self, trial: Trial, rng: np.random.Generator) -> np.ndarray:
        """The hand positions (K, 3), screen units, the scripted hand visits in a trial."""
        return self.exploration.positions(rng)

    def respond(self, trial: Trial, patterns: np.ndarray | None, scene: Scene | None,
                rng: np.random.Generator) -> str:
        """The answer to a trial from the patterns felt (None: motors off) and the view (None: not drawn)."""
        options = list(trial.options)
        if rng.random() < self.lapse:
            return options[int(rng.integers(len(options)))]
        view = split_condition(trial.condition)[1]
        total = np.zeros(len(options))
        if patterns is not None and len(patterns):
            felt = np.asarray(patterns, dtype=float)
            total += self.touch_cue(trial.task, view).log_posterior(self.feel(felt, rng))
        if scene is not None:
            seen = view_features(in_view(copy.copy(scene), view))
            total += self.view_cue(trial.task, view).log_posterior(
                seen + rng.normal(0.0, self.visual_noise, seen.shape))
        return options[int(rng.choice(np.flatnonzero(best_options(total[None])[0])))]

    def localisation(self, *, trials: int = 2000, seed: int = 0) -> dict:
        """The palm's localisation task through this observer: one of its glove's palm motors vibrates,
        it points where it felt it (`psychophysics.vibration_localisation`, sd `localisation_mm`)."""
        positions = self.glove.motor_positions
        palm = self.glove.hand.regions(positions)["palm"]
        return vibration_localisation(positions[palm], self.localisation_mm, trials=trials, seed=seed)

    # -- training ------------------------------------------------------------------------------------

    def touch_cue(self, task_id: str, view: str = "projection") -> _Cue:
        """The trained touch classifier of a task in a view (trained on first use)."""
        if (task_id, view) not in self._touch:
            task = self.study.task(task_id)
            rng = self._rng(task_id, "touch", view)
            x, k, groups = touch_examples(self.glove, self.study, task, rng, scenes=self.train_scenes,
                                          positions=self.train_positions, exploration=self.exploration, view=view)
            answers = np.array([a for _, _, a in stimuli_of(task)])[k]
            self._touch[task_id, view] = _Cue(self.feel(x, rng), answers, groups, list(task.options))
        return self._touch[task_id, view]

    def view_cue(self, task_id: str, view: str = "projection") -> _Cue:
        """The trained view classifier of a task in a view (trained on first use)."""
        if (task_id, view) not in self._view:
            task = self.study.task(task_id)
            rng = self._rng(task_id, "view", view)
            x, k, groups = view_examples(self.study, task, rng, scenes=self.view_scenes, view=view)
            answers = np.array([a for _, _, a in stimuli_of(task)])[k]
            self._view[task_id, view] = _Cue(x + rng.normal(0.0, self.visual_noise, x.shape), answers, groups,
                                             list(task.options), setting="view_scenes")
        return self._view[task_id, view]

    @property
    def noise_per_motor(self) -> np.ndarray:
        """The sd of the noise on each motor (M,): `noise` (the fingertip's) scaled by its skin's ratio."""
        return self.noise * self._skin

    def feel(self, patterns: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Motor patterns (..., M) as felt: each motor's intensity plus Gaussian noise of its skin's sd
        (`noise_per_motor`); what the touch cue is trained on and answers from."""
        patterns = np.asarray(patterns, dtype=float)
        return patterns + rng.normal(0.0, self.noise_per_motor, patterns.shape)

    def with_noise(self, factor: float) -> "ModelObserver":
        """The same trained observer with its sensory noise (touch and sight) scaled by `factor`: a
        participant of the same population who feels and sees more or less sharply (every motor's
        noise scales alike: one free parameter a participant)."""
        other = copy.copy(self)                      # shares the trained cues
        other.noise, other.visual_noise = self.noise * factor, self.visual_noise * factor
        return other

    def train(self) -> "ModelObserver":
        """Train every task's cues in every view the study's conditions use now (else on first use)."""
        views = dict.fromkeys(split_condition(c)[1] for c in self.study.conditions)
        for task in self.study.tasks:
            for view in views:
                self.touch_cue(task.id, view)
                self.view_cue(task.id, view)
        return self

    def _rng(self, task_id: str, cue: str, view: str = "projection") -> np.random.Generator:
        key = f"{task_id}|{cue}" if view == "projection" else f"{task_id}|{cue}|{view}"
        salt = int.from_bytes(hashlib.sha256(key.encode()).digest()[:8], "big")
        return np.random.default_rng([self.seed, salt])


def best_options(total: np.ndarray) -> np.ndarray:
    """Which options have the highest summed log posterior, per row of `total` (B, options): the
    observer answers one of them at random (every option when no cue favours any)."""
    top = total.max(axis=1, keepdims=True)
    return np.where(np.isfinite(top), total >= top - 1e-9, True)


def chance(trial_or_options) -> float:
    """The chance rate of a trial's (or a list of options') choice."""
    options = getattr(trial_or_options, "options", trial_or_options)
    return 1.0 / len(options)


__all__ = ["ModelObserver", "Exploration", "every_sample_glove", "patterns_at", "view_features", "touch_examples",
           "view_examples", "best_options", "chance"]
