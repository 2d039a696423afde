"""The welcome page's device check judged without a server (touch4d.web.devicecheck): the report
checked, the browser named from its user agent, a device failing for what it lacks or felt; the study
file's `device_check` key and its checks (touch4d.study.design.DeviceCheck)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from touch4d.errors import ConfigError
from touch4d.study.design import DeviceCheck, load_study
from touch4d.web.devicecheck import answered, browser_name, failures, parse_report

REPO = Path(__file__).resolve().parents[1]
QUEST = ("Mozilla/5.0 (X11; Linux x86_64; Quest 3) AppleWebKit/537.36 (KHTML, like Gecko) OculusBrowser/35.1 "
         "SamsungBrowser/4.0 Chrome/126.0 VR Safari/537.36")


def report(**said) -> dict:
    return parse_report(json.dumps({"immersive": True, "rumble": False, **said}).encode(), QUEST)


def test_browsers_are_named_from_their_user_agent():
    assert browser_name(QUEST) == "OculusBrowser"
    assert browser_name("Mozilla/5.0 (X11; Linux x86_64; rv:128.0) Gecko/20100101 Firefox/128.0") == "Firefox"
    assert browser_name("Mozilla/5.0 AppleWebKit/537.36 (KHTML, like Gecko) HeadlessChrome/131.0 Safari/537.36") \
        == "HeadlessChrome"
    assert browser_name("curl/8.0") == "other"


def test_a_device_passes_or_fails_the_studys_criterion():
    check = DeviceCheck(trials=8, catch=4, min_hits=6, max_false_alarms=1, min_fps=45)
    good = report(fps=72, trials=8, catch=4, hits=7, false_alarms=1, round_trip_ms=20, clock_offset_ms=-5)
    assert answered(good) and failures(good, check) == [] and good["haptics"] == "xr-pulse"
    assert good["browser"] == "OculusBrowser" and good["user_agent"] == QUEST
    assert failures(report(fps=72), check) == [] and not answered(report(fps=72))     # the test still to run
    assert failures(report(immersive=False, fps=60), check) == ["no haptic actuator"]
    assert failures(report(fps=30), check) == ["frame rate 30 below 45"]
    assert failures(report(trials=8, catch=4, hits=5, false_alarms=2), check) == [
        "5 of 8 vibrations felt, fewer than 6", "2 catch trials said felt, more than 1"]
    assert failures(report(trials=2, catch=0, hits=2, false_alarms=0), check)[0].startswith("a test of 2")


@pytest.mark.parametrize("said", [{"immersive": "yes", "rumble": False}, {"immersive": True},
                                  {"immersive": True, "rumble": False, "fps": "fast"},
                                  {"immersive": True, "rumble": False, "hits": 3},
                                  {"immersive": True, "rumble": False, "hits": 5, "trials": 4},
                                  {"immersive": True, "rumble": False, "trials": 10**6},
                                  {"immersive": True, "rumble": False, "haptics": "telepathy"},
                                  {"immersive": True, "rumble": False, "fps": float("inf")}, [1], "x"])
def test_a_report_that_is_not_the_pages_is_refused_saying_what_is_expected(said):
    with pytest.raises(ValueError, match='/device takes {"immersive": bool'):
        parse_report(json.dumps(said).encode())
    with pytest.raises(ValueError):
        parse_report(b"\xff{")


def test_the_study_files_device_check_key(tmp_path):
    study = tmp_path / "s.yaml"
    base = (REPO / "config/studies/paper.yaml").read_text()
    assert load_study(REPO / "config/studies/paper.yaml").device_check is None
    study.write_text(base + "\ndevice_check: {trials: 6, catch: 2}\n")
    assert load_study(study).device_check == DeviceCheck(trials=6, catch=2, min_hits=6, max_false_alarms=1)
    for bad, key in (("{trials: 4, min_hits: 5}", "device_check.min_hits"),
                     ("{catch: 0}", "device_check.max_false_alarms"),
                     ("{trials: 0}", "device_check.trials"), ("{min_fps: -1}", "device_check.min_fps"),
                     ("{trial: 3}", "device_check.trial")):
        study.write_text(base + f"\ndevice_check: {bad}\n")
        with pytest.raises(ConfigError, match=f"key '{key}'"):
            load_study(study)
