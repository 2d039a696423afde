"""Exact mass properties of convex 4-polytopes and their unions, from 4-simplices.

Each convex part is cut into 4-simplices (its centre, a cell's centre, and a triangle of a fan over each
2-face of that cell); a simplex with vertices v0..v4 and volume V has, exactly,
    integral of x x^T dV = V / 30 (sum_i v_i v_i^T + (sum_i v_i)(sum_i v_i)^T)
(the n-simplex rule V / ((n + 1)(n + 2)) with n = 4). Summing over the simplices gives a part's volume,
centroid and second moments; a union of parts is their sum (parts must not overlap).

In 4D a body's inertia acts on bivectors: with S the second-moment matrix about the centre of mass in
principal axes (S = diag(s)), the inertia in plane ab is s_a + s_b, so L_ab = (s_a + s_b) w_ab
(ten Bosch 2020). A tesseract of edge a and mass m has s = m a^2 / 12 on every axis.
"""
from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from touch4d.geometry.polytope import Polytope

from .bivector import PAIRS


@dataclass(frozen=True)
class MassProperties:
    """Volume, mass, centre of mass and second moments (about the centre, in the given frame)."""

    volume: float
    mass: float
    center: np.ndarray          # (4,)
    second_moment: np.ndarray   # (4, 4) integral of rho (x - c)(x - c)^T
    axes: np.ndarray            # (4, 4) columns: principal axes (local frame), a rotation
    principal: np.ndarray       # (4,) second moments along the axes
    plane_inertia: np.ndarray   # (6,) s_a + s_b over the planes xy, xz, xw, yz, yw, zw


def simplices(poly: Polytope) -> np.ndarray:
    """(K, 5, 4) 4-simplices that tile the polytope exactly."""
    verts = poly.vertices
    centre = verts.mean(axis=0)
    faces = poly.topology.faces
    out = []
    for cell, face_ids in enumerate(poly.topology.cell_faces):
        cell_centre = verts[poly.topology.cell_vertices[cell]].mean(axis=0)
        for f in face_ids:
            ring = verts[faces[f]]
            for i in range(1, len(ring) - 1):
                out.append((centre, cell_centre, ring[0], ring[i], ring[i + 1]))
    return np.array(out)


def raw_moments(parts) -> tuple[float, np.ndarray, np.ndarray]:
    """(volume, first moment (4,), second moment about the origin (4, 4)) of non-overlapping parts."""
    volume, first, second = 0.0, np.zeros(4), np.zeros((4, 4))
    for poly in parts:
        s = simplices(poly)
        vol = np.abs(np.linalg.det(s[:, 1:] - s[:, :1])) / factorial(4)
        total = s.sum(axis=1)                                          # (K, 4)
        volume += vol.sum()
        first += (vol[:, None] * total).sum(axis=0) / 5.0
        outer = np.einsum("kia,kib->kab", s, s) + np.einsum("ka,kb->kab", total, total)
        second += (vol[:, None, None] * outer).sum(axis=0) / 30.0
    return volume, first, second


def mass_properties(parts, mass: float | None = None, density: float | None = None) -> MassProperties:
    """Mass properties of a body made of the convex `parts` (local coordinates), given its mass or its
    density (default density 1)."""
    volume, first, second = raw_moments(parts)
    if volume <= 0:
        raise ValueError("a body needs a positive volume")
    if mass is None:
        mass = (1.0 if density is None else density) * volume
    rho = mass / volume
    centre = first / volume
    s = rho * second - mass * np.outer(centre, centre)
    s = 0.5 * (s + s.T)
    principal, axes = np.linalg.eigh(s)
    if np.linalg.det(axes) < 0:
        axes[:, 3] = -axes[:, 3]
    planes = principal[PAIRS[:, 0]] + principal[PAIRS[:, 1]]
    return MassProperties(volume, float(mass), centre, s, axes, principal, planes)
