"""Before consent, the welcome page of a served study asks the browser what it can vibrate and
says so (Debian's chromium without a headset: nothing; with iwer's Quest 3: a headset). The study's
`without_vibration` refuses such a browser's Join (or lets it in), and the experimenter's page shows
what each participant's browser could do. The page runs under the server's real Content-Security-Policy."""
from __future__ import annotations

from pathlib import Path

import pytest

from touch4d.bus.testing import wait_until
from touch4d.web.testing import chromium, context_options, iwer_script

from test_study_serve import Browser, experimenter_view, invite, serve

pytestmark = pytest.mark.timeout(240)

REPO = Path(__file__).resolve().parents[1]


def welcome(browser, link, headset: bool):
    options = {**context_options(), "bypass_csp": False}      # the page as a participant's browser runs it
    context = browser.new_context(**options)
    if headset:
        context.add_init_script(iwer_script())
    page = context.new_page()
    errors = []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.goto(link)
    # polled from here: the page's CSP forbids the string evaluation wait_for_function's polling uses
    wait_until(lambda: page.evaluate("document.body.dataset.vibration !== undefined"), timeout=30)
    return page, errors


def test_a_browser_that_cannot_vibrate_is_told_before_consent_and_cannot_join(tmp_path, capsys):
    with serve(tmp_path) as served, chromium() as browser:
        page, errors = welcome(browser, invite(served, "P01", capsys=capsys), headset=False)
        assert page.evaluate("document.body.dataset.vibration") == "none"
        assert page.is_visible("#vibration") and "cannot vibrate" in page.inner_text("#vibration")
        assert page.is_disabled("#join")
        assert page.evaluate("location.search") == ""          # the token left the address bar
        assert not [e for e in errors if "Content Security Policy" in e], errors
        # the server refuses the join itself, whatever the page does
        status = page.evaluate("fetch('/join', {method: 'POST'}).then(r => r.status)")
        assert status == 403
        headset, errors = welcome(browser, invite(served, "P02", capsys=capsys), headset=True)
        assert headset.evaluate("document.body.dataset.vibration") == "headset"
        assert not headset.is_visible("#vibration") and not headset.is_disabled("#join")
        view = experimenter_view(served)
        found = {p["participant"]: p["vibration"] for p in view["participants"]}
        assert found == {"P01": "none", "P02": "headset"} and view["counts"]["no vibration"] == 1
        assert "P01: its browser cannot vibrate" in served.text
        # a report that is not two booleans: 400, nothing kept
        status = headset.evaluate("fetch('/device', {method: 'POST', body: JSON.stringify({immersive: 'yes'})})"
                                  ".then(r => r.status)")
        assert status == 400


def test_a_study_that_allows_it_lets_such_a_browser_join_and_says_what_it_will_feel(tmp_path, capsys):
    study = tmp_path / "allow.yaml"
    study.write_text((REPO / "config/studies/paper.yaml").read_text() + "\nwithout_vibration: allow\n")
    with serve(tmp_path, study=str(study)) as served, chromium() as browser:
        page, _ = welcome(browser, invite(served, "P01", capsys=capsys), headset=False)
        assert page.evaluate("document.body.dataset.vibration") == "none"
        assert "you will feel nothing" in page.inner_text("#vibration") and not page.is_disabled("#join")
        assert experimenter_view(served)["counts"]["no vibration"] == 0
