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
    _motors: list = field(default_factory=list)    # (stamp, any motor > threshold, 30-motor mean)
    _poses: list = field(default_factory=list)     # (stamp, position or None when invalid)

    def reset(self) -> None:
        """Keep only the latest sample of each signal (it holds into the next trial's window)."""
        self._motors = self._motors[-1:]
        self._poses = self._poses[-1:]

    def add_motors(self, stamp: float, intensity: np.ndarray) -> None:
        intensity = np.asarray(intensity, dtype=float)
        if not math.isfinite(intensity.sum()):     # NaN as 0 (a finite sum proves every value finite: as is)
            intensity = np.nan_to_num(intensity)
        # the mean as ndarray.mean computes it (the same sum, the same division), without its wrapper's cost
        mean = float(np.add.reduce(intensity) / intensity.size) if intensity.size else 0.0
        self._motors.append((stamp, bool((intensity > self.threshold).any()), mean))

    def add_motor_rows(self, stamps: np.ndarray, intensity: np.ndarray) -> None:
        """Many motor commands at once (rows of `intensity`, one per stamp): a served page's batch."""
        if not len(stamps):
            return
        intensity = np.asarray(intensity, dtype=float)
        if not math.isfinite(intensity.sum()):     # NaN as 0 (as add_motors)
            intensity = np.nan_to_num(intensity)
        on = (intensity > self.threshold).any(axis=1) if intensity.shape[1] else np.zeros(len(stamps), bool)
        mean = intensity.mean(axis=1) if intensity.shape[1] else np.zeros(len(stamps))
        self._motors.extend(zip(np.asarray(stamps, dtype=float).tolist(), on.tolist(), mean.tolist()))

    def add_poses(self, stamps: np.ndarray, positions: np.ndarray, valid: np.ndarray) -> None:
        """Many hand poses at once (rows of `positions`, one per stamp; an invalid one holds no place)."""
        positions = np.array(positions, dtype=float)
        self._poses.extend((t, p if v else None) for t, p, v in zip(np.asarray(stamps, dtype=float).tolist(),
                                                                    positions, np.asarray(valid).tolist()))

    def add_pose(self, stamp: float, position, valid: bool) -> None:
        self._poses.append((stamp, np.asarray(position, dtype=float).copy() if valid else None))

    def measure(self, onset: float, end: float) -> Measures:
        touching = integral = 0.0
        samples = sorted(self._motors, key=lambda s: s[0])
        for k, (t, on, mean) in enumerate(samples):
            t_next = samples[k + 1][0] if k + 1 < len(samples) else end
            a, b = max(t, onset), min(t_next, end)
            if b > a:
                touching += (b - a) * on
                integral += (b - a) * mean
        span = end - onset
        path = 0.0
        previous = None
        for t, position in sorted(self._poses, key=lambda s: s[0]):
            if t > end:
                break
            if t < onset:
                previous = position      # where the hand was at the onset
                continue
            if position is not None and previous is not None:
                path += float(np.linalg.norm(position - previous))
            previous = position
        return Measures(touching, integral / span if span > 0 else 0.0, path)
