"""The study server over HTTP on loopback (`touch4d study serve`, a real process): links, consent,
403 for a forged, revoked or mismatched link, 503 when full, a participant's stack started on join
under their namespace and stopped when they leave, the experimenter's page."""
from __future__ import annotations

import http.cookiejar
import json
import os
import re
import signal
import subprocess
import sys
import threading
import urllib.error
import urllib.request
from contextlib import contextmanager
from pathlib import Path

import pytest

from touch4d.bus.realtime import realtime_permitted
from touch4d.bus.testing import wait_until
from touch4d.cli import main as cli_main

pytestmark = pytest.mark.timeout(240)

REPO = Path(__file__).resolve().parents[1]
STUDY = "config/studies/paper.yaml"


class Served:
    """A `touch4d study serve` process and what it printed."""

    def __init__(self, proc, out: Path):
        self.proc, self.out = proc, out
        self.lines: list[str] = []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()
        wait_until(lambda: any(line.startswith("experimenter page:") for line in self.lines) or proc.poll() is not None,
                   timeout=60)
        text = "\n".join(self.lines)
        self.url = re.search(r"serving (http://\S+)/ for", text).group(1)
        self.experimenter = re.search(r"experimenter page: (\S+)", text).group(1)

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))

    @property
    def text(self) -> str:
        return "\n".join(self.lines)


@contextmanager
def serve(tmp_path, *args, study=STUDY):
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-u", "-m", "touch4d.cli", "study", "serve", study, "--out", str(out),
                             "--port", "0", "--quick", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        yield Served(proc, out)
    finally:
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(30)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass
        try:
            os.killpg(proc.pid, signal.SIGKILL)   # whatever is left of its group
        except ProcessLookupError:
            pass
        proc.wait()


def invite(served, participant, *extra, capsys=None) -> str:
    assert cli_main(["study", "invite", str(served.out), participant, "--no-qr", *extra]) == 0
    return capsys.readouterr().out.strip().splitlines()[-1] if capsys else ""


class Browser:
    """A cookie-keeping HTTP client: (status, text) for each request."""

    def __init__(self):
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))

    def get(self, url, data=None, timeout=120):
        try:
            with self.opener.open(url, data=data, timeout=timeout) as response:
                return response.status, response.read().decode()
        except urllib.error.HTTPError as exc:
            return exc.code, exc.read().decode()


def experimenter_view(served):
    status, text = Browser().get(served.experimenter.replace("/experimenter?", "/experimenter?format=json&"))
    assert status == 200
    return json.loads(text)


def test_links_consent_and_refusals(tmp_path, capsys):
    with serve(tmp_path) as served:
        # no --max-participants: four per core this process may use
        assert f"for up to {4 * len(os.sched_getaffinity(0))} participants" in served.text
        link = invite(served, "P01", capsys=capsys)
        assert link.startswith(f"{served.url}/?participant=P01&token=")
        page = Browser()
        status, text = page.get(link)
        assert status == 200 and "By pressing Join you agree" in text and "enter VR" in text and 'id=join' in text
        # forged: 403, logged once however often
        for _ in range(3):
            assert Browser().get(f"{served.url}/?participant=P01&token=AAAAAAAAAAAAAAAAAAAAAA")[0] == 403
        # a participant id that is not its token's
        status, text = Browser().get(link.replace("participant=P01", "participant=P02"))
        assert status == 403 and "does not match" in text
        # revoked: the link and its cookie stop working
        assert cli_main(["study", "invite", str(served.out), "P01", "--revoke"]) == 0
        assert Browser().get(link)[0] == 403
        assert page.get(f"{served.url}/")[0] == 403
        view = experimenter_view(served)
        assert view["counts"]["forged"] >= 4 and view["counts"]["mismatched"] == 1
        # a new link works again
        assert Browser().get(invite(served, "P01", capsys=capsys))[0] == 200
    assert served.text.count("forged, expired or revoked") == 1
    assert oct((served.out / "invites.json").stat().st_mode & 0o777) == "0o600"


