"""Bivectors of 4D space as 6-vectors over the planes xy, xz, xw, yz, yw, zw (`geometry.rotation.PLANES`).

A bivector w has the antisymmetric matrix W (`hat`) with W[b, a] = w_ab, so a rotation rate w_ab > 0
turns axis a toward axis b, as `plane_rotation` does. The velocity of a point r of a body turning at w
is W r; an impulse P at r changes the angular momentum by r ^ P (`wedge`); kinetic energy is w . L / 2.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from touch4d.geometry.rotation import PLANES, plane_axes

PAIRS = np.array([plane_axes(p) for p in PLANES])          # (6, 2) axis indices of each plane
PA = np.ascontiguousarray(PAIRS[:, 0])                     # first axis of each plane
PB = np.ascontiguousarray(PAIRS[:, 1])                     # second axis

# The formulas live once, compiled for one vector (`*_into`, which the physics step calls); the functions
# below apply them to stacks (..., 4) or (..., 6).


@njit(cache=True, nogil=True)
def compound_into(m, out):
    """6x6 matrix turning bivectors as m turns vectors."""
    for i in range(6):
        a, b = PA[i], PB[i]
        for j in range(6):
            c, d = PA[j], PB[j]
            out[i, j] = m[a, c] * m[b, d] - m[a, d] * m[b, c]


@njit(cache=True, nogil=True)
def wedge_into(r, p, out):
    """out = r ^ p (one pair of 4-vectors)."""
    for i in range(6):
        out[i] = r[PA[i]] * p[PB[i]] - r[PB[i]] * p[PA[i]]


@njit(cache=True, nogil=True)
def turn_into(w, r, out):
    """out = W r, the velocity of the point r of a body turning at w."""
    for k in range(4):
        out[k] = 0.0
    for i in range(6):
        a, b = PA[i], PB[i]
        out[b] += w[i] * r[a]
        out[a] -= w[i] * r[b]


@njit(cache=True, nogil=True)
def exp_into(w, out):
    """exp(hat(w)) in closed form: the product of its two commuting isoclinic parts, each
    cos(theta) I + sin(theta) / theta hat(part) with theta = |part| / sqrt(2)."""
    p0, p1, p2 = 0.5 * (w[0] + w[5]), 0.5 * (w[1] - w[4]), 0.5 * (w[2] + w[3])    # self-dual part
    q0, q1, q2 = 0.5 * (w[0] - w[5]), 0.5 * (w[1] + w[4]), 0.5 * (w[2] - w[3])    # anti-self-dual part
    tp = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    tq = math.sqrt(q0 * q0 + q1 * q1 + q2 * q2)
    # hat() of a self-dual bivector (p0, p1, p2, p2, -p1, p0) and of an anti-self-dual one (q0, q1, q2, -q2, q1, -q0)
    cp, sp = math.cos(tp), (math.sin(tp) / tp if tp > 0 else 1.0)
    cq, sq = math.cos(tq), (math.sin(tq) / tq if tq > 0 else 1.0)
    a = np.empty((4, 4))
    b = np.empty((4, 4))
    _hat_into(p0, p1, p2, p2, -p1, p0, cp, sp, a)
    _hat_into(q0, q1, q2, -q2, q1, -q0, cq, sq, b)
    for k in range(4):
        for j in range(4):
            out[k, j] = a[k, 0] * b[0, j] + a[k, 1] * b[1, j] + a[k, 2] * b[2, j] + a[k, 3] * b[3, j]


@njit(cache=True, nogil=True)
def _hat_into(w0, w1, w2, w3, w4, w5, c, s, out):
    """out = c I + s hat(w)."""
    for k in range(4):
        for j in range(4):
            out[k, j] = 0.0
        out[k, k] = c
    out[1, 0], out[0, 1] = s * w0, -s * w0
    out[2, 0], out[0, 2] = s * w1, -s * w1
    out[3, 0], out[0, 3] = s * w2, -s * w2
    out[2, 1], out[1, 2] = s * w3, -s * w3
    out[3, 1], out[1, 3] = s * w4, -s * w4
    out[3, 2], out[2, 3] = s * w5, -s * w5



@njit(cache=True, nogil=True)
def _wedge_rows(r, p, out):
    for n in range(len(r)):
        wedge_into(r[n], p[n], out[n])


@njit(cache=True, nogil=True)
def _compound_rows(m, out):
    for n in range(len(m)):
        compound_into(m[n], out[n])


@njit(cache=True, nogil=True)
def _exp_rows(w, out):
    for n in range(len(w)):
        exp_into(w[n], out[n])


def _rows(a, width: int) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64).reshape(-1, width))


def wedge(r, p) -> np.ndarray:
    """r ^ p over the six planes: (r ^ p)_ab = r_a p_b - r_b p_a (works on stacks (..., 4))."""
    r, p = np.broadcast_arrays(np.asarray(r, dtype=np.float64), np.asarray(p, dtype=np.float64))
    out = np.empty((int(np.prod(r.shape[:-1])), 6))
    _wedge_rows(_rows(r, 4), _rows(p, 4), out)
    return out.reshape(r.shape[:-1] + (6,))


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
    """The 6x6 matrix that turns bivectors as the rotation r turns vectors: hat(C w) = r hat(w) r^T
    (C[(ab), (cd)] = r_ac r_bd - r_ad r_bc; stacks too)."""
    r = np.asarray(r, dtype=np.float64)
    out = np.empty((int(np.prod(r.shape[:-2])), 6, 6))
    _compound_rows(np.ascontiguousarray(r.reshape(-1, 4, 4)), out)
    return out.reshape(r.shape[:-2] + (6, 6))


def exp(w) -> np.ndarray:
    """The rotation exp(hat(w)) (`exp_into`; stacks too)."""
    w = np.asarray(w, dtype=np.float64)
    out = np.empty((int(np.prod(w.shape[:-1])), 4, 4))
    _exp_rows(_rows(w, 6), out)
    return out.reshape(w.shape[:-1] + (4, 4))


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
