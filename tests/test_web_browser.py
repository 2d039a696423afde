"""The WebXR page in a real browser (Debian's chromium, a Quest 3 emulated by iwer) against the real
stack of launch/webxr.yaml: the page draws in stereo, its controller turns the object, its hand
drives the glove's motors on a (virtual) CAN bus (a tracked hand with its fingers), and whatever
ends the page turns them off.

The motor node runs in this process on a private virtual CAN channel, so the test reads the duty
frames on the bus itself, with their send times.
"""
from __future__ import annotations

import io
import re
import threading
import time
import uuid

import can
import numpy as np
import pytest
from PIL import Image

from touch4d.boards.config import load_glove_can
from touch4d.boards.protocol import GloveProtocol
from touch4d.bus import Node
from touch4d.bus.realtime import bus_context, raise_thread_priority
from touch4d.bus.testing import collect, free_port, launch_process, node_process, running_broker, wait_until
from touch4d.messages import ControllerState, HandJoints, HandPose, Heartbeat, MotorCommand, SceneState
from touch4d.nodes.motors import MotorsNode
from touch4d.web.testing import chromium, context_options, enter_vr, headset_page, wait_connected

pytestmark = pytest.mark.timeout(120)

CENTER = (0.0, 1.2, -0.45)          # the screen's centre in the room (config/calibration.yaml)
AWAY = (0.6, 1.2, -0.45)            # 0.6 m to the right: the hand is outside the screen
BACKGROUND = np.array([0.04, 0.04, 0.06]) * 255


class Glove:
    """The motor node (emulated boards) and a listener on its CAN bus, in a thread of this process
    with the real-time priority the launch files give the motor node (when the machine allows it),
    so the frames' send times are the node's, not this busy test process's."""

    def __init__(self, bus):
        self.cfg = load_glove_can(None)
        self.protocol = GloveProtocol(self.cfg)
        self.channels = {b.id: b.channels for b in self.cfg.boards}
        self.channel = f"webxr-test-{uuid.uuid4().hex}"
        self.bus = bus
        self.frames: list[tuple[float, int, bool]] = []   # (send time, board, any channel on)
        self.lock = threading.Lock()
        self.ready = threading.Event()
        self.error = None
        self._stop = False
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        if not self.ready.wait(30) or self.error:
            raise RuntimeError(f"the motor node did not start: {self.error}")

    def _run(self):
        raise_thread_priority()          # before the node's threads (zmq I/O, emulator) exist: they inherit it
        try:
            context = bus_context()
            node = MotorsNode(params={"channel": self.channel, "emulate": True}, bus=self.bus, context=context)
            listener = can.Bus(interface="virtual", channel=self.channel)
        except Exception as exc:  # noqa: BLE001 - reported to the fixture
            self.error = exc
            self.ready.set()
            return
        self.ready.set()
        try:
            while not self._stop:
                node.spin_once(0.002)
                while (msg := listener.recv(0)) is not None:
                    frame = self.protocol.decode(msg)
                    if frame is not None and frame.kind == "duty":
                        on = any(self.protocol.levels(frame, self.channels[frame.board]))
                        with self.lock:
                            self.frames.append((msg.timestamp, frame.board, on))
        finally:
            node.shutdown()
            listener.shutdown()
            context.destroy(linger=0)

    def on_since(self, t: float) -> bool:
        with self.lock:
            return any(on for when, _, on in self.frames if when >= t)

    def all_off_at(self, t0: float) -> float | None:
        """When every board's duty frames turned all-zero for good after t0 (None if not yet)."""
        with self.lock:
            after = [f for f in self.frames if f[0] >= t0]
        off_at = {}
        for when, board, on in after:
            if on:
                off_at.pop(board, None)
            else:
                off_at.setdefault(board, when)
        if len(off_at) < len(self.cfg.boards):
            return None
        return max(off_at.values())

    def close(self):
        self._stop = True
        self.thread.join(10)


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


@pytest.fixture(scope="module")
def stack():
    """launch/webxr.yaml (the page is the tracker), its motor node replaced by the in-process Glove."""
    port = free_port()
    args = ["launch/webxr.yaml", "motors:=none", "monitor:=none", f"tracker.port:={port}",
            "tracker.save_calibration:=false"]
    with launch_process(args) as run:
        bus = run.wait_ready(60)
        run.wait_for_line("WebXR page", timeout=60)
        glove = Glove(bus)
        watcher = Node("browser-test", bus=bus, heartbeat=False)
        try:
            yield {"url": f"http://127.0.0.1:{port}/", "bus": bus, "glove": glove, "watcher": watcher, "run": run}
        finally:
            watcher.shutdown()
            glove.close()