def test_join_starts_the_participants_stack_and_a_second_is_refused_when_full(tmp_path, capsys):
    with serve(tmp_path, "--max-participants", "1", "--leave-after", "600") as served:   # no page opens here
        p1, p2 = Browser(), Browser()
        assert p1.get(invite(served, "P01", capsys=capsys))[0] == 200
        assert p2.get(invite(served, "P02", capsys=capsys))[0] == 200
        status, text = p1.get(f"{served.url}/join", data=b"")
        assert status == 200 and '<canvas id="view">' in text          # the WebXR page, through the server
        assert p1.get(f"{served.url}/static/main.js")[0] == 200
        status, text = p2.get(f"{served.url}/join", data=b"")
        assert status == 503 and "full" in text
        view = experimenter_view(served)
        states = {p["participant"]: p["state"] for p in view["participants"]}
        assert states == {"P01": "running", "P02": "invited"} and view["counts"]["full"] == 1
        log = (served.out / "P01" / "serve.log").read_text()
        assert "every topic under P01/" in log and "loaded in container participants-1" in log
        # launch/study-serve.yaml's haptic loop is `realtime`: the server's loop thread, which the
        # page's messages pass through, and the container's run SCHED_FIFO (each thread alone:
        # tests/test_bus_container.py) where permitted, else at normal priority; the log says which
        permitted = realtime_permitted()
        (container,) = _containers(served.proc.pid)
        for pid in (served.proc.pid, container):
            assert os.sched_getscheduler(pid) & ~os.SCHED_RESET_ON_FORK == (os.SCHED_FIFO if permitted else os.SCHED_OTHER)
        assert ("the container's loop runs at real-time priority" if permitted else
                "real-time priority not permitted") in log
        wait_until(lambda: (served.out / "P01" / "manifest.json").exists(), timeout=60)
        # the study node runs P01's session (its namespace's study/trial reaches the experimenter's page)
        wait_until(lambda: [p for p in experimenter_view(served)["participants"]
                            if p["participant"] == "P01" and p["of"]], timeout=60)
        # the experimenter pauses P01's session (its study node says so on P01/study/trial)
        lab = Browser()
        assert lab.get(served.experimenter)[0] == 200
        assert lab.get(f"{served.url}/experimenter/pause", data=b"participant=P01")[0] == 200
        wait_until(lambda: [p for p in experimenter_view(served)["participants"]
                            if p["participant"] == "P01" and p["phase"] == "paused"], timeout=60)
    # the terminal said each in a line: the join, the refusal while full, and the shutdown
    served.thread.join(10)          # its last lines read
    said = served.text.splitlines()
    assert any(re.match(r"\d\d:\d\d:\d\d P01 joined: starting its stack .*; 1 of 1 running", line) for line in said)
    assert any(re.match(r"\d\d:\d\d:\d\d P02: refused, the study is full \(1 of 1 running", line) for line in said)
    assert any(line.endswith("stopping: 1 running participants' stacks stop (each resumes at its next trial when "
                             "its link is opened again)") for line in said), served.text
    assert said[-1].endswith(" stopped")


def _processes_with(text: str) -> list[int]:
    """The processes whose command line holds `text` (this test's folder: its server's stacks)."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                if text in (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace"):
                    found.append(int(entry.name))
            except OSError:
                pass
    return found


def _starts(out: Path, participant: str = "P01") -> int:
    """How often a participant's study node started its session (manifest.json; 0 before it is written)."""
    try:
        return len(json.loads((out / participant / "manifest.json").read_text())["starts"])
    except FileNotFoundError:
        return 0


