"""The frame model: everything one frame is made of, built without any GL, so every backend (the GPU
renderer, the clip-unit renderer, the WebXR page) draws the same frame.

A `Frame` holds the 4D scene as a `SceneLayer` — the per-revision `SceneGeometry` and the per-frame
object transforms, the projection and the `Style` — and the flat layers drawn around it in 3D screen
coordinates: opaque solids (the slice view's cross-sections) and triangles and lines (N, 7)
[x, y, z, r, g, b, a], points (N, 8) [.., size in pixels], and an RGBA overlay image at the top-left
corner. docs/contracts.md fixes the layouts.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FLOATS_PER_VERTEX = 7          # x, y, z, r, g, b, a
POINT_FLOATS = 8               # x, y, z, r, g, b, a, size (pixels)

# Centre copies are colour-coded per cell (local cell index), so a cell keeps its colour as it turns.
CELL_PALETTE = np.array([
    [0.95, 0.33, 0.25], [0.25, 0.70, 0.95], [0.98, 0.80, 0.20], [0.55, 0.35, 0.90],
    [0.20, 0.85, 0.45], [0.95, 0.45, 0.75], [0.10, 0.55, 0.55], [0.90, 0.60, 0.25],
    [0.60, 0.80, 0.20], [0.35, 0.40, 0.95], [0.85, 0.20, 0.45], [0.55, 0.95, 0.85],
])


def cell_color(index) -> np.ndarray:
    """The RGB colour of the centre copy of local cell `index` (array-valued for arrays)."""
    return CELL_PALETTE[np.asarray(index) % len(CELL_PALETTE)]


@dataclass(frozen=True)
class Style:
    """How the scene is drawn: alphas of fills, edges and centre copies; what is shown."""

    fill_alpha: float = 0.18
    edge_alpha: float = 1.0
    centre_scale: float = 0.3
    centre_alpha: float = 0.55
    cell_colors: bool = True      # centre copies in per-cell colours; False: the object's colour
    centres: bool = True
    clip: bool = True             # hidden-hypersurface removal (False draws hidden parts too)


@dataclass
class SceneLayer:
    """The 4D scene of one frame: geometry uploaded once per revision, transforms that change per frame.

    `geometry`: a `touch4d.render.scene_geometry.SceneGeometry`; `transforms`: (objects, 6, 4) float32
    from `scene_geometry.object_transforms`; `eye_distance` is used in perspective only.
    """

    geometry: object
    transforms: np.ndarray
    projection: str = "orthographic"
    eye_distance: float = 3.0
    style: Style = Style()

    @property
    def perspective_eye(self) -> float | None:
        return self.eye_distance if self.projection == "perspective" else None


@dataclass
class Frame:
    """Everything one frame draws: the scene's projection (or None), the opaque solids (depth-tested
    among themselves, drawn over the projection) and the flat layers around it."""

    scene: SceneLayer | None = None
    solids: list = field(default_factory=list)
    triangles: list = field(default_factory=list)
    lines: list = field(default_factory=list)
    points: list = field(default_factory=list)
    overlay: np.ndarray | None = None