def tracker_page(browser, url):
    """A small page whose headset looks away from the screen, so that SwiftShader's frames are cheap:
    the hand is tracked only while the page keeps up (stale_s), and a page busy drawing a software
    frame answers its events late (a headset's GPU draws these frames in a millisecond or two)."""
    page = headset_page(browser, url, 320, 180)
    enter_vr(page)
    page.evaluate("xr.position.set(0, 1.5, 0.8)")
    page.evaluate("xr.quaternion.set(0, 1, 0, 0)")          # turned round: the screen is behind
    return page


def spin_until(node, predicate, timeout=15.0):
    return wait_until(predicate, timeout=timeout, spin=node)


def settled_scene(watcher, scenes, since: float) -> dict:
    """The first object of the scene once the scene node has handled what reached the bus before
    `since` (wall clock): two scene/state messages published after it with one revision, the
    second a steady repeat (the node repeats its state every 0.5 s), so no change came between.
    Generous: the scene node's first turn loads numba's compiled renormalize (or compiles it)."""
    def steady():
        after = [s for s in scenes if s.stamp > since]
        return len(after) >= 2 and after[-1].revision == after[-2].revision and after[-1].objects[0]

    return spin_until(watcher, steady, timeout=30.0)


def set_controller(page, position, trigger=None):
    x, y, z = position
    page.evaluate(f"xr.controllers.right.position.set({x}, {y}, {z})")
    if trigger is not None:
        page.evaluate(f"xr.controllers.right.updateButtonValue('trigger', {trigger})")


def screenshot(page) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"), dtype=float)


def horizontal_shift(left: np.ndarray, right: np.ndarray, max_shift: int = 120) -> int:
    """The shift s (pixels) that best maps the right eye's picture onto the left eye's: left[x] ~ right[x - s]."""
    a, b = left.mean(axis=2), right.mean(axis=2)
    best, best_err = 0, np.inf
    for s in range(-max_shift, max_shift + 1):
        if s >= 0:
            err = np.mean(np.abs(a[:, s:] - b[:, :b.shape[1] - s]))
        else:
            err = np.mean(np.abs(a[:, :s] - b[:, -s:]))
        if err < best_err:
            best, best_err = s, err
    return best


