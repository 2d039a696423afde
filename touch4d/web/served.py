"""A served participant in the study server's own process: the trial machine, the scene, the page's
frames, trials.csv, the manifest and the MCAP log, wired without a bus. A participant costs a few
objects and one deadline on the server's loop, not a stack of processes.

The page computes the touch itself (static/touch.js, the setup frame's `touch: page`), so nothing of
the haptic loop passes through here: the server sends the page the scene of each trial, the trial's
state (its prompt, whether objects are drawn and touch is felt: touch4d.study.gate) and repeats the
last frame every `heartbeat_s` (a page whose frames stop for `gate_stale_s` plays 0); the page sends a
"batch" of its frames every `batch_s` (each pose, whether it was tracked, what it played: the trial's
exploration columns and the log) and its answers at once (touch4d.web.protocol).

Wiring, one way: the machine's events (touch4d.study.machine) load the trial's scene into a
SceneControl, whose state goes to the page's WebBridge and back to the machine as shown; the trial's
state goes to the bridge (the page's gate) and the log; a row goes to trials.csv, fsync'd, before
anything else. A restarted server resumes each participant at the first trial without a row, as a
restarted study node does. The log: `scene/state`, `study/trial`, `study/response`, `hand/poses`,
`tactile/played` and `safety/stop`, flushed every `flush_s` (a crash loses at most that much of it,
never a row).
"""
from __future__ import annotations

import math
import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Callable

import msgspec
import numpy as np

from touch4d.messages.hand import IDENTITY

from touch4d.boards.config import load_glove_can
from touch4d.bus.launchfile import load_launch
from touch4d.boards.dbc import dbc_text
from touch4d.errors import Touch4dError
from touch4d.geometry.scene import load_scene
from touch4d.log.writer import LogWriter
from touch4d.messages import HandPoses, MotorCommands, Stop, StudyResponse, StudyTrial, encode
from touch4d.study.design import Study
from touch4d.study.lock import WRITER, SessionLock
from touch4d.study.machine import Announce, Finished, LoadScene, TrialDone, TrialMachine
from touch4d.study.manifest import read_manifest, start_manifest, write_manifest
from touch4d.study.plan import condition_order, plan_session, quick_plan
from touch4d.study.store import TrialsFile, next_segment, session_dir
from touch4d.study.table import TRIALS
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration, load_placement
from touch4d.tracking.scene_control import ControlConfig, SceneControl

from .bridge import BridgeConfig, ClockMap, WebBridge
from .protocol import PageError, parse_page_message

SCENE = "config/scenes/hypercube.yaml"   # shown (hidden by the closed gate) until the first trial's loads
LAB = "launch/study.yaml"   # a served participant's controller does to the scene what the lab's does (its scene node's)


class ServedOptions(msgspec.Struct, kw_only=True, frozen=True):
    """What every served participant shares: files, timings, the page's batching."""

    glove: str = "config/gloves/quest-controller.yaml"   # the controller as the glove
    calibration: str = "config/calibration.yaml"         # the screen's placement in the room
    quick: bool = False            # one repetition per task x condition cell, no practice
    session: str = "1"             # the session label in every row
    iti_s: float = 0.6             # blank time between trials
    break_s: float = 0.0           # a break ends by itself after this long (0: when the participant goes on)
    batch_s: float = 0.25          # the page sends its frames this often (the server's cost is per batch)
    heartbeat_s: float = 1.0       # the last frame again this often while a page is connected
    gate_stale_s: float = 3.0      # a page without a frame this long plays 0 (the server or its link gone)
    flush_s: float = 2.0           # the log handed to the OS this often (a crash loses at most this of it, no row)