def _containers(server_pid: int) -> list[int]:
    """The server's containers (touch4d.bus.container): the processes of participants' stacks."""
    found = []
    for pid in _processes_with("--container"):
        try:
            if int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1]) == server_pid:
                found.append(pid)
        except (OSError, ValueError, IndexError):
            pass
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def test_a_crashed_container_comes_back_whole_a_killed_server_takes_its_stacks_and_everyone_resumes(tmp_path, capsys):
    with serve(tmp_path, "--leave-after", "600") as served:          # no page opens here
        links, pages = {}, {}
        for participant in ("P01", "P02"):
            links[participant] = invite(served, participant, capsys=capsys)
            page = pages[participant] = Browser()
            page.get(links[participant])
            assert page.get(f"{served.url}/join", data=b"")[0] == 200
        for participant in ("P01", "P02"):
            wait_until(lambda: _starts(served.out, participant) >= 1, timeout=90)   # its session began
            status, text = pages[participant].get(f"{served.url}/")
            assert status == 200 and '<canvas id="view">' in text                  # its page, from its stack
        first = _containers(served.proc.pid)
        assert 1 <= len(first) <= 2                                    # spread over the cores first, then shared
        for pid in first:
            os.kill(pid, signal.SIGKILL)                               # a crash takes every stack of it
        # the server starts each container again with its stacks: each study node resumes its session
        for participant in ("P01", "P02"):
            wait_until(lambda: _starts(served.out, participant) >= 2, timeout=90)
        back = _containers(served.proc.pid)
        assert len(back) == len(first) and not set(back) & set(first)
        wait_until(lambda: len(re.findall(r"participants-\d was killed by SIGKILL with \d group\(s\)", served.text))
                   == len(first), timeout=10)
        assert all(f"{participant}: its stack's process died; started again" in served.text for participant in ("P01", "P02"))
        wait_until(lambda: (served.out / "P01" / "serve.log").read_text().count("P01: 5 node(s) loaded in container")
                   == 2, timeout=30)
        # each page is served again, from the port its stack's new process bound (its ready file says which)
        for participant in ("P01", "P02"):
            assert wait_until(lambda: pages[participant].get(f"{served.url}/")[0] == 200, timeout=30)
            assert '<canvas id="view">' in pages[participant].get(f"{served.url}/")[1]
        served.proc.send_signal(signal.SIGKILL)                         # the server alone, killed
        served.proc.wait()
        wait_until(lambda: not _alive(back[0]), timeout=30)            # its containers go with it
    with serve(tmp_path, "--leave-after", "600") as again:
        page = Browser()
        link = links["P01"]
        status, text = page.get(link.replace(served.url, again.url))   # the same link, the same token
        assert status == 200 and "id=join" in text
        assert page.get(f"{again.url}/join", data=b"")[0] == 200
        # the study node started again on the same session (it resumes at the first trial without a row)
        wait_until(lambda: _starts(again.out) >= 3, timeout=90)


def test_the_experimenter_page_makes_and_revokes_links_and_only_for_the_experimenter(tmp_path, capsys):
    with serve(tmp_path) as served:
        lab = Browser()
        status, text = lab.get(served.experimenter)
        assert status == 200 and f"0 of {4 * len(os.sched_getaffinity(0))} running" in text
        status, text = lab.get(f"{served.url}/experimenter/invite", data=b"participant=P09")
        link = re.search(r"(http://\S+participant=P09&amp;token=[\w-]+)", text).group(1).replace("&amp;", "&")
        participant = Browser()
        assert participant.get(link)[0] == 200
        assert participant.get(f"{served.url}/experimenter")[0] == 403          # a participant is not the lab
        assert lab.get(f"{served.url}/experimenter/invite", data=b"participant=experimenter")[0] == 400
        status, text = lab.get(f"{served.url}/experimenter/revoke", data=b"participant=P09")
        assert status == 200 and "P09" in text                                 # back on the list
        assert participant.get(f"{served.url}/")[0] == 403 and Browser().get(link)[0] == 403
        assert "P09" not in json.loads((served.out / "invites.json").read_text())
