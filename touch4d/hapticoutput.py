"""A haptic output, and the one guard that keeps it safe.

`HapticOutput` is what every actuator does (the glove's CAN boards: touch4d.boards.driver's
`MotorDriver`; the page's controller: touch4d.web.haptics's `PageOutput`): take per-motor
intensities 0..1, turn everything off. `OUTPUTS` names the implementations (as python-can names its
interfaces: "module:Class", imported when asked for, so this module needs none of them);
`register_output` adds one, `output_class` finds one.

`OutputGuard` owns the fail-safe rules every output obeys, as pure logic on the time it is given:
- a stop (`safety/stop`) -> 0, and commands ignored for `stop_hold_s` (inf: until restart);
- the study's gate closed -> 0 (the command is held; when the gate opens it plays again only if
  still younger than `max_age_s`);
- a command older than `max_age_s` when it arrives (its age from its own stamp; 0 turns the check
  off) -> 0, never on, and it does not feed the watchdog;
- no command for `watchdog_s` -> 0.
`reason(now)` says which rule holds the output at 0 now, in that order.
"""
from __future__ import annotations

import abc
import importlib
import math
from collections import Counter

import numpy as np

from touch4d.errors import ConfigError

STOP, GATE, STALE, WATCHDOG = "stop", "gate", "stale", "watchdog"   # why an output is 0, first rule first


class OutputGuard:
    """The fail-safe rules of one output of `motors` intensities (see the module doc); counts what it
    refused in `counts` (`ignored_during_stop`, `stale_command`, `command_from_future`, `stops`)."""

    def __init__(self, motors: int, watchdog_s: float, max_age_s: float = 0.0, stop_hold_s: float = math.inf,
                 gate_open: bool = True, counts: Counter | None = None):
        self.motors = motors
        self.watchdog_s, self.max_age_s, self.stop_hold_s = watchdog_s, max_age_s, stop_hold_s
        self.gate_open = gate_open
        self.counts = Counter() if counts is None else counts
        self.intensity = np.zeros(motors)
        self.last_command_at: float | None = None   # when the last accepted command arrived (feeds the watchdog)
        self.stop_until = -math.inf
        self.stale = False                           # the last command was stale
        self._age: float | None = None               # the held command's age when it arrived

    def is_stale(self, age: float | None) -> bool:
        """Whether a command `age` seconds old (from its own stamp; None: unknown) is too old to use."""
        return bool(self.max_age_s) and age is not None and not age <= self.max_age_s   # NaN age: stale

    def command(self, intensity: np.ndarray, now: float, age: float | None = None) -> bool:
        """A command: one intensity per motor. False when a stop hold ignores it (nothing changed)."""
        if now < self.stop_until:
            self.counts["ignored_during_stop"] += 1
            return False
        self.stale = self.is_stale(age)
        if self.stale:
            self.counts["stale_command"] += 1
            self.intensity = np.zeros(self.motors)
            return True
        if self.max_age_s and age is not None and age < -self.max_age_s:
            self.counts["command_from_future"] += 1   # the sender's clock is ahead: the age check is blind
        self.intensity = np.array(intensity, dtype=np.float64)   # a copy: the caller's array may change
        self.last_command_at, self._age = now, age
        return True

    def stop(self, now: float) -> None:
        """A safety stop: 0 now, and commands ignored for `stop_hold_s`."""
        self.stop_until = now + self.stop_hold_s
        self.counts["stops"] += 1
        self.silence()

    def silence(self) -> None:
        """The commands' source is gone: 0 now, as the watchdog would be; the next command plays."""
        self.intensity = np.zeros(self.motors)
        self.last_command_at = None

    def set_gate(self, open_: bool, now: float) -> bool:
        """The study's gate; True when it changed. An opening gate drops a held command grown stale."""
        if open_ == self.gate_open:
            return False
        self.gate_open = open_
        if open_ and self.last_command_at is not None and self._age is not None \
                and self.is_stale(self._age + (now - self.last_command_at)):
            self.intensity = np.zeros(self.motors)
        return True

    def silent(self, now: float) -> bool:
        """No command within `watchdog_s`."""
        return self.last_command_at is None or now - self.last_command_at > self.watchdog_s

    def holds_off(self, now: float) -> str | None:
        """STOP or GATE when the output must be 0 whatever the commands say, else None."""
        if now < self.stop_until:
            return STOP
        return None if self.gate_open else GATE

    def reason(self, now: float) -> str | None:
        """Why the output is 0 now (STOP, GATE, STALE, WATCHDOG: the first rule that holds), None: it plays."""
        held = self.holds_off(now)
        if held:
            return held
        if self.stale:
            return STALE
        return WATCHDOG if self.silent(now) else None

    def output(self, now: float) -> np.ndarray:
        """The intensities to play now: the command's, or 0 while a rule holds."""
        return np.zeros(self.motors) if self.reason(now) else self.intensity

    def expires(self, now: float) -> float:
        """When time alone next changes `reason` (a stop hold ending, the watchdog tripping); inf: never."""
        due = self.stop_until if now < self.stop_until else math.inf
        if not self.silent(now):
            due = min(due, self.last_command_at + self.watchdog_s)
        return due


class HapticOutput(abc.ABC):
    """An actuator: plays per-motor intensities 0..1 through its `guard`, and turns everything off."""

    guard: OutputGuard

    @abc.abstractmethod
    def play(self, intensity: np.ndarray, now: float, age: float | None = None) -> None:
        """A command: one intensity per motor (glove file order), `age` seconds old; the guard decides."""

    @abc.abstractmethod
    def off(self, now: float) -> None:
        """Everything off now (the commands' source is gone); the next command plays again."""


# name -> "module:Class" of each HapticOutput (imported only when asked for)
OUTPUTS: dict[str, str | type] = {
    "can": "touch4d.boards.driver:MotorDriver",
    "page": "touch4d.web.haptics:PageOutput",
}


def register_output(name: str, target: str | type) -> None:
    """Add an output: a HapticOutput subclass, or "module:Class" naming one."""
    OUTPUTS[name] = target


def output_class(name: str) -> type[HapticOutput]:
    """The HapticOutput registered as `name`; ConfigError for a name not registered or not an output."""
    target = OUTPUTS.get(name)
    if target is None:
        raise ConfigError(None, "output", f"one of {', '.join(sorted(OUTPUTS))}", name)
    if isinstance(target, str):
        module, _, attr = target.partition(":")
        target = getattr(importlib.import_module(module), attr)
    if not (isinstance(target, type) and issubclass(target, HapticOutput)):
        raise ConfigError(None, "output", f"a HapticOutput subclass for {name!r}", target)
    return target
