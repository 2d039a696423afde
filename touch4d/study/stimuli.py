"""A trial's stimulus as a scene: the task's scene file with the trial's tilt (tilt tasks) and jitter
turned onto every object, about the object's own centre (world = R_jitter R_tilt R_file local +
position), so it stays behind the screen (w > 0) as the paper's scenes are.

`scene_mapping` gives it as a scene-file mapping (what `parse_scene` reads; a runner can send it
as text), `trial_scene` as a `Scene`; one is the other parsed, so they never disagree.
"""
from __future__ import annotations

import copy
import math
from functools import lru_cache
from pathlib import Path

from touch4d import schema
from touch4d.geometry.scene import Scene, parse_scene

from .design import Study, scene_path
from .plan import Trial


def stimulus_scene_path(study: Study, trial: Trial) -> Path:
    """The scene file behind a trial's stimulus (a tilt task's untilted scene)."""
    index = [t.id for t in study.tasks].index(trial.task)
    task = study.tasks[index]
    if task.kind == "tilt":
        return scene_path(study, f"tasks[{index}].scene", task.scene)
    for j, stim in enumerate(task.stimuli):
        if stim.label == trial.stimulus:
            return scene_path(study, f"tasks[{index}].stimuli[{j}].scene", stim.scene)
    schema.fail(study.path, f"tasks[{index}].stimuli", f"a stimulus named {trial.stimulus!r}", got=trial.stimulus,
                choices=task.stimulus_names())


def trial_rotation(study: Study, trial: Trial) -> list[list]:
    """The turns a trial adds to every object, in order: the tilt (tilt tasks), then the jitter."""
    steps = []
    if trial.kind == "tilt" and not math.isnan(trial.level):
        steps.append([study.task(trial.task).plane, float(trial.level)])
    steps.extend([str(plane), float(deg)] for plane, deg in trial.transform)
    return steps


def scene_mapping(study: Study, trial: Trial) -> dict:
    """The trial's scene as a scene-file mapping (objects' `rotation` lists extended by the trial's)."""
    path = stimulus_scene_path(study, trial)
    data = copy.deepcopy(_scene_file(str(path), path.stat().st_mtime_ns))
    steps = trial_rotation(study, trial)
    for obj in data["objects"]:
        obj["rotation"] = [list(step) for step in obj.get("rotation", [])] + [list(s) for s in steps]
    data["description"] = f"{study.name}: {trial.task} {trial.stimulus} ({Path(path).name})"
    return data


def trial_scene(study: Study, trial: Trial) -> Scene:
    """The trial's scene, ready for a RayCaster or a renderer."""
    path = stimulus_scene_path(study, trial)
    return parse_scene(scene_mapping(study, trial), path)


@lru_cache(maxsize=64)
def _scene_file(path: str, mtime_ns: int) -> dict:
    """A scene file's mapping, read and checked once per version of the file."""
    data = schema.read_yaml(path, "scene file")
    parse_scene(data, path)
    return data