def test_immersive_session_shows_the_scene_in_both_eyes_with_disparity(browser, stack):
    page = headset_page(browser, stack["url"], 480, 270)
    try:
        enter_vr(page)
        page.wait_for_function("touch4d.geometry !== null && touch4d.frame !== null && touch4d.xrFrames > 10")
        image = screenshot(page)
        h, w, _ = image.shape
        left, right = image[:, : w // 2], image[:, w // 2:]
        blue = np.array([0.30, 0.65, 1.00]) * 255               # the hypercube's colour (its scene file)
        for eye in (left, right):
            drawn = np.abs(eye - BACKGROUND).sum(axis=2) > 30
            near_blue = np.abs(eye - blue).sum(axis=2) < 90
            assert drawn.mean() > 0.01 and near_blue.sum() > 100
        # The screen stands 0.45 m ahead of the eyes (1.6 m high, the screen's centre at 1.2 m);
        # with a 90-degree field of view the focal length is half the eye's height in pixels, so a
        # 63 mm eye distance puts things there about f * 0.063 / 0.45 ~ 0.07 x height apart,
        # the left eye's picture to the right of the right eye's (crossed disparity, nearer than infinity).
        shift = horizontal_shift(left, right)
        expected = (h / 2) * 0.063 / 0.45
        assert 0.4 * expected < shift < 2.5 * expected
    finally:
        page.context.close()


def test_the_controller_arrives_on_controller_state_and_turns_the_object(browser, stack):
    watcher = stack["watcher"]
    states = collect(watcher, "controller/state", ControllerState, latest_only=True)
    scenes = collect(watcher, "scene/state", SceneState, latest_only=True)
    page = tracker_page(browser, stack["url"])
    try:
        set_controller(page, AWAY, trigger=0)
        first = spin_until(watcher, lambda: next((s for s in reversed(states) if s.valid and s.trigger == 0
                                                 and abs(s.position[0] - AWAY[0]) < 0.1), None))
        # 10 cm to the left without the trigger: the grip follows, the object stays
        set_controller(page, (AWAY[0] - 0.1, AWAY[1], AWAY[2]))
        moved = spin_until(watcher, lambda: next((s for s in reversed(states)
                                                  if abs(s.position[0] - (first.position[0] - 0.1)) < 1e-3), None))
        assert np.allclose(moved.position[1:], first.position[1:], atol=1e-3)
        # hold the trigger and move 10 cm back to the right: the object turns in the xw plane (paper §4.4)
        set_controller(page, (AWAY[0] - 0.1, AWAY[1], AWAY[2]), trigger=1)
        spin_until(watcher, lambda: states[-1].trigger == 1.0)
        # the scene node (another process, latest sample only) grabs on the first held sample it
        # handles: wait until it has caught up with this one, or a busy machine would grab mid-motion
        before = settled_scene(watcher, scenes, time.time())["orientation"].copy()
        for k in range(1, 11):
            set_controller(page, (AWAY[0] - 0.1 + 0.01 * k, AWAY[1], AWAY[2]))
            time.sleep(0.05)
        spin_until(watcher, lambda: abs(states[-1].position[0] - first.position[0]) < 1e-3)
        # and it turns until the last held sample it handles: that must be this one, before the release
        after = settled_scene(watcher, scenes, time.time())["orientation"]
        set_controller(page, (AWAY[0], AWAY[1], AWAY[2]), trigger=0)
        spin_until(watcher, lambda: states[-1].trigger == 0.0)
        turn = after @ before.T
        # 0.1 m along the screen's x at the scene node's default 6 rad/m: 0.6 rad in the xw plane only
        angle = np.arctan2(abs(turn[3, 0]), turn[0, 0])
        assert angle == pytest.approx(0.6, abs=0.08)
        assert np.allclose(turn[1:3, 1:3], np.eye(2), atol=1e-6)
    finally:
        page.context.close()


def test_a_hand_in_the_object_drives_the_glove_and_closing_the_page_stops_it_within_100_ms(browser, stack):
    watcher, glove = stack["watcher"], stack["glove"]
    commands = collect(watcher, "tactile/motors", MotorCommand, latest_only=True)
    page = tracker_page(browser, stack["url"])
    try:
        set_controller(page, AWAY)
        watcher.spin(0.3)
        start = time.time()
        set_controller(page, CENTER)                 # into the hypercube's front cell
        spin_until(watcher, lambda: commands and commands[-1].intensity.max() > 0.1)
        wait_until(lambda: glove.on_since(start), timeout=10)
        # the page is closed while the hand touches
        wait_until(lambda: glove.on_since(time.time() - 0.05), timeout=10)
        t0 = time.time()
        page.close(run_before_unload=True)      # as a user closing the tab: the page's pagehide runs
        off = wait_until(lambda: glove.all_off_at(t0), timeout=5)
        assert off - t0 < 0.1, f"motors off {1000 * (off - t0):.0f} ms after the page closed"
    finally:
        page.context.close()


def test_a_hidden_page_turns_the_motors_off(browser, stack):
    glove = stack["glove"]
    page = tracker_page(browser, stack["url"])
    try:
        set_controller(page, CENTER)
        wait_until(lambda: glove.on_since(time.time() - 0.05), timeout=15)
        # e.g. the headset taken off; timed from the page's own clock (this machine's), when it happens
        t0 = page.evaluate("() => { const t = performance.timeOrigin + performance.now(); "
                           "xr.updateVisibilityState('hidden'); return t / 1000; }")
        off = wait_until(lambda: glove.all_off_at(t0), timeout=5)
        assert off - t0 < 0.1, f"motors off {1000 * (off - t0):.0f} ms after the page was hidden"
        page.evaluate("xr.updateVisibilityState('visible')")   # back on: touch again
        t1 = time.time()
        wait_until(lambda: glove.on_since(t1), timeout=10)
    finally:
        page.context.close()


def test_garbage_on_the_socket_is_counted_and_survived(browser, stack):
    watcher = stack["watcher"]
    beats = collect(watcher, "node/heartbeat", Heartbeat)
    commands = collect(watcher, "tactile/motors", MotorCommand, latest_only=True)
    page = tracker_page(browser, stack["url"])
    try:
        set_controller(page, CENTER)
        spin_until(watcher, lambda: [b for b in beats if b.node == "tracker"])
        base = [b for b in beats if b.node == "tracker"][-1].stats
        # a second socket from the same page sends garbage
        page.evaluate("""() => new Promise((done) => {
            const ws = new WebSocket(`ws://${location.host}/ws`);
            ws.onopen = () => {
                ws.send('{not json');
                ws.send('{"type": "input", "time": 1, "tracking": true, "head": [NaN, 1, 0, 0, 0, 0, 1], "sources": []}');
                ws.send(new Uint8Array([0, 255, 1, 2]));
                ws.send(JSON.stringify({type: 'input', time: 1, tracking: true, head: null,
                                        sources: [{handedness: 'right', grip: [0, 1, 0, 0, 0, 0, 5], trigger: 0, buttons: [], joints: null}]}));
                ws.send('{"type": "input", "junk": "' + 'x'.repeat(40000) + '"}');   // over the limit: closes it
                setTimeout(() => { ws.close(); done(); }, 200);
            };
        })""")

        def counted():
            stats = [b for b in beats if b.node == "tracker"][-1].stats
            grew = {k: stats.get(k, 0) - base.get(k, 0) for k in ("page_malformed", "page_non_finite", "page_oversized")}
            return grew == {"page_malformed": 3, "page_non_finite": 1, "page_oversized": 1} and stats
        spin_until(watcher, counted)
        # the page still drives the hand and still receives frames
        n = page.evaluate("touch4d.frame.n")
        commands.clear()
        spin_until(watcher, lambda: commands and commands[-1].intensity.max() > 0.1)
        page.wait_for_function(f"touch4d.frame.n > {n} + 5")
        assert stack["run"].proc.poll() is None
    finally:
        page.context.close()


def test_the_desktop_view_draws_orbits_and_asks_nobody_but_the_node(browser, stack):
    context = browser.new_context(**context_options(640, 400))
    page = context.new_page()
    requests = []
    page.on("request", lambda r: requests.append(r.url))
    page.on("websocket", lambda ws: requests.append(ws.url))
    try:
        page.goto(stack["url"])
        wait_connected(page)
        page.wait_for_function("touch4d.geometry !== null && touch4d.frames > 5")
        assert page.is_hidden("#enter-vr")                    # no WebXR runtime here: no VR button
        before = screenshot(page)
        drawn = np.abs(before - BACKGROUND).sum(axis=2) > 30
        assert drawn.mean() > 0.01
        page.mouse.move(320, 200)
        page.mouse.down()
        page.mouse.move(420, 230, steps=5)
        page.mouse.up()
        page.wait_for_timeout(300)
        after = screenshot(page)
        assert np.abs(after - before).sum(axis=2).astype(bool).mean() > 0.01   # the view turned
        origin = stack["url"].rstrip("/").split("://", 1)[1]
        assert requests and all(re.match(rf"(http|ws)://{re.escape(origin)}/", url) for url in requests), requests
    finally:
        context.close()


def test_beyond_loopback_a_page_without_the_token_is_refused(browser, tmp_path):
    port = free_port()
    with running_broker() as bus, node_process("webxr", bus, params={
            "host": "0.0.0.0", "port": port, "cert_dir": str(tmp_path), "save_calibration": False}) as proc:
        line = proc.wait_for_line(r"WebXR page .*https://", timeout=30)
        token = re.search(r"\?token=([\w-]+)", line).group(1)
        proc.wait_for_line("█|▀|▄", timeout=10)                   # the QR code
        context = browser.new_context(**context_options(ignore_https_errors=True))   # the node's self-signed certificate
        try:
            page = context.new_page()
            response = page.goto(f"https://127.0.0.1:{port}/")
            assert response.status == 403 and "token" in page.content()
            response = page.goto(f"https://127.0.0.1:{port}/?token={token}")
            assert response.status == 200
            wait_connected(page)
            # the token was traded for a cookie no script can read, and left the address bar and history
            assert token not in page.url and page.evaluate("document.cookie") == ""
            page.go_back()
            page.go_forward()                             # the entry of the tokened link, as history kept it
            assert token not in page.url and token not in page.evaluate("location.href")
            (cookie,) = context.cookies()
            assert cookie["httpOnly"] and cookie["secure"] and cookie["sameSite"] == "Strict"
            assert cookie["value"] != token
            assert page.reload().status == 200            # the cookie alone lets the page in again
            wait_connected(page)
        finally:
            context.close()


def test_hand_tracking_drives_the_hand_its_pinch_and_the_joints_are_recorded(browser, tmp_path):
    port = free_port()
    log = tmp_path / "hands.mcap"
    with running_broker() as bus, \
            node_process("webxr", bus, params={"port": port, "tracker": True, "hand_source": "hand",
                                               "save_calibration": False}) as proc, \
            node_process("recorder", bus, params={"file": str(log), "topics": ["hand/joints", "hand/pose"]}) as rec:
        proc.wait_for_line("WebXR page", timeout=30)
        rec.wait_for_line("recording", timeout=30)
        probe = Node("hands-test", bus=bus, heartbeat=False)
        joints = collect(probe, "hand/joints", HandJoints, latest_only=True)
        poses = collect(probe, "hand/pose", HandPose, latest_only=True)
        states = collect(probe, "controller/state", ControllerState, latest_only=True)
        page = headset_page(browser, f"http://127.0.0.1:{port}/", 320, 180)
        try:
            page.evaluate("xr.primaryInputMode = 'hand'")
            enter_vr(page)
            page.evaluate("xr.position.set(0, 1.5, 0.8)")
            page.evaluate("xr.quaternion.set(0, 1, 0, 0)")      # looking away: cheap frames
            page.evaluate(f"xr.hands.right.position.set{CENTER}")
            # the hand, put at the screen's centre, arrives there (screen units: 4 per metre)
            spin_until(probe, lambda: poses and poses[-1].valid and np.linalg.norm(poses[-1].position) < 0.5)
            probe.spin(0.3)
            msg = next(j for j in reversed(joints) if j.handedness == "right")
            assert msg.valid and len(msg.names) == 25 and msg.names[0] == "wrist"
            # the glove hand sits halfway between the wrist and the middle finger's knuckle (the hand
            # stands still: the last valid pose goes with the last joints)
            knuckle = msg.names.index("middle-finger-phalanx-proximal")
            palm = 0.5 * (msg.positions[0] + msg.positions[knuckle])
            pose = next(p for p in reversed(poses) if p.valid)
            assert np.allclose(pose.position, palm, atol=1e-6)
            page.evaluate("xr.hands.right.updatePinchValue(1)")  # a pinch is the trigger
            spin_until(probe, lambda: states and states[-1].valid and states[-1].trigger == 1.0)
        finally:
            page.context.close()
            probe.shutdown()
    from touch4d.log.reader import LogReader
    topics = LogReader(log).topics()
    assert topics.get("hand/joints") == "HandJoints"


# The hypercube's front cell fills the screen's cube [-0.6, 0.6]^3 (0.3 m in the room). iwer's right
# hand, set 0.15 m toward the viewer from the screen's centre, reaches into it with its fingers
# only: the wrist and the knuckles stay outside (screen z > 0.6), the relaxed fingers' tips reach
# z ~ 0.4. Pointing keeps the index in and curls the middle, ring and little fingers out.
HAND = (CENTER[0], CENTER[1], CENTER[2] + 0.15)


def board_on_since(glove, board, t):
    with glove.lock:
        return any(on for when, b, on in glove.frames if when >= t and b == board)


def board_off_since(glove, board, t):
    with glove.lock:
        frames = [on for when, b, on in glove.frames if when >= t and b == board]
    return len(frames) >= 3 and not any(frames)


def test_the_tracked_hands_fingers_drive_the_glove_and_pointing_changes_which_motors_run(browser, stack):
    watcher, glove = stack["watcher"], stack["glove"]
    commands = collect(watcher, "tactile/motors", MotorCommand, latest_only=True)
    beats = collect(watcher, "node/heartbeat", Heartbeat)
    page = tracker_page(browser, stack["url"])
    try:
        page.evaluate("xr.primaryInputMode = 'hand'")
        page.evaluate(f"xr.hands.right.position.set{HAND}")

        def motors_on():
            return {n for n, v in zip(commands[-1].names, commands[-1].intensity) if v > 0} if commands else set()

        relaxed = wait_until(lambda: (on := motors_on()) and any(n.startswith("ring-") for n in on) and on,
                             timeout=30, spin=watcher)
        # the fingers touch, the palm (outside the object) does not: the samples follow the joints
        assert {"middle-front-distal", "ring-front-distal"} <= relaxed
        assert not any(n.startswith(("palm-", "back-")) for n in relaxed)
        t0 = time.time()
        wait_until(lambda: board_on_since(glove, 4, t0), timeout=10)       # ring and little on board 4
        # the tactile node follows the joints (a beat of it saying so; a page that stalls past the
        # joints' timeout on a loaded machine hands the glove to the pose for a moment: not that beat)
        wait_until(lambda: [b for b in beats if b.node == "tactile" and b.stats.get("joints", 0) > 0
                            and b.stats.get("hand_joints") == 1], timeout=10, spin=watcher)

        page.evaluate("xr.hands.right.poseId = 'point'")
        pointing = wait_until(lambda: (on := motors_on()) and not any(n.startswith(("ring-", "little-", "middle-"))
                                                                      for n in on) and on,
                              timeout=30, spin=watcher)
        assert any(n.startswith("index-") for n in pointing)               # the pointing index still touches
        t1 = time.time()
        wait_until(lambda: board_off_since(glove, 4, t1), timeout=10)      # ring and little off on the bus
        assert board_on_since(glove, 3, t1) or board_on_since(glove, 2, t1)   # the index's motors run
    finally:
        page.context.close()
