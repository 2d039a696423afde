"""Ray casting along +w from screen points (paper eq. 4-7), many points against many convex parts at once.

Along a ray x(t) = (p, 0) + t e_w a half-space n.x <= c bounds t from below when n_w < 0 (the ray enters
there), from above when n_w > 0 (it leaves), and not at all when n_w = 0 (then p itself must satisfy it).
Each bound is t = c/n_w - (n3/n_w).p, linear in p, so all of them are one matrix product; the half-spaces
of every part are sorted once into entering / leaving / parallel columns (by the shared kernel,
`halfspace.kinds`), reduced per part with reduceat. Perspective rays become parallel to w under the
projective map of `projection.perspective_points`.
"""
from __future__ import annotations

import numpy as np

from .halfspace import GRAZE, kinds, view_halfspaces
from .polytope import Polytope
from .projection import perspective_distance


class RayCaster:
    """Entry distances along +w from screen points to a scene of convex parts; build once per scene.

    world_parts: list of (object_index, Polytope) in world coordinates. eye_distance: None for
    orthographic rays (x, y, z, 0) + t (0, 0, 0, 1); d > 0 for perspective rays from the eye (0,0,0,-d)
    through (x, y, z, 0), t measured from the screen point (eq. 7).
    """

    def __init__(self, world_parts: list[tuple[int, Polytope]], eye_distance: float | None = None):
        self.eye_distance = None if eye_distance is None else float(eye_distance)
        self.part_object = np.array([int(i) for i, _ in world_parts], dtype=np.int64)
        blocks = []
        for _, poly in world_parts:
            n, c = view_halfspaces(poly.normals, poly.offsets, self.eye_distance)
            if self.eye_distance is not None:
                # phi is only valid in front of the eye: v < 1.
                n, c = np.vstack([n, [0, 0, 0, 1.0]]), np.r_[c, 1.0 - 1e-9]
            blocks.append(_split(n, c))
        self._build(blocks)

    def _build(self, blocks):
        """Concatenate each kind of bound over all parts (ragged, no padding); every part gets at least
        one column of each kind (a neutral one if needed) so per-part reductions can use reduceat.
        The three kinds share one matrix, so a cast does one matrix product."""
        neutral = ((np.zeros((1, 3)), np.array([-np.inf])), (np.zeros((1, 3)), np.array([np.inf])),
                   (np.zeros((1, 3)), np.array([1.0])))
        cols = [[], [], []]
        for block in blocks:
            for kind in range(3):
                a, b = block[kind] if len(block[kind][1]) else neutral[kind]
                cols[kind].append((a, b))
        self._parts = len(blocks)
        self._has_parallel = any(len(block[2][1]) for block in blocks)
        if not self._parts:
            return
        kinds = [np.vstack([a for a, _ in cols[kind]]) for kind in range(3 if self._has_parallel else 2)]
        self._a = np.ascontiguousarray(np.vstack(kinds).T)          # (3, columns): entering, leaving, parallel
        self._b = np.concatenate([np.concatenate([b for _, b in cols[kind]]) for kind in range(len(kinds))])
        # One part: bounds as rows (columns x rays), reduced over axis 0, several times quicker in numpy.
        self._rows, self._b_rows = np.ascontiguousarray(self._a.T), self._b[:, None]
        ends = np.cumsum([len(k) for k in kinds])
        self._slices = [slice(0 if k == 0 else ends[k - 1], ends[k]) for k in range(len(kinds))]
        self._starts = [np.r_[0, np.cumsum([len(b) for _, b in cols[kind]])[:-1]] for kind in range(len(kinds))]

    @property
    def n_parts(self) -> int:
        return self._parts

    def _intervals(self, p: np.ndarray):
        """Per ray and part: entry bound, exit bound, and whether the parallel cells let the ray through."""
        if not self._parts:
            empty = np.zeros((len(p), 0))
            return empty, empty, empty.astype(bool)
        s = self._slices
        if self._parts == 1:   # every bound t = b - A.p at once, a row per bound; parallel cells: A.p <= b
            bounds = self._b_rows - self._rows @ p.T
            enter = bounds[s[0]].max(axis=0)[:, None]
            leave = bounds[s[1]].min(axis=0)[:, None]
            through = (bounds[s[2]] >= -GRAZE).all(axis=0)[:, None] if self._has_parallel else None
        else:                  # a column per bound, reduced per part
            bounds = self._b - p @ self._a
            enter = np.maximum.reduceat(bounds[:, s[0]], self._starts[0], axis=1)
            leave = np.minimum.reduceat(bounds[:, s[1]], self._starts[1], axis=1)
            through = (np.logical_and.reduceat(bounds[:, s[2]] >= -GRAZE, self._starts[2], axis=1)
                       if self._has_parallel else None)
        np.maximum(enter, 0.0, out=enter)
        ok = enter <= leave + GRAZE
        if through is not None:
            ok &= through
        return enter, leave, ok

    def cast(self, points3) -> tuple[np.ndarray, np.ndarray]:
        """(N,3) screen points -> (t (N,) float64 entry distance >= 0, NaN on a miss; hit (N,) object or -1).

        A point already inside an object has t = 0; where parts overlap the nearest entry wins.
        """
        p = np.asarray(points3, dtype=np.float64).reshape(-1, 3)
        n = len(p)
        if not self._parts or not n:
            return np.full(n, np.nan), np.full(n, -1, dtype=np.int64)
        enter, _, ok = self._intervals(p)
        if self._parts == 1:
            t = np.where(ok[:, 0], enter[:, 0], np.nan)
            hit = np.where(ok[:, 0], self.part_object[0], -1)
        else:
            t_part = np.where(ok, enter, np.inf)
            best = t_part.argmin(axis=1)
            t = t_part[np.arange(n), best]
            found = np.isfinite(t)
            hit = np.where(found, self.part_object[best], -1)
            t = np.where(found, t, np.nan)
        if self.eye_distance is not None:
            # t is v = w / (w + d) on the mapped ray: back to w, then to the distance along the sight line.
            w = t * self.eye_distance / (1.0 - t)
            t = perspective_distance(p, w, self.eye_distance)
        return t, hit

    def intervals(self, points3) -> tuple[np.ndarray, np.ndarray]:
        """Per ray and part, (enter, leave) (N,P) of the ray's t >= 0 inside the part, NaN on a miss.

        Orthographic: t is w. Perspective: t is v = w / (w + d) of the projective map (same order).
        """
        p = np.asarray(points3, dtype=np.float64).reshape(-1, 3)
        enter, leave, ok = self._intervals(p)
        return np.where(ok, enter, np.nan), np.where(ok, leave, np.nan)


def _split(normals: np.ndarray, offsets: np.ndarray):
    """Half-spaces as ((A_enter, b_enter), (A_exit, b_exit), (A_par, b_par)): bound t = b - A.p; parallel: A.p <= b."""
    nw = normals[:, 3]
    entering, leaving, parallel = kinds(normals)

    def bounds(mask):
        return normals[mask, :3] / nw[mask, None], offsets[mask] / nw[mask]

    return bounds(entering), bounds(leaving), (normals[parallel, :3], offsets[parallel])
