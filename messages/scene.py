"""Scene messages: every object of the 4D scene and how it is projected (topic scene/state)."""
from typing import Literal

import numpy as np

from .base import Array, Float, Map, Message, Records, doc

PROJECTIONS = ("orthographic", "perspective")
VIEWS = ("projection", "slice", "both")        # what is drawn: the projection, the section at w = slice_w, both
SLICE_TOUCH = ("section", "projection")         # what the glove renders in a slice view
PHYSICS_COMMANDS = ("pause", "play", "step")      # only the physics node runs these
SCENE_COMMANDS = ("next", "select", "reset", "projection", "view", "slice", "load", *PHYSICS_COMMANDS)

SceneObject = Records(
    name=str, shape=str, params=Map, size=Float, position=Array(4), orientation=Array(4, 4), color=Array(4),
    parts=list[Array(None, 5)], optional=("params", "parts"),
)


class SceneState(Message):
    """The whole 4D scene; published on every change and at a low steady rate for late joiners."""

    objects: SceneObject = doc(
        "objects: name; shape (catalog name or 'custom'); params (catalog parameters); size (scale of "
        "the local coordinates); position (4,) world; orientation (4,4) orthogonal, local -> world; "
        "color (4,) RGBA 0..1; parts: local half-spaces [n1,n2,n3,n4,d] (n.x <= d) of each convex part, "
        "only for 'custom' shapes",
    )
    projection: Literal[PROJECTIONS] = doc("how the 4D world is projected to the 3D screen")
    eye_distance: Float = doc("perspective eye on the w axis at w = -eye_distance, screen units")
    selected: int = doc("index of the object the controller rotates (-1: the whole scene)")
    revision: int = doc("bumps on every change of the scene, so consumers rebuild only then")
    view: Literal[VIEWS] = doc("projection: the 4D scene projected (the paper); slice: each object's cross-section "
                               "at w = slice_w, solid; both: the section inside the translucent projection",
                               default="projection", optional=True)
    slice_w: Float = doc("where the slice view cuts the world, w in screen units", default=0.0, optional=True)
    slice_touch: Literal[SLICE_TOUCH] = doc("in the slice view, what the glove renders: section (the cross-section "
                                            "as a solid the hand presses) or projection (the paper's touch)",
                                            default="section", optional=True)

    def check(self):
        for index, obj in enumerate(self.objects):
            if not obj["size"] > 0:
                raise ValueError(f"objects[{index}].size: expected > 0, got {obj['size']}")
            o = obj["orientation"]
            if not np.allclose(o @ o.T, np.eye(4), atol=1e-6):
                raise ValueError(f"objects[{index}].orientation: expected an orthogonal 4x4 matrix")
            if obj["shape"] == "custom" and not obj.get("parts"):
                raise ValueError(f"objects[{index}].parts: a 'custom' shape needs its half-spaces")
        if self.projection == "perspective" and not self.eye_distance > 0:
            raise ValueError(f"eye_distance: expected > 0 for perspective, got {self.eye_distance}")
        if not -1 <= self.selected < max(len(self.objects), 1):
            raise ValueError(f"selected: expected -1..{len(self.objects) - 1}, got {self.selected}")


class SceneCommand(Message):
    """A request to the scene node (topic scene/command): next/select object, reset, projection, or load a
    whole scene (argument: scene-file text, YAML, as touch4d.geometry.scene.parse_scene reads it)."""

    command: Literal[SCENE_COMMANDS] = doc("what to do")
    argument: str = doc("select: object name or index; projection: orthographic|perspective|toggle; "
                        "view: projection|slice|both|next; slice: where it cuts (a number, w = C) or "
                        "up / down [D] to move it by D (default one step); "
                        "load: the scene file's text; step: how many physics steps (default 1)")
