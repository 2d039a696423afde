"""A parametric hand (a rounded palm slab and five capsule fingers) and the grid of samples inside it.

Hand frame, metres: origin at the centre of the palm, x toward the thumb, y along the fingers,
z out of the back of the hand (the palm faces -z).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from touch4d.hands import FINGER_NAMES  # noqa: F401 - the glove file's finger names, re-exported


@dataclass(frozen=True)
class Finger:
    """A finger as a capsule: a segment from `base` to `tip` swept by `radius` (metres)."""

    name: str
    base: np.ndarray   # (3,)
    tip: np.ndarray    # (3,)
    radius: float

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Which of `points` (N, 3) lie inside the capsule (boundary included)."""
        points, axis = np.asarray(points, dtype=float), self.tip - self.base
        t = np.clip((points - self.base) @ axis / (axis @ axis), 0.0, 1.0)
        return np.sum((points - (self.base + t[:, None] * axis)) ** 2, axis=1) <= (self.radius + tol) ** 2


@dataclass(frozen=True)
class Hand:
    """A palm and fingers (capsules).

    The palm is a slab centred at the origin, `palm_half` (3,) its half extents, whose thumb and
    little-finger sides are rounded (half-cylinders of radius palm_half[2]) like a real palm's.
    """

    palm_half: np.ndarray
    fingers: tuple[Finger, ...]

    @classmethod
    def from_sizes(cls, palm: dict, fingers: list[dict]) -> "Hand":
        """Build from config sizes: palm {width, length, thickness}; fingers [{name, base [x, y], angle_deg, length, radius}].

        `base` is where the finger's axis starts, in the palm plane z = 0; `angle_deg` turns the
        finger from +y toward +x (the thumb side).
        """
        half = 0.5 * np.array([palm["width"], palm["length"], palm["thickness"]], dtype=float)
        if half[0] < half[2]:
            raise ValueError("palm: expected width >= thickness")
        made = []
        for f in fingers:
            angle = np.radians(f["angle_deg"])
            base = np.array([f["base"][0], f["base"][1], 0.0], dtype=float)
            direction = np.array([np.sin(angle), np.cos(angle), 0.0])
            made.append(Finger(f["name"], base, base + f["length"] * direction, float(f["radius"])))
        return cls(half, tuple(made))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The hand's axis-aligned bounding box (low corner, high corner)."""
        lows = [-self.palm_half]
        highs = [self.palm_half]
        for f in self.fingers:
            ends = np.stack([f.base, f.tip])
            lows.append(ends.min(axis=0) - f.radius)
            highs.append(ends.max(axis=0) + f.radius)
        return np.min(lows, axis=0), np.max(highs, axis=0)

    def contains(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Which of `points` (N, 3) lie inside the palm or a finger (boundary included)."""
        points = np.asarray(points, dtype=float)
        inside = self.in_palm(points, tol)
        for f in self.fingers:
            inside |= f.contains(points, tol)
        return inside

    def in_palm(self, points: np.ndarray, tol: float = 1e-9) -> np.ndarray:
        """Which of `points` (N, 3) lie inside the rounded palm slab."""
        hx, hy, hz = self.palm_half
        dx = np.maximum(np.abs(points[:, 0]) - (hx - hz), 0.0)
        return (np.abs(points[:, 1]) <= hy + tol) & (dx**2 + points[:, 2] ** 2 <= (hz + tol) ** 2)

    def regions(self, points: np.ndarray) -> dict[str, list[int]]:
        """The indices of `points` (N, 3) in each region of the hand: `palm` (the palm's side of the
        slab, z < 0), `back` (z > 0), and each finger by name (its capsule, outside the palm)."""
        points = np.asarray(points, dtype=float)
        palm = self.in_palm(points)
        regions = {"palm": np.flatnonzero(palm & (points[:, 2] < 0)).tolist(),
                   "back": np.flatnonzero(palm & (points[:, 2] > 0)).tolist()}
        for f in self.fingers:
            regions[f.name] = np.flatnonzero(f.contains(points) & ~palm).tolist()
        return regions

    def grid_samples(self, n: int | tuple[int, int, int]) -> np.ndarray:
        """Sample points: an n x n x n grid over the bounding box, keeping those inside the hand (paper §6)."""
        counts = (n, n, n) if np.isscalar(n) else tuple(n)
        low, high = self.bounds()
        axes = [np.linspace(low[k], high[k], counts[k]) for k in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        return grid[self.contains(grid)]

    def finger(self, name: str) -> Finger:
        for f in self.fingers:
            if f.name == name:
                return f
        raise KeyError(name)
