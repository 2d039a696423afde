"""Recruiting online in a real browser (Debian's chromium, a Quest 3 emulated by iwer): two visitors of
the open link become two participants with folders and counterbalancing rows of their own, the same
PROLIFIC_PID twice one participant; the welcome page's device check passed by answering its vibrations
(felt when the controller pulsed, not felt on a catch trial) before joining, and failed by a page with
no haptic actuator, which is thanked and not counted. The pages run under the server's real CSP."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from touch4d.bus.testing import wait_until
from touch4d.study.design import load_study
from touch4d.study.plan import order_table
from touch4d.web.testing import chromium, context_options, iwer_script

from test_study_serve import experimenter_view, serve
from test_study_serve_recruit import open_link

pytestmark = pytest.mark.timeout(300)

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"
# The test's view of the check's pulses: the session the welcome page asks for, its actuators counted.
COUNT_PULSES = """
window.pulses = 0;
const requestSession = navigator.xr.requestSession.bind(navigator.xr);
navigator.xr.requestSession = async (...args) => {
  const session = await requestSession(...args);
  const counted = new WeakSet();
  const count = () => {
    for (const source of session.inputSources) {
      const actuator = source.gamepad && source.gamepad.hapticActuators && source.gamepad.hapticActuators[0];
      if (!actuator || counted.has(actuator)) continue;
      counted.add(actuator);
      const pulse = actuator.pulse.bind(actuator);
      actuator.pulse = (value, duration) => { window.pulses++; return pulse(value, duration); };
    }
  };
  count();
  session.addEventListener('inputsourceschange', count);
  setInterval(count, 20);
  return session;
};
"""


def visitor(browser, url, headset: bool = True, pulses: bool = False):
    """A participant's browser at `url`, its welcome page's check told to the server."""
    context = browser.new_context(**{**context_options(), "bypass_csp": False})
    if headset:
        context.add_init_script(iwer_script())
    if pulses:
        context.add_init_script(COUNT_PULSES)
    page = context.new_page()
    page.goto(url)
    # polled from here: the page's CSP forbids the string evaluation wait_for_function's polling uses
    wait_until(lambda: page.evaluate("document.body.dataset.vibration !== undefined"), timeout=30)
    return page


def join(page):
    with page.expect_navigation(timeout=150000):
        page.click("#join", no_wait_after=True)
    wait_until(lambda: page.evaluate("Boolean(window.touch4d && touch4d.connected && touch4d.setup !== null)"),
               timeout=90)       # polled from here (the CSP forbids wait_for_function's string evaluation)


def press(page, button):
    """Press and release a button of the emulated right controller (its select or squeeze event)."""
    page.evaluate(f"xr.controllers.right.updateButtonValue('{button}', 1)")
    page.wait_for_timeout(200)
    page.evaluate(f"xr.controllers.right.updateButtonValue('{button}', 0)")
    page.wait_for_timeout(200)


def manifest(served, participant):
    return json.loads((served.out / participant / "manifest.json").read_text())


def test_two_visitors_become_two_participants_and_the_same_prolific_id_is_one(tmp_path):
    table = order_table(load_study(STUDY))
    with serve(tmp_path, "--open-link", "--leave-after", "600") as served, chromium() as browser:
        link = open_link(served)
        first = visitor(browser, f"{link}&PROLIFIC_PID=60aa&STUDY_ID=st&SESSION_ID=s1")
        second = visitor(browser, f"{link}&PROLIFIC_PID=60bb&STUDY_ID=st&SESSION_ID=s2")
        assert first.evaluate("location.search") == ""                          # the token left the address bar
        assert first.evaluate("document.body.dataset.vibration") == "headset"
        join(first)
        join(second)
        # the same PROLIFIC_PID from another browser: P01's link again (its WebXR page: it has joined)
        again = browser.new_context(**context_options()).new_page()
        response = again.goto(f"{link}&PROLIFIC_PID=60aa&STUDY_ID=st&SESSION_ID=s3")
        assert "participant=P01&token=" in response.url and '<canvas id="view">' in response.text()
        view = experimenter_view(served)
        assert sorted(p["participant"] for p in view["participants"]) == ["P01", "P02"]
        assert view["counts"]["open link"] == 2
        for participant, pid, row in (("P01", "60aa", 0), ("P02", "60bb", 1)):
            said = manifest(served, participant)
            assert said["condition_order"] == table[row]                      # its own counterbalancing row
            assert said["platform"]["PROLIFIC_PID"] == pid
            assert said["device"]["browser"] == "HeadlessChrome" and said["device"]["haptics"] == "xr-pulse"
        assert view["summary"]["rows_filled"][:3] == [1, 1, 0]


def test_the_device_check_passed_by_answering_its_vibrations_and_failed_without_an_actuator(tmp_path):
    checked = tmp_path / "checked.yaml"
    checked.write_text((REPO / STUDY).read_text() + "\ndevice_check: {trials: 2, catch: 2, min_hits: 2, "
                       "max_false_alarms: 0, min_fps: 0}\n")
    with serve(tmp_path, "--open-link", "--leave-after", "600", "--return-url", "https://example.org/back",
               study=str(checked)) as served, chromium() as browser:
        link = open_link(served)
        # no headset, no gamepad: thanked, not counted, its place freed
        bare = visitor(browser, f"{link}&PROLIFIC_PID=61aa", headset=False)
        wait_until(lambda: bare.evaluate("document.body.dataset.check") == "failed", timeout=30)
        assert "not been counted" in bare.inner_text("#vibration") and not bare.is_visible("#join")
        assert bare.is_visible("a[href='https://example.org/back']")
        assert experimenter_view(served)["participants"] == [] and not (served.out / "P01").exists()
        # a headset: the vibration test, each answered as felt when the controller pulsed
        page = visitor(browser, f"{link}&PROLIFIC_PID=61bb", pulses=True)
        wait_until(lambda: page.is_visible("#check-start"), timeout=30)
        assert page.is_disabled("#join")
        page.click("#check-start")
        seen = 0
        for _ in range(4):    # in the session the page is hidden: the trigger says felt, the grip not felt
            wait_until(lambda: page.evaluate("!document.getElementById('check-answer').hidden"), timeout=30)
            pulses = page.evaluate("window.pulses")
            press(page, "trigger" if pulses > seen else "squeeze")     # felt only what the controller played
            seen = pulses
        wait_until(lambda: page.evaluate("document.body.dataset.check") == "passed", timeout=30)
        assert page.evaluate("window.pulses") == 2 and not page.is_disabled("#join")
        join(page)
        view = experimenter_view(served)
        assert [p["participant"] for p in view["participants"]] == ["P01"] and view["counts"]["device failed"] == 1
        device = manifest(served, "P01")["device"]
        assert (device["trials"], device["catch"], device["hits"], device["false_alarms"]) == (2, 2, 2, 0)
        assert device["passed"] and device["fps"] > 0 and device["round_trip_ms"] >= 0
        assert device["clock_offset_ms"] is not None



def test_a_participant_who_answers_every_trial_follows_finish_to_the_completion_url(tmp_path):
    one = tmp_path / "one.yaml"          # one condition: the quick plan's 14 trials, answered on the page
    one.write_text((REPO / STUDY).read_text().replace("conditions: [visual, touch, visual+touch]",
                                                      "conditions: [visual]"))
    complete = "https://app.prolific.com/submissions/complete"
    with serve(tmp_path, "--open-link", "--iti", "0", "--complete-url", complete, "--completion-code", "C0DE42",
               study=str(one)) as served, chromium() as browser:
        page = visitor(browser, f"{open_link(served)}&PROLIFIC_PID=62aa")
        requested = []         # the platform's page is not reached from here: what the browser asked for
        page.on("request", lambda request: requested.append(request.url))
        join(page)
        while not page.evaluate("Boolean(document.getElementById('finish'))"):
            page.evaluate("(() => { const b = document.querySelector('#study button'); if (b) b.click(); })()")
            page.wait_for_timeout(150)     # the next trial's buttons (the page server paces a page's answers)
        page.click("#finish")
        wait_until(lambda: f"{complete}?cc=C0DE42" in requested, timeout=30)
        assert f"{served.url}/done" in requested
        assert experimenter_view(served)["participants"][0]["state"] == "done"