class Shared:
    """What is loaded once for every participant: the glove, the calibration, the first scene; and
    the one thread that writes and fsyncs every participant's rows (an fsync takes milliseconds of a
    disk: on the server's loop, hundreds a minute would hold every participant's frames)."""

    def __init__(self, options: ServedOptions):
        self.options = options
        self.rows = ThreadPoolExecutor(1, thread_name_prefix="trials.csv")
        self.glove = load_glove(options.glove)
        self.calibration = load_calibration(options.calibration, "hand_in_grip")
        self.placement = load_placement(options.calibration)
        self.scene = load_scene(SCENE)
        scene = load_launch(LAB)["scene"].params
        self.control = ControlConfig.from_params(gains={}, trigger_threshold=0.5, buttons=scene["buttons"],
                                                 rotate=scene["rotate"], spin={}, source=f"{LAB}: scene")
        self.dbc = dbc_text(load_glove_can(options.glove))   # what the manifest hashes, as the study node's


class ServedSession:
    """One participant's session, served. `send(conn, frame)` and `broadcast(frame, latest)` reach
    its pages (the server's); `clock` is the server's (time.time: answers' stamps compare with onsets)."""

    def __init__(self, study: Study, study_path, participant: str, out, shared: Shared, *,
                 send: Callable[[int, bytes], None], broadcast: Callable[[bytes, bool], None],
                 clock: Callable[[], float] = time.time):
        o = shared.options
        self.study, self.participant, self.options, self.clock = study, participant, o, clock
        self.directory = session_dir(out, participant)
        self._lock = SessionLock(self.directory, WRITER).acquire()   # one writer of trials.csv
        self._broadcast = broadcast
        try:
            self.plan = (quick_plan if o.quick else plan_session)(study, participant)
            self.trials = TrialsFile(self.directory / TRIALS)
            self.machine = TrialMachine(study, self.plan, self.trials.done, participant=participant,
                                        session=o.session, clock=clock, iti_s=o.iti_s, break_s=o.break_s,
                                        threshold=shared.glove.touch_threshold)
            remaining = self.machine.remaining
            start_manifest(self.directory, study=study, study_path=study_path, participant=participant,
                           session=o.session, condition_order=condition_order(study, participant), trials=len(self.plan),
                           glove_path=o.glove, calibration_path=o.calibration, dbc_text=shared.dbc,
                           resumed_at=remaining[0].index if remaining else -1, quick=o.quick, simulation=None)
            self.log = LogWriter(next_segment(self.directory))
        except BaseException:
            self._lock.release()
            raise
        self._writer = shared.rows
        self._rows: list[Future] = []               # rows handed to the rows' thread, not yet known written
        self.glove = shared.glove
        self.names = list(shared.glove.motor_names)
        self.control = SceneControl(shared.scene, shared.calibration, shared.control)
        config = BridgeConfig(tracker=True, touch="page", study_gate="closed", invalid_period_s=math.inf,
                              batch_s=o.batch_s, gate_stale_s=o.gate_stale_s)
        self.bridge = WebBridge(config, shared.glove, shared.calibration, shared.placement, publish=self._published,
                                broadcast=self._sent_all, send=send, now=clock)
        self.pages: set[int] = set()
        self.clock_map = ClockMap()
        self.trial: StudyTrial | None = None       # the latest state, for the experimenter's page
        self.finished = False                      # every trial has its row
        self.page = {"fps": [], "haptics": None, "mode": None, "clock_offset_s": None}   # what the page said
        self.counts = {"batches": 0, "poses": 0, "touches": 0, "malformed": 0, "responses": 0, "frames": 0}
        self._sent_at = -math.inf                  # the last frame to the pages (the heartbeat's clock)
        self._flushed_at = clock()
        self._closed = False
        self.bridge.tick()                         # its one invalid hand (a page tracks nothing yet), unheard
        self.machine.start()
        self._act()

    # ---- the machine's events -------------------------------------------------------------------

    def _act(self) -> None:
        """Do what the machine asked, in order (a row is fsync'd before anything after it)."""
        while True:
            events = self.machine.drain()
            if not events:
                return
            for event in events:
                if isinstance(event, LoadScene):
                    self.control.load(event.text, "the study's trial")
                    state = self.control.message()
                    self.bridge.on_scene(state)
                    self._write("scene/state", state)
                    self.machine.scene_shown(state)
                elif isinstance(event, Announce):
                    self.trial = self.machine.trial_message(event.stamp)
                    self.bridge.on_trial(self.trial)
                    self._write("study/trial", self.trial)
                elif isinstance(event, TrialDone):
                    # fsync'd in the rows' thread within milliseconds, in order, well before the next
                    # trial's onset (iti_s); a server killed meanwhile runs that trial again: none lost
                    self._rows.append(self._writer.submit(self.trials.write, event.row))
                elif isinstance(event, Finished):
                    self.finished = True
                    stop = Stop(reason="study session complete", origin="study")
                    self.bridge.on_stop(stop)
                    self._write("safety/stop", stop)
            self._frame()

    def _frame(self) -> None:
        frame = self.bridge.frame()
        if frame is not None:
            self._sent_all(frame, True)

    def _sent_all(self, frame: bytes, latest: bool) -> None:
        self._sent_at = self.clock()
        if self.pages:
            self.counts["frames"] += 1
        self._broadcast(frame, latest)

    def _published(self, topic: str, msg) -> None:
        """What the bridge would publish for a tracked page: nothing here needs it (the page's own
        batches carry its poses and touches)."""

    def _write(self, topic: str, msg) -> None:
        if not self._closed:
            self.log.write(topic, encode(msg), time.time_ns())

    # ---- the page -------------------------------------------------------------------------------

    def connected(self, conn: int, peer: str = "") -> None:
        self.pages.add(conn)
        self.clock_map = ClockMap()   # another page, perhaps another clock
        self.bridge.connected(conn, peer)
        self._sent_at = self.clock()

    def closed(self, conn: int) -> None:
        self.pages.discard(conn)
        self.bridge.closed(conn)

    def page_message(self, conn: int, data, arrival: float) -> None:
        """One message from the page: parsed, checked, acted on; a bad one is counted and dropped."""
        try:
            msg = parse_page_message(data)
        except PageError:
            self.counts["malformed"] += 1
            return
        kind = msg["type"]
        if kind == "batch":
            self._batch(msg, arrival)
        elif kind == "response":
            stamp = self.clock_map.stamp(msg["time"] / 1000.0, arrival)
            self.counts["responses"] += 1
            answer = StudyResponse(index=msg["index"], response=msg["option"], source="page", stamp=stamp,
                                   received=arrival)
            self._write("study/response", answer)
            self.machine.respond(answer.index, answer.response, stamp, arrival)
            self._act()
        elif kind == "buttons":   # the controller's held buttons changed: the scene's (the slice's c)
            if self.control.on_controller(np.zeros(3), IDENTITY, 0.0, msg["held"], True):
                state = self.control.message()
                self.bridge.on_scene(state)
                self._write("scene/state", state)
                self.machine.scene_shown(state)
                self._frame()
        elif kind == "recenter":
            self.bridge.recenter(msg["head"], arrival)
        elif kind == "stats":
            self.page["fps"].append(round(float(msg["fps"]), 1))
            del self.page["fps"][:-600]   # the last ten minutes' seconds
        elif kind == "haptics":
            self.page["haptics"] = msg["output"]
        elif kind == "session":
            self.page["mode"] = msg["mode"] if msg["active"] else "inline"
        else:
            self.counts["malformed"] += 1   # "input": a served page batches its frames

    def _batch(self, msg: dict, arrival: float) -> None:
        """A batch of the page's frames: its poses and what it played, on this clock (the page's time
        mapped through the smallest delay seen), to the trial's measures and the log."""
        times, touch_times = msg["time"] / 1000.0, msg["touch_time"] / 1000.0
        if len(times):
            offset = self.clock_map.stamp(float(times[-1]), arrival) - float(times[-1])
        elif len(touch_times):
            offset = self.clock_map.stamp(float(touch_times[-1]), arrival) - float(touch_times[-1])
        else:
            return
        self.page["clock_offset_s"] = round(offset, 4)
        intensity = msg["intensity"]
        if len(touch_times) and intensity.shape[1] != len(self.names):
            self.counts["malformed"] += 1
            return
        stamps, valid = times + offset, msg["valid"]
        orientation = msg["orientation"].copy()
        orientation[~valid] = (0.0, 0.0, 0.0, 1.0)
        position = np.where(valid[:, None], msg["position"], 0.0)
        self.counts["batches"] += 1
        self.counts["poses"] += len(stamps)
        self.counts["touches"] += len(touch_times)
        touched = touch_times + offset
        self.machine.poses(stamps, position, valid)
        if len(touched):
            self.machine.motor_rows(touched, intensity)
        if len(stamps):
            self._write("hand/poses", HandPoses(stamps=stamps, positions=position, orientations=orientation,
                                                valid=valid))
        if len(touched):
            self._write("tactile/played", MotorCommands(names=self.names, source_stamps=touched, intensity=intensity))

    # ---- the experimenter -------------------------------------------------------------------------

    def command(self, name: str, why: str) -> None:
        """`pause`, `resume` or `toggle` the trials (the server's or the experimenter's)."""
        self.machine.command(name, why)
        self._act()

    # ---- time -------------------------------------------------------------------------------------

    def next_due(self) -> float:
        """When (server clock) `tick` next has something to do: the machine's next deadline, the
        bridge's, the heartbeat frame while a page is connected, the log's flush."""
        due = min(self.machine.next_check(), self.bridge.next_due(), self._flushed_at + self.options.flush_s)
        if self.pages:
            due = min(due, self._sent_at + self.options.heartbeat_s)
        return due

    def _check_rows(self) -> None:
        """Rows written so far forgotten; one that could not be written raises its error here (the
        server then stops this participant's session, saying why)."""
        while self._rows and self._rows[0].done():
            self._rows.pop(0).result()

    def tick(self) -> None:
        now = self.clock()
        self._check_rows()
        self.machine.tick()
        self._act()
        self.bridge.tick()
        if self.pages and now >= self._sent_at + self.options.heartbeat_s:
            frame = self.bridge.last_frame()
            if frame is not None:
                self._sent_all(frame, True)
            else:
                self._sent_at = now
        if now >= self._flushed_at + self.options.flush_s:
            self._flushed_at = now
            if not self._closed:
                self.log.flush()

    # ---- the end ----------------------------------------------------------------------------------

    def close(self) -> None:
        """The server stops serving this participant: the gate closed (the trial shown is shown again
        on resume), the log complete, what the page said of itself in the manifest."""
        if self._closed:
            return
        self.machine.stop()
        self._act()
        self._closed = True
        unwritten = []
        for row in self._rows:        # every row written before the file closes
            try:
                row.result()
            except (OSError, Touch4dError) as exc:
                unwritten.append(exc)
        try:
            self.log.close({"participant": self.participant, "study": self.study.name})
            self.trials.close()
            self._keep_page()
        finally:
            self._lock.release()
        if unwritten:
            raise unwritten[0]

    def _keep_page(self) -> None:
        """The page's frame rates, haptics and clock offset, in manifest.json's `page` (one entry per start)."""
        fps = self.page["fps"]
        if not fps and self.page["haptics"] is None:
            return
        manifest = read_manifest(self.directory)
        seen = {"haptics": self.page["haptics"], "mode": self.page["mode"], "clock_offset_s": self.page["clock_offset_s"],
                "fps_median": float(np.median(fps)) if fps else None, "fps_min": min(fps) if fps else None,
                "fps_seconds": len(fps)}
        manifest.setdefault("page", []).append(seen)
        write_manifest(self.directory, manifest)
