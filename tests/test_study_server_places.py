"""The study server's places, in process (a real `sleep` process stands as a participant's stack, in
place of the server's containers, so no stack needs starting): a link revoked with `touch4d study invite --revoke` stops its stack with no
request made, a join whose page never connects gives its place back, and an unreadable invites.json
keeps the links read before instead of failing every request."""
from __future__ import annotations

import asyncio
import subprocess
import threading
from pathlib import Path

import aiohttp
import pytest

from touch4d.cli import main as cli_main
from touch4d.study.design import load_study
from touch4d.study.participation import Life, State
from touch4d.web.invites import Invites
from touch4d.web.studyserver import Participant, ServeOptions, StudyServer, _page_port

pytestmark = pytest.mark.timeout(60)

STUDY = "config/studies/paper.yaml"


def _server(out, **kw) -> StudyServer:
    return StudyServer(load_study(STUDY), STUDY, out, ServeOptions(port=0, **kw))


class SleepStacks:
    """Stands for the server's ContainerPool (touch4d.bus.container): each participant's stack a real
    `sleep` process, which unloading ends."""

    def __init__(self):
        self.procs: dict[str, subprocess.Popen] = {}

    def start(self, participant: str) -> subprocess.Popen:
        proc = self.procs[participant] = subprocess.Popen(["sleep", "60"], start_new_session=True)
        return proc

    def unload(self, participant: str) -> None:
        proc = self.procs.pop(participant, None)
        if proc is not None:
            proc.terminate()

    def running(self, participant: str) -> bool:
        proc = self.procs.get(participant)
        return proc is not None and proc.poll() is None

    def container_of(self, participant: str) -> str | None:
        return "sleep" if participant in self.procs else None

    def check(self) -> list[str]:
        return []

    def close(self) -> None:
        for participant in list(self.procs):
            self.unload(participant)


def _stack(server: StudyServer, participant: str) -> tuple[Participant, subprocess.Popen]:
    """A running participant whose stack is a real process (its own process group, as a stack's)."""
    if server.pool is None:
        server.pool = SleepStacks()
    p = server.participants[participant]
    proc = server.pool.start(participant)
    p.life = Life(State.RUNNING)
    return p, proc


async def _until(predicate, timeout: float) -> bool:
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout
    while not predicate():
        if loop.time() > deadline:
            return False
        await asyncio.sleep(0.05)
    return True


def _serving(server: StudyServer, body) -> None:
    """Run `body(server)` (a coroutine function) while the server serves; stop it after."""
    async def main():
        serve = asyncio.ensure_future(server._serve())
        try:
            assert await _until(lambda: server._stopping is not None and hasattr(server, "client"), 10)
            await asyncio.sleep(0.2)
            await body(server)
        finally:
            server._stopping.set()
            await serve
    asyncio.run(main())


