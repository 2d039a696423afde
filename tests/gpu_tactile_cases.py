"""Random scenes and hand poses built by construction (a seeded numpy Generator picks shapes, sizes,
angles and positions), for the tactile model's GPU paths held against the CPU one
(test_render_tactile, test_web_touch_browser)."""
from __future__ import annotations

import math

import numpy as np

from touch4d.geometry.scene import parse_scene

SHAPES = ("tesseract", "5-cell", "16-cell", "24-cell", "pyramid", "hollow-front", "duoprism")
PLANES = ("xy", "xz", "xw", "yz", "yw", "zw")


def random_scene(rng: np.random.Generator, projection: str | None = None, slice_w: float | None = None):
    """One to three objects in front of the screen, each turned in a few planes; orthographic or
    perspective (eye 3 units behind the screen); with `slice_w`, the slice view touching its
    cross-section there."""
    objects = []
    for _ in range(int(rng.integers(1, 4))):
        steps = [[str(PLANES[k]), float(rng.uniform(-180, 180))] for k in rng.choice(6, size=3, replace=False)]
        objects.append({"shape": str(rng.choice(SHAPES)), "size": float(rng.uniform(0.8, 1.6)),
                        "position": [*(float(v) for v in rng.uniform(-0.4, 0.4, 3)), float(rng.uniform(1.2, 2.2))],
                        "rotation": steps})
    projection = projection or str(rng.choice(["orthographic", "perspective"]))
    view = {} if slice_w is None else {"view": "slice", "slice_w": float(slice_w), "slice_touch": "section"}
    return parse_scene({"objects": objects, "projection": projection, "eye_distance": 3.0, **view})


def quaternion_of(axis_angles) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of turns about x, then y, then z by the given angles (radians)."""
    q = np.array([0.0, 0.0, 0.0, 1.0])
    for k, a in enumerate(axis_angles):
        turn = np.zeros(4)
        turn[k], turn[3] = math.sin(a / 2), math.cos(a / 2)
        x1, y1, z1, w1 = turn
        x2, y2, z2, w2 = q
        q = np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                      w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])
    return q / np.linalg.norm(q)


def random_pose(rng: np.random.Generator, reach: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """A hand position in the screen (screen units) and an orientation from three angles."""
    return rng.uniform(-reach, reach, 3), quaternion_of(rng.uniform(-math.pi, math.pi, 3))
