"""A trial's exploration measured from the bus samples of its stimulus (tactile/motors, hand/pose):
the table's columns time touching, mean intensity and hand path (touch4d.study.table)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Measures:
    time_touching_s: float
    mean_intensity: float
    path_length: float


@dataclass
class TrialMeasures:
    """Bus samples of one trial -> time touching, mean intensity and hand path over [onset, end].

    Both signals are sample-and-hold: a motor command holds until the next one, so the sample before
    the onset counts from the onset on. `threshold`: a motor intensity above it is felt (the glove's
    duty deadband). Path: the sum of the hand's steps between valid poses inside the window."""

    threshold: float
    # each a list of chunks, a sample or a served page's batch each: (stamps, felt, 30-motor mean) and
    # (stamps, positions with NaN rows where the hand was not tracked)
    _motors: list = field(default_factory=list)
    _poses: list = field(default_factory=list)

    def reset(self) -> None:
        """Keep only the latest sample of each signal (it holds into the next trial's window)."""
        self._motors = [tuple(a[-1:] for a in self._motors[-1])] if self._motors else []
        self._poses = [tuple(a[-1:] for a in self._poses[-1])] if self._poses else []

    def add_motors(self, stamp: float, intensity: np.ndarray) -> None:
        self.add_motor_rows(np.array([stamp], dtype=float), np.asarray(intensity, dtype=float).reshape(1, -1))

    def add_motor_rows(self, stamps: np.ndarray, intensity: np.ndarray) -> None:
        """Many motor commands at once (rows of `intensity`, one per stamp): a served page's batch."""
        if not len(stamps):
            return
        intensity = np.asarray(intensity, dtype=float)
        if not math.isfinite(intensity.sum()):     # NaN as 0 (a finite sum proves every value finite: as is)
            intensity = np.nan_to_num(intensity)
        if intensity.shape[1]:
            felt, mean = (intensity > self.threshold).any(axis=1), intensity.mean(axis=1)
        else:
            felt, mean = np.zeros(len(stamps), bool), np.zeros(len(stamps))
        self._motors.append((np.asarray(stamps, dtype=float), felt, mean))

    def add_poses(self, stamps: np.ndarray, positions: np.ndarray, valid: np.ndarray) -> None:
        """Many hand poses at once (rows of `positions`, one per stamp; an invalid one holds no place)."""
        positions = np.array(positions, dtype=float).reshape(-1, 3)
        positions[~np.asarray(valid, dtype=bool)] = np.nan
        self._poses.append((np.asarray(stamps, dtype=float), positions))

    def add_pose(self, stamp: float, position, valid: bool) -> None:
        self.add_poses(np.array([stamp], dtype=float), np.asarray(position, dtype=float).reshape(1, 3),
                       np.array([valid]))

    def measure(self, onset: float, end: float) -> Measures:
        touching = integral = 0.0
        if self._motors:
            t, felt, mean = (np.concatenate(a) for a in zip(*self._motors))
            order = np.argsort(t, kind="stable")
            t, felt, mean = t[order], felt[order], mean[order]
            held = np.clip(np.minimum(np.append(t[1:], end), end) - np.maximum(t, onset), 0.0, None)
            touching, integral = float(held @ felt), float(held @ mean)   # each sample holds until the next
        span = end - onset
        path = 0.0
        if self._poses:
            t, positions = (np.concatenate(a) for a in zip(*self._poses))
            order = np.argsort(t, kind="stable")
            t, positions = t[order], positions[order]
            before = np.flatnonzero(t < onset)
            inside = positions[(t >= onset) & (t <= end)]
            if len(before):           # where the hand was at the onset (or untracked: no step from it)
                inside = np.vstack([positions[before[-1]], inside])
            steps = np.sqrt(((inside[1:] - inside[:-1]) ** 2).sum(axis=1))   # NaN where a side was untracked
            path = float(np.nansum(steps))
        return Measures(touching, integral / span if span > 0 else 0.0, path)
