"""The welcome page's device check (static/welcome.js), judged here: what the browser can vibrate
(an immersive session's controller with a haptic actuator, a gamepad's rumble), the frame rate it
held, and, when the study file asks (`device_check`, touch4d.study.design.DeviceCheck), its answers
to vibrations at random times and catch trials without one. The page measures; the server decides
against the study's criterion and keeps what was measured for the participant's manifest (`device`).
"""
from __future__ import annotations

import json
import math

from touch4d.study.design import DeviceCheck

MAX_BODY = 2048            # the report: a few numbers
MAX_TRIALS = 100           # a test longer than this is not a welcome page's
MAX_UA_CHARS = 256         # the user agent kept in the manifest
HAPTICS = ("xr-pulse", "gamepad-rumble", "none")
# The browser's name from its user agent, most specific first (a Quest's says Chrome too).
BROWSERS = (("OculusBrowser", "OculusBrowser"), ("Wolvic", "Wolvic"), ("PicoBrowser", "PicoBrowser"),
            ("SamsungBrowser", "SamsungBrowser"), ("Edg/", "Edge"), ("Firefox/", "Firefox"),
            ("HeadlessChrome", "HeadlessChrome"), ("Chromium/", "Chromium"), ("Chrome/", "Chrome"),
            ("Safari/", "Safari"))
EXPECTED = ('{"immersive": bool, "rumble": bool} and optionally "haptics" (xr-pulse, gamepad-rumble, none), '
            '"fps", "round_trip_ms", "clock_offset_ms" (numbers), "trials", "catch", "hits", "false_alarms" '
            f"(integers 0..{MAX_TRIALS}, hits <= trials, false_alarms <= catch)")


def browser_name(user_agent: str) -> str:
    """A short name of the browser a user agent string names (`other` for one not known)."""
    for token, name in BROWSERS:
        if token in user_agent:
            return name
    return "other"


def _number(value, low: float, high: float) -> float | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
            or not low <= value <= high:
        raise ValueError
    return round(float(value), 2)


def _count(value) -> int | None:
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= MAX_TRIALS:
        raise ValueError
    return value


def parse_report(body: bytes, user_agent: str = "") -> dict:
    """The page's report as the manifest keeps it (`device`), or ValueError saying what is expected."""
    try:
        said = json.loads(body)
        immersive, rumble = said["immersive"], said["rumble"]
        if not (isinstance(immersive, bool) and isinstance(rumble, bool)):
            raise TypeError
        haptics = said.get("haptics")
        if haptics is not None and haptics not in HAPTICS:
            raise TypeError
        report = {"browser": browser_name(user_agent), "user_agent": user_agent[:MAX_UA_CHARS],
                  "immersive": immersive, "rumble": rumble,
                  "haptics": haptics or ("xr-pulse" if immersive else "gamepad-rumble" if rumble else "none"),
                  "fps": _number(said.get("fps"), 0, 1000),
                  "round_trip_ms": _number(said.get("round_trip_ms"), 0, 60_000),
                  "clock_offset_ms": _number(said.get("clock_offset_ms"), -1e12, 1e12)}
        report.update({key: _count(said.get(key)) for key in ("trials", "catch", "hits", "false_alarms")})
    except (ValueError, KeyError, TypeError, AttributeError, RecursionError):
        raise ValueError(f"/device takes {EXPECTED}") from None
    for part, whole in (("hits", "trials"), ("false_alarms", "catch")):
        if report[part] is not None and (report[whole] is None or report[part] > report[whole]):
            raise ValueError(f"/device takes {EXPECTED}")
    return report


def answered(report: dict) -> bool:
    """Whether the report carries the vibration test's answers (not only what the browser can do)."""
    return report["hits"] is not None and report["false_alarms"] is not None


def failures(report: dict, check: DeviceCheck) -> list[str]:
    """Why a device fails the study's check, in words for the experimenter (empty: it passes; a report
    without the test's answers fails only for what it lacks already: no vibration, a low frame rate)."""
    why = []
    if report["haptics"] == "none" or not (report["immersive"] or report["rumble"]):
        why.append("no haptic actuator")
    if report["fps"] is not None and report["fps"] < check.min_fps:
        why.append(f"frame rate {report['fps']:g} below {check.min_fps:g}")
    if answered(report):
        if (report["trials"], report["catch"]) != (check.trials, check.catch):
            why.append(f"a test of {report['trials']} and {report['catch']} catch trials, not the study's "
                       f"{check.trials} and {check.catch}")
        if report["hits"] < check.min_hits:
            why.append(f"{report['hits']} of {report['trials']} vibrations felt, fewer than {check.min_hits}")
        if report["false_alarms"] > check.max_false_alarms:
            why.append(f"{report['false_alarms']} catch trials said felt, more than {check.max_false_alarms}")
    return why