def _reap(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
    proc.wait()


def test_a_link_revoked_from_the_command_line_stops_its_stack_without_a_request(tmp_path):
    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    p, proc = _stack(server, "P01")
    try:
        async def body(server):
            assert cli_main(["study", "invite", str(tmp_path), "P01", "--revoke"]) == 0
            assert await _until(lambda: proc.poll() is not None, 10), "the revoked participant's stack still runs"
            assert p.life.shown() == "revoked" and server.running() == 0
        _serving(server, body)
    finally:
        _reap(proc)


def test_a_join_whose_page_never_connects_gives_its_place_back(tmp_path):
    server = _server(tmp_path, leave_after_s=0.1, page_grace_s=0.3)
    Invites(tmp_path).issue("P01")
    Invites(tmp_path).issue("P02")
    server._load_invites()
    (gone, gone_proc), (stays, stays_proc) = _stack(server, "P01"), _stack(server, "P02")
    procs = [gone_proc, stays_proc]
    try:
        async def body(server):
            server._await_page(gone)
            server._await_page(stays)
            server._page_opened(stays)          # P02's page came
            assert await _until(lambda: procs[0].poll() is not None, 10), "a join without a page holds its place"
            assert gone.life.shown() == "left" and server.counts["left"] == 1
            await asyncio.sleep(0.5)
            assert procs[1].poll() is None and stays.life.shown() == "running"
        _serving(server, body)
    finally:
        _reap(procs[0])
        _reap(procs[1])


def test_an_unreadable_invites_file_keeps_the_links_read_before(tmp_path):
    server = _server(tmp_path)
    token = Invites(tmp_path).issue("P01")

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as page:
            async with page.get(f"{url}/?participant=P01&token={token}") as response:
                assert response.status == 200 and "id=join" in await response.text()
            (tmp_path / "invites.json").write_text("{not json")
            async with page.get(f"{url}/") as response:
                assert response.status == 200 and "id=join" in await response.text()
            async with page.get(f"{url}/?participant=P01&token={token}") as response:
                assert response.status == 200
            async with aiohttp.ClientSession() as stranger:
                async with stranger.get(f"{url}/?participant=P01&token=AAAAAAAAAAAAAAAAAAAAAA") as response:
                    assert response.status == 403
    _serving(server, body)


def test_the_experimenter_resumes_a_trial_they_paused(tmp_path):
    """A pause from the experimenter's page needs its way back: the participant's page has no resume."""
    from touch4d.bus import Node
    from touch4d.bus.testing import collect, wait_until
    from touch4d.messages import StudyCommand

    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    server._start_bus(tmp_path)
    probe = Node("probe", bus=server.node.bus)        # the participants' broker
    heard = collect(probe, "P01/study/command", StudyCommand)
    p, proc = _stack(server, "P01")                   # its trial runs: the commands reach its study node
    try:
        async def body(server):
            url = f"http://127.0.0.1:{server.port}"
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
                async with lab.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
                    page = await response.text()
                    assert response.status == 200 and "action=/experimenter/resume" in page
                for action in ("pause", "resume"):
                    await asyncio.sleep(0.3)      # the probe's subscription settles
                    async with lab.post(f"{url}/experimenter/{action}", data={"participant": "P01"}) as response:
                        assert response.status == 200
                    await asyncio.to_thread(wait_until, lambda: any(m.command == action for m in heard), 10)
        spinning = threading.Thread(target=probe.spin, daemon=True)
        spinning.start()
        _serving(server, body)
        assert [m.command for m in heard] == ["pause", "resume"]
    finally:
        _reap(proc)
        probe.request_shutdown()
        server.node.request_shutdown()
        server._bus_thread.join(5)
        server.broker.stop()


def test_a_new_link_ends_what_the_old_one_opened(tmp_path):
    """Re-inviting a participant (a leaked or lost link) cuts off the old link's browsers and stack."""
    server = _server(tmp_path)
    old = Invites(tmp_path).issue("P01")
    server._load_invites()
    p, proc = _stack(server, "P01")
    try:
        async def body(server):
            url = f"http://127.0.0.1:{server.port}"
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as leaked:
                async with leaked.get(f"{url}/?participant=P01&token={old}") as response:
                    assert response.status in (200, 502)          # in (its stack is no page server here)
                assert cli_main(["study", "invite", str(tmp_path), "P01", "--no-qr",
                                 "--public-url", url]) == 0
                async with leaked.get(f"{url}/") as response:
                    assert response.status == 403, "the old link's cookie still opens the page"
                assert await _until(lambda: proc.poll() is not None, 10), "the old link's stack still runs"
            new = Invites(tmp_path).load()["P01"]
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as page:
                async with page.get(f"{url}/?participant=P01&token={new}") as response:
                    assert response.status == 200 and "id=join" in await response.text()
            async with aiohttp.ClientSession() as stranger:
                async with stranger.get(f"{url}/?participant=P01&token={old}") as response:
                    assert response.status == 403
        _serving(server, body)
    finally:
        _reap(proc)


@pytest.mark.timeout(240)
def test_a_stack_that_cannot_start_tells_the_participant_without_the_servers_paths(tmp_path, caplog):
    """The page faces the internet: where the server keeps its files is the experimenter's to read."""
    server = _server(tmp_path, overrides=["study.no_such_parameter:=1"])     # the launch refuses it
    token = Invites(tmp_path).issue("P01")
    server._load_invites()
    server.tmp = tmp_path
    server.bus_file = tmp_path / "bus.yaml"
    server.bus_file.write_text("broker: {bind: 127.0.0.1, pub_port: 1, sub_port: 2}\nconnect: 127.0.0.1\n")

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as page:
            async with page.get(f"{url}/?participant=P01&token={token}") as response:
                assert response.status == 200
            async with page.post(f"{url}/join", timeout=aiohttp.ClientTimeout(total=200)) as response:
                text = await response.text()
                assert response.status == 500 and "could not start" in text
                assert str(tmp_path) not in text and "serve.log" not in text
    _serving(server, body)
    assert str(tmp_path / "P01" / "serve.log") in caplog.text         # the experimenter's log says where
    assert server.running() == 0


def test_the_welcome_back_counts_whole_rows_as_the_study_node_does(tmp_path):
    """A row cut short by a crash is run again, so it is not done; a cell may hold a line break."""
    from touch4d.study.store import TrialsFile
    from touch4d.study.table import COLUMNS

    trials = TrialsFile(tmp_path / "P01" / "trials.csv")
    for index in range(3):
        trials.write({c: "" for c in COLUMNS} | {"index": index, "response": "left\nthen right"})
    trials.close()
    with open(tmp_path / "P01" / "trials.csv", "a") as f:
        f.write("P01,1,0,4,3")                                  # the fourth row, cut short
    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    assert "3 trials are done" in server._welcome(server.participants["P01"])
    assert len(TrialsFile(tmp_path / "P01" / "trials.csv").done) == 3     # the study node agrees


def test_the_server_hears_each_participants_study_trial_and_nothing_else(tmp_path):
    """The experimenter page needs each stack's study/trial only: the poses, fields and motor commands
    every stack sends at 72 Hz must not reach the server's process. A link made while the server runs
    is followed too."""
    from touch4d.bus import Node
    from touch4d.bus.testing import wait_until

    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    heard: list[str] = []
    server._on_bus = lambda topic, payload: heard.append(topic)
    server._start_bus(tmp_path)
    Invites(tmp_path).issue("P02")
    server._load_invites()                               # a link made meanwhile (the invites file watched)
    probe = Node("probe", bus=server.node.bus)
    topics = ["P01/study/trial", "P02/study/trial", "P01/hand/pose", "P02/tactile/motors", "P03/study/trial"]
    pubs = {t: probe.create_raw_publisher(f"/{t}") for t in topics}
    try:
        def both_heard() -> bool:
            for pub in pubs.values():
                pub.publish(b"\x80")
            return {"P01/study/trial", "P02/study/trial"} <= set(heard)
        wait_until(both_heard, timeout=20, interval=0.05)
        before = len(heard)
        for pub in pubs.values():                          # once more: what arrives after the trials
            pub.publish(b"\x80")
        wait_until(lambda: len(heard) >= before + 2, timeout=10)
        assert set(heard) == {"P01/study/trial", "P02/study/trial"}
    finally:
        probe.shutdown()
        server.node.request_shutdown()
        server._bus_thread.join(5)
        server.broker.stop()


def test_a_stack_that_is_not_one_group_or_cannot_be_made_fails_the_server_at_start(tmp_path, capsys):
    """A participant's stack is one group in a container: a launch file that splits it, or an
    override it refuses, stops `study serve` before it serves anyone, naming the file and the key."""
    split = tmp_path / "split.yaml"
    split.write_text(f"include: [{Path('launch/study-serve.yaml').resolve()}]\nnodes:\n  scene: {{group: other}}\n")
    assert cli_main(["study", "serve", STUDY, "--out", str(tmp_path / "a"), "--port", "0", "--stack", str(split)]) == 2
    err = capsys.readouterr().err
    assert f"{split}: key 'nodes': expected every node in one `group`" in err and "got 'participant, other'" in err
    assert cli_main(["study", "serve", STUDY, "--out", str(tmp_path / "b"), "--port", "0", "study.nope:=1"]) == 2
    assert "key 'study.nope:=1': expected a parameter of node study" in capsys.readouterr().err
    assert not (tmp_path / "b" / "serve.json").exists()     # it never served


def test_the_page_port_is_read_from_the_ready_file_and_anything_else_is_no_port():
    assert _page_port('ready {"tracker": {"page": 40123}}\n') == 40123
    assert _page_port('ready {"scene": {}, "tracker": {"page": 8090}}') == 8090
    for said in ("ready", "ready\n", "failed: node tracker: port", 'ready {"tracker": {"page": 0}}',
                 'ready {"tracker": {"page": 70000}}', 'ready {"tracker": {"page": "80"}}', "ready [1, 2]",
                 'ready {"tracker": 5}', "ready {not json", 'ready {"recorder": {"page": 40123}}', ""):
        assert _page_port(said) is None, said


def test_a_page_reloaded_resumes_only_the_servers_pause_not_the_experimenters(tmp_path):
    """The page gone pauses the trial and the page back resumes it; a pause from the experimenter's
    page stays through the participant's reloads until the experimenter resumes it."""
    from touch4d.bus import Node
    from touch4d.bus.testing import collect, wait_until
    from touch4d.messages import StudyCommand

    server = _server(tmp_path, leave_after_s=60)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    server._start_bus(tmp_path)
    probe = Node("probe", bus=server.node.bus)
    heard = collect(probe, "P01/study/command", StudyCommand)
    p, proc = _stack(server, "P01")
    commands = lambda: [m.command for m in heard]  # noqa: E731

    async def settle(n):
        await asyncio.to_thread(wait_until, lambda: len(heard) >= n, 10)
        await asyncio.sleep(0.3)           # and nothing more follows

    try:
        async def body(server):
            url = f"http://127.0.0.1:{server.port}"
            await asyncio.sleep(0.3)       # the probe's subscription settles
            server._page_opened(p)
            server._page_closed(p)         # the page gone: the server pauses
            server._page_opened(p)         # and back: the server resumes
            await settle(2)
            assert commands() == ["pause", "resume"]
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
                async with lab.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
                    assert response.status == 200
                async with lab.post(f"{url}/experimenter/pause", data={"participant": "P01"},
                                    headers={"Origin": url}) as response:
                    assert response.status == 200
                await settle(3)
                server._page_closed(p)     # the participant reloads their page
                server._page_opened(p)
                await asyncio.sleep(0.5)
                assert commands()[2:] == ["pause"]    # no resume: the experimenter's pause holds
                view = [s for s in server.status() if s["participant"] == "P01"][0]
                assert view["state"] == "paused" and view["paused_by"] == "experimenter"
                async with lab.post(f"{url}/experimenter/resume", data={"participant": "P01"},
                                    headers={"Origin": url}) as response:
                    assert response.status == 200
                await settle(4)
                assert commands() == ["pause", "resume", "pause", "resume"]
        spinning = threading.Thread(target=probe.spin, daemon=True)
        spinning.start()
        _serving(server, body)
    finally:
        _reap(proc)
        probe.request_shutdown()
        server.node.request_shutdown()
        server._bus_thread.join(5)
        server.broker.stop()


def _trials(out: Path, participant: str, rows: int) -> None:
    """A session folder whose trials.csv has `rows` whole rows (what a study node wrote before a restart)."""
    from touch4d.study.table import COLUMNS
    folder = out / participant
    folder.mkdir()
    lines = [",".join(COLUMNS)] + [",".join([participant, "1", "1", str(k), str(k)] + [""] * (len(COLUMNS) - 5))
                                   for k in range(rows)]
    (folder / "trials.csv").write_text("\n".join(lines) + "\n")


async def _experimenter(server, session: aiohttp.ClientSession, url: str) -> None:
    async with session.get(f"{url}/experimenter?token={server.experimenter_token}") as response:
        assert response.status == 200


def test_the_experimenter_page_shows_each_participants_state_from_its_data_after_a_restart(tmp_path):
    """Restarted on an OUT with data: 7 trials done is 'left' (not 'invited'), every trial done is
    'done', a revoked link's data is 'revoked' (not gone); empty cells read '-'; the page refreshes
    itself from its script and keeps no token in the address."""
    from touch4d.study.plan import quick_plan
    study = load_study(STUDY)
    for participant in ("P01", "P02", "P04"):
        Invites(tmp_path).issue(participant)
    _trials(tmp_path, "P02", 7)
    _trials(tmp_path, "P03", 2)                       # its link revoked before the restart
    _trials(tmp_path, "P04", len(quick_plan(study, "P04")))
    server = _server(tmp_path, quick=True)

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            async with lab.get(f"{url}/experimenter?format=json") as response:
                view = await response.json()
            states = {p["participant"]: (p["state"], p["rows"]) for p in view["participants"]}
            assert states == {"P01": ("invited", 0), "P02": ("left", 7), "P03": ("revoked", 2),
                              "P04": ("done", len(quick_plan(study, "P04")))}
            async with lab.get(f"{url}/experimenter") as response:
                page = await response.text()
                assert response.headers["Referrer-Policy"] == "no-referrer"
            assert "<script src=/experimenter.js></script>" in page and "<script>" not in page
            assert "<td>- of -</td>" in page and " of </td>" not in page and "None" not in page
            async with lab.get(f"{url}/experimenter.js") as response:
                script = await response.text()
                assert response.status == 200 and response.headers["Cache-Control"] == "no-store"
            assert 'history.replaceState(null, "", "/experimenter")' in script and "format=table" in script
            async with lab.get(f"{url}/experimenter?format=table") as response:
                table = await response.text()
            assert table.count("<tr data-state=") == 4 and "<tr data-state=revoked><td>P03</td>" in table
        async with aiohttp.ClientSession() as stranger:       # the table is the experimenter's alone
            async with stranger.get(f"{url}/experimenter?format=table") as response:
                assert response.status == 403
    _serving(server, body)


def test_experimenter_actions_posted_from_another_site_are_refused(tmp_path):
    server = _server(tmp_path)
    Invites(tmp_path).issue("P01")
    server._load_invites()
    p, proc = _stack(server, "P01")
    sent = []
    server.command = lambda participant, command, reason: sent.append((participant, command))

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            for headers in ({"Origin": "https://evil.example"}, {"Sec-Fetch-Site": "cross-site"},
                            {"Origin": "null"}):
                for action in ("pause", "revoke"):
                    async with lab.post(f"{url}/experimenter/{action}", data={"participant": "P01"},
                                        headers=headers, allow_redirects=False) as response:
                        assert response.status == 403, headers
            assert sent == [] and "P01" in Invites(tmp_path).load()
            async with lab.post(f"{url}/experimenter/pause", data={"participant": "P01"},
                                headers={"Origin": url, "Sec-Fetch-Site": "same-origin"}) as response:
                assert response.status == 200
            assert sent == [("P01", "pause")]
    try:
        _serving(server, body)
    finally:
        _reap(proc)


def test_a_new_experimenter_link_ends_the_old_one_and_its_browsers(tmp_path, capsys):
    server = _server(tmp_path)

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        old = server.experimenter_token
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as lab:
            await _experimenter(server, lab, url)
            assert cli_main(["study", "invite", str(tmp_path), "--experimenter", "--public-url", url, "--no-qr"]) == 0
            link = capsys.readouterr().out.strip().splitlines()[-1]
            assert link.startswith(f"{url}/experimenter?token=") and old not in link
            await asyncio.sleep(1.5)                         # the server reads invites.json again each second
            async with lab.get(f"{url}/experimenter?format=json") as response:
                assert response.status == 403                # the old link's cookie
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as fresh:
            async with fresh.get(f"{url}/experimenter?format=json&token={old}") as response:
                assert response.status == 403
            async with fresh.get(link.replace("/experimenter?", "/experimenter?format=json&")) as response:
                assert response.status == 200
    _serving(server, body)


def test_one_links_flood_gets_429_and_spares_the_others_and_a_join_probes_a_running_stack_once(tmp_path):
    server = _server(tmp_path)
    tokens = {p: Invites(tmp_path).issue(p) for p in ("P01", "P02")}
    server._load_invites()
    p, proc = _stack(server, "P01")
    probes = []

    async def counted(participant):
        probes.append(participant.id)
        return True
    server._wait_ready = counted
    loads = []
    load = server.invites.load
    server.invites.load = lambda: loads.append(1) or load()

    async def body(server):
        url = f"http://127.0.0.1:{server.port}"
        async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as one, \
                aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as other:
            for session, who in ((one, "P01"), (other, "P02")):
                async with session.get(f"{url}/?participant={who}&token={tokens[who]}") as response:
                    assert response.status in (200, 502)     # P01's stack is a `sleep`: its page is not there
            loads.clear()

            async def join():
                async with one.post(f"{url}/join", allow_redirects=False) as response:
                    return response.status
            statuses = await asyncio.gather(*(join() for _ in range(300)))
            assert probes == [] and set(statuses) == {303, 429}, set(statuses)   # running: never probed again
            assert 20 <= statuses.count(303) <= 120      # the burst and what a second refills, no more
            async with other.get(f"{url}/") as response:
                assert response.status == 200            # the other link is not slowed by the flood
            assert loads == []                           # invites.json unchanged: not parsed again
            Invites(tmp_path).issue("P03")
            async with other.get(f"{url}/") as response:
                assert response.status == 200
            assert len(loads) == 1 and "P03" in server.participants
    try:
        _serving(server, body)
    finally:
        _reap(proc)
