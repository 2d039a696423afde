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

from .conditions import split_condition
from .design import Study, scene_path
from .plan import Trial


def stimulus_scene_path(study: Study, task_id: str, stimulus: str) -> Path:
    """The scene file behind a task's stimulus, as its kind says (`Task.scene_of`: a tilt task's
    untilted scene)."""
    index = [t.id for t in study.tasks].index(task_id)
    task = study.tasks[index]
    found = task.scene_of(stimulus)
    if found is None:
        schema.fail(study.path, f"tasks[{index}].stimuli", f"a stimulus named {stimulus!r}", got=stimulus,
                    choices=task.stimulus_names())
    key, path = found
    return scene_path(study, f"tasks[{index}].{key}", path)


def stimulus_rotation(study: Study, task_id: str, level: float, transform) -> list[list]:
    """The turns a stimulus adds to every object, in order: its kind's (`Task.turns`: a tilt task's
    tilt), then the jitter."""
    return study.task(task_id).turns(level) + [[str(plane), float(deg)] for plane, deg in transform]


def stimulus_mapping(study: Study, task_id: str, stimulus: str, level: float = math.nan, transform=()) -> dict:
    """A stimulus, tilted and jittered, as a scene-file mapping (objects' `rotation` lists extended)."""
    path = stimulus_scene_path(study, task_id, stimulus)
    data = copy.deepcopy(_scene_file(str(path), path.stat().st_mtime_ns))
    steps = stimulus_rotation(study, task_id, level, transform)
    for obj in data["objects"]:
        obj["rotation"] = [list(step) for step in obj.get("rotation", [])] + [list(s) for s in steps]
    data["description"] = f"{study.name}: {task_id} {stimulus} ({path.name})"
    return data


def stimulus_scene(study: Study, task_id: str, stimulus: str, level: float = math.nan, transform=()) -> Scene:
    """A stimulus, tilted and jittered, as a Scene."""
    return parse_scene(stimulus_mapping(study, task_id, stimulus, level, transform),
                       stimulus_scene_path(study, task_id, stimulus))


def scene_mapping(study: Study, trial: Trial) -> dict:
    """The trial's scene as a scene-file mapping (what `parse_scene` reads; a runner sends it as text),
    in the view its condition sets."""
    data = stimulus_mapping(study, trial.task, trial.stimulus, trial.level, trial.transform)
    view = split_condition(trial.condition)[1]
    if view != "projection":
        data["view"] = view
    return data


def trial_scene(study: Study, trial: Trial) -> Scene:
    """The trial's scene, in the view its condition sets, ready for a RayCaster or a renderer."""
    return in_view(stimulus_scene(study, trial.task, trial.stimulus, trial.level, trial.transform),
                   split_condition(trial.condition)[1])


def in_view(scene: Scene, view: str) -> Scene:
    """`scene` shown (and touched) in `view`: projection, slice or both."""
    scene.view = view
    return scene


@lru_cache(maxsize=64)
def _scene_file(path: str, mtime_ns: int) -> dict:
    """A scene file's mapping, read and checked once per version of the file."""
    data = schema.read_yaml(path, "scene file")
    parse_scene(data, path)
    return data
