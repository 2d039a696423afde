"""A served study in a real browser (Debian's chromium, Quest 3s emulated by iwer): participants
join by their link, touch with the controller in a touch trial (the page's own touch: its pulses
recorded by wrapping the actuator's `pulse`, here only), leave and come back to resume, two at once
each a session of the server's own with its folder; a third is told the study is full (503), a
forged or mismatched link refused. What the page played and where its hand was reach the
participant's trials.csv and MCAP log."""
from __future__ import annotations

import json

import numpy as np
import pytest

from touch4d.bus.testing import wait_until
from touch4d.log.reader import LogReader
from touch4d.study.design import load_study
from touch4d.study.plan import quick_plan
from touch4d.web.testing import chromium, context_options, enter_vr, headset_page, wait_connected

from test_study_serve import experimenter_view, invite, serve
from test_web_haptics_browser import CENTER, RECORD_PULSES

pytestmark = pytest.mark.timeout(300)

STUDY = "config/studies/paper.yaml"


def join(browser, link):
    """Open a link as a participant, press Join, enter VR looking away (cheap frames)."""
    page = headset_page(browser, link, 320, 180)
    with page.expect_navigation(timeout=150000):   # the server starts the participant's session meanwhile
        page.click("#join", no_wait_after=True)
    wait_connected(page, 90)
    enter_vr(page)
    page.evaluate("xr.position.set(0, 1.5, 0.8); xr.quaternion.set(0, 1, 0, 0)")
    return page


def state(served, participant):
    return next(p for p in experimenter_view(served)["participants"] if p["participant"] == participant)


def press_a_until(page, predicate, timeout=30):
    page.evaluate("xr.controllers.right.updateButtonValue('a-button', 1)")
    try:
        return wait_until(predicate, timeout=timeout)
    finally:
        page.evaluate("xr.controllers.right.updateButtonValue('a-button', 0)")


def test_join_touch_leave_resume_and_a_second_participant(tmp_path, capsys):
    study = load_study(STUDY)
    assert quick_plan(study, "P03")[0].condition == "touch"          # this participant starts touching
    with serve(tmp_path, "--max-participants", "2", "--leave-after", "2", "--iti", "0.2") as served, \
            chromium() as browser:
        link = invite(served, "P03", capsys=capsys)
        page = join(browser, link)
        page.evaluate(RECORD_PULSES)
        # the session opens with a break; A goes on to the first trial, a touch trial
        page.wait_for_function("touch4d.study && touch4d.study.phase === 'break'", timeout=60000)
        press_a_until(page, lambda: page.evaluate("touch4d.study && touch4d.study.phase === 'stimulus'"))
        assert page.evaluate("touch4d.drawObjects") is False
        page.evaluate("xr.controllers.right.position.set({}, {}, {})".format(*CENTER))
        page.wait_for_function("pulses.some(([hand, value]) => value > 0.05)", timeout=60000)
        index = page.evaluate("touch4d.study.index")
        assert state(served, "P03")["state"] == "running"
        assert page.evaluate("touch4d.setup.batch_s") > 0 and page.evaluate("touch4d.setup.touch") == "page"
        # leaving: paused at once, the session stopped after --leave-after
        page.context.close()
        wait_until(lambda: state(served, "P03")["state"] == "paused", timeout=30)
        wait_until(lambda: state(served, "P03")["state"] == "left", timeout=30)
        # a second participant meanwhile, in their own session and folder
        other = join(browser, invite(served, "P04", capsys=capsys))
        other.wait_for_function("touch4d.study && touch4d.study.phase === 'break'", timeout=60000)
        # the link again: the session resumes at the trial without a row
        page = join(browser, link)
        page.wait_for_function("touch4d.study && touch4d.study.phase === 'break'", timeout=60000)
        press_a_until(page, lambda: page.evaluate("touch4d.study && touch4d.study.phase === 'stimulus'"))
        assert page.evaluate("touch4d.study.index") == index       # the trial left unanswered, again
        assert not (served.out / "P03" / "trials.csv").exists() or \
            len((served.out / "P03" / "trials.csv").read_text().splitlines()) <= 1
        both = {p["participant"]: p["state"] for p in experimenter_view(served)["participants"]}
        assert both == {"P03": "running", "P04": "running"}
        for participant in ("P03", "P04"):
            assert (served.out / participant / "manifest.json").exists()
        # refused in the browser too: full (HTTP 503, a page that says so), forged, mismatched (403)
        third = headset_page(browser, invite(served, "P05", capsys=capsys), 320, 180)
        with third.expect_navigation(timeout=60000) as refused:
            third.click("#join", no_wait_after=True)
        assert refused.value.status == 503 and "full" in third.content()
        for url, text in ((f"{served.url}/?participant=P06&token=AAAAAAAAAAAAAAAAAAAAAA", "needs its link"),
                          (link.replace("participant=P03", "participant=P04"), "does not match")):
            refused_page = browser.new_context(**context_options(320, 180)).new_page()
            response = refused_page.goto(url)
            assert response.status == 403 and text in refused_page.content()
            refused_page.context.close()
        for opened in (other, page, third):
            opened.context.close()
    # the server logged what the page tracked and played, in batches with the page's stamps
    logs = sorted((served.out / "P03").rglob("*.mcap"))
    assert len(logs) == 2     # one log per start of the session
    topics = {t for log in logs for t in LogReader(log).topics()}
    assert {"hand/poses", "tactile/played", "study/trial", "scene/state"} <= topics, topics
    felt = [np.max(m.decode()["intensity"], initial=0.0) for log in logs
            for m in LogReader(log).messages({"tactile/played"})]
    assert max(felt) > 0.05
    poses = [m.decode() for log in logs for m in LogReader(log).messages({"hand/poses"})]
    stamps = np.concatenate([b["stamps"] for b in poses])
    assert len(stamps) > 50 and np.all(np.diff(stamps[:len(poses[0]["stamps"])]) > 0)
    assert any(b["valid"].any() for b in poses)
    manifest = json.loads((served.out / "P03" / "manifest.json").read_text())
    # one entry per start of the session: what its page said of itself (a start whose page left within
    # its first second has no frame rate yet)
    assert len(manifest["page"]) == 2 and all(e["haptics"] == "pulse" for e in manifest["page"])
    assert any((e["fps_median"] or 0) > 0 for e in manifest["page"])


def test_the_welcome_page_takes_the_token_out_of_the_address_bar(tmp_path, capsys):
    """What the browser keeps in its history or shows over a shoulder holds no secret; the cookie
    carries the participant on (a reload still shows their welcome)."""
    with serve(tmp_path) as served, chromium() as browser:
        link = invite(served, "P01", capsys=capsys)
        page = browser.new_context(**context_options(320, 180)).new_page()
        response = page.goto(link)
        assert response.status == 200 and page.locator("#join").count() == 1
        page.wait_for_function("!location.search")
        assert "token" not in page.url and page.url == f"{served.url}/"
        assert page.reload().status == 200 and page.locator("#join").count() == 1
        page.context.close()
