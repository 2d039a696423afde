"""Bivectors of 4D space as 6-vectors over the planes xy, xz, xw, yz, yw, zw (`geometry.rotation.PLANES`).

A bivector w has the antisymmetric matrix W (`hat`) with W[b, a] = w_ab, so a rotation rate w_ab > 0
turns axis a toward axis b, as `plane_rotation` does. The velocity of a point r of a body turning at w
is W r; an impulse P at r changes the angular momentum by r ^ P (`wedge`); kinetic energy is w . L / 2.
"""
from __future__ import annotations

import numpy as np

from touch4d.geometry.rotation import PLANES, plane_axes

PAIRS = np.array([plane_axes(p) for p in PLANES])          # (6, 2) axis indices of each plane


def wedge(r, p) -> np.ndarray:
    """r ^ p over the six planes: (r ^ p)_ab = r_a p_b - r_b p_a (works on stacks (..., 4))."""
    r, p = np.asarray(r, dtype=np.float64), np.asarray(p, dtype=np.float64)
    a, b = PAIRS[:, 0], PAIRS[:, 1]
    return r[..., a] * p[..., b] - r[..., b] * p[..., a]


def hat(w) -> np.ndarray:
    """The antisymmetric 4x4 matrix W of a bivector: W[b, a] = w_ab, W[a, b] = -w_ab (stacks too)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.zeros(w.shape[:-1] + (4, 4))
    a, b = PAIRS[:, 0], PAIRS[:, 1]
    out[..., b, a] = w
    out[..., a, b] = -w
    return out


def vee(m) -> np.ndarray:
    """The bivector of an antisymmetric matrix (its antisymmetric part for any matrix)."""
    m = np.asarray(m, dtype=np.float64)
    a, b = PAIRS[:, 0], PAIRS[:, 1]
    return 0.5 * (m[..., b, a] - m[..., a, b])


def compound(r) -> np.ndarray:
    """The 6x6 matrix that turns bivectors as the rotation r turns vectors: hat(C w) = r hat(w) r^T."""
    r = np.asarray(r, dtype=np.float64)
    a, b = PAIRS[:, 0], PAIRS[:, 1]
    ra, rb = r[..., a, :], r[..., b, :]                      # rows a and b of every plane
    # C[(ab), (cd)] = r_ac r_bd - r_ad r_bc
    return ra[..., :, a] * rb[..., :, b] - ra[..., :, b] * rb[..., :, a]


def star(w) -> np.ndarray:
    """The Hodge dual: xy <-> zw, xz <-> -yw, xw <-> yz."""
    w = np.asarray(w, dtype=np.float64)
    return np.stack([w[..., 5], -w[..., 4], w[..., 3], w[..., 2], -w[..., 1], w[..., 0]], axis=-1)


def exp(w) -> np.ndarray:
    """The rotation exp(hat(w)), closed form: w splits into a self-dual and an anti-self-dual part whose
    matrices commute and square to -|w+-|^2/2 times the identity (two isoclinic rotations)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.broadcast_to(np.eye(4), w.shape[:-1] + (4, 4)).copy()
    for sign in (1.0, -1.0):
        part = 0.5 * (w + sign * star(w))
        theta = np.linalg.norm(part, axis=-1) / np.sqrt(2.0)
        sinc = np.where(theta > 0, np.sin(theta) / np.where(theta > 0, theta, 1.0), 1.0)
        e = np.cos(theta)[..., None, None] * np.eye(4) + sinc[..., None, None] * hat(part)
        out = out @ e
    return out


def to_planes(w) -> dict[str, float]:
    """A bivector as {plane: value}."""
    return {p: float(v) for p, v in zip(PLANES, np.asarray(w, dtype=np.float64))}


def from_planes(pairs) -> np.ndarray:
    """A bivector from [[plane, value], ...]; a plane written backwards ("wx") counts negatively."""
    w = np.zeros(6)
    for plane, value in pairs:
        a, b = plane_axes(plane)
        if a < b:
            w[PLANES.index("xyzw"[a] + "xyzw"[b])] += value
        else:
            w[PLANES.index("xyzw"[b] + "xyzw"[a])] -= value
    return w
