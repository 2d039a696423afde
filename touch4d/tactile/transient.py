"""Contact transients: a short vibration burst on the motors touching an object that was struck.

The paper's stimulus (eq. 1-3) renders where an object's front lies; it says nothing when objects
collide. Beside it, each contact event of the physics (topic `physics/contacts`) adds, on the motors
whose samples touch one of the struck objects, a burst
    V_i += a exp(-(t - t0) / tau)   for 0 <= t - t0 < duration, a = min(1, closing speed / full_speed)
(the motor intensity capped at 1): a decaying pulse, the cue of an impact that vibrotactile displays use
because an ERM motor cannot render a click. Events close together on the same objects add up to 1.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

TAU = 0.025            # s: the burst's decay
DURATION = 0.1         # s: after this a burst is over
FULL_SPEED = 1.5       # screen units / s: a strike this fast gives a full burst


@dataclass(frozen=True)
class Transient:
    """One burst: when it started (seconds, any clock), on which objects, how strong (0..1)."""

    start: float
    objects: frozenset
    strength: float


def strength(speed: float, full_speed: float = FULL_SPEED) -> float:
    """A burst's amplitude for a closing speed."""
    return float(min(1.0, max(0.0, speed) / full_speed))


def envelope(elapsed, amplitude: float, tau: float = TAU, duration: float = DURATION):
    """The burst's intensity `elapsed` seconds after it started (0 outside [0, duration))."""
    elapsed = np.asarray(elapsed, dtype=float)
    inside = (elapsed >= 0) & (elapsed < duration)
    return np.where(inside, amplitude * np.exp(-np.where(inside, elapsed, 0.0) / tau), 0.0)


def transient_intensity(transients, now: float, motor_hits: np.ndarray, tau: float = TAU,
                        duration: float = DURATION) -> np.ndarray:
    """(M,) intensity to add to the motors at time `now`; motor_hits: the object each motor's sample touches
    (-1: none)."""
    motor_hits = np.asarray(motor_hits)
    out = np.zeros(len(motor_hits))
    for t in transients:
        on = np.isin(motor_hits, list(t.objects))
        if on.any():
            out[on] += float(envelope(now - t.start, t.strength, tau, duration))
    return np.minimum(out, 1.0)


@dataclass
class TransientBank:
    """The bursts still running; `add` a contact event, `apply` them to a motor command's intensities."""

    tau: float = TAU
    duration: float = DURATION
    full_speed: float = FULL_SPEED
    active: list = field(default_factory=list)

    def add(self, a, b, speeds, now: float) -> None:
        """A `physics/contacts` message's rows (bodies a, b; closing speeds) as one burst per struck pair."""
        pairs: dict[frozenset, float] = {}
        for x, y, s in zip(np.asarray(a), np.asarray(b), np.asarray(speeds)):
            key = frozenset(int(o) for o in (x, y) if o >= 0)
            if key:
                pairs[key] = max(pairs.get(key, 0.0), float(s))
        for key, speed in sorted(pairs.items(), key=lambda item: sorted(item[0])):
            amp = strength(speed, self.full_speed)
            if amp > 0:
                self.active.append(Transient(now, key, amp))

    def apply(self, intensity: np.ndarray, motor_hits: np.ndarray, now: float) -> np.ndarray:
        """The intensities with the running bursts added (capped at 1); finished bursts are dropped."""
        self.active = [t for t in self.active if now - t.start < self.duration]
        if not self.active:
            return intensity
        extra = transient_intensity(self.active, now, motor_hits, self.tau, self.duration)
        return np.minimum(np.asarray(intensity, dtype=float) + extra, 1.0)
