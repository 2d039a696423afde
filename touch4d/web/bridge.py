"""Topics <-> pages, without a bus or a network: what the WebXR node sends its pages and publishes
for them. The node wires it to its subscriptions, its server and one deadline (one thread): it
calls `tick` at `next_due`, when something is next due without an event (a change's frame, the
vibration or the hand going stale, invalid poses repeated, a placement stored), not at a rate.

Bus -> pages: a "setup" frame when a page connects, a "geometry" frame when what the scene is
made of changes, and a "frame" with the latest transforms and tactile values after a change, at
most one per `frame_period_s`.

Pages -> bus (when the page is the tracker): `hand/pose`, `controller/state`, and the tracked glove
hand's joints on `hand/joints` (just before the pose of the same instant, with its stamp; the other
hand's on `hand/joints/other`) from the one page that drives the hand. The rule: a page drives from
its first tracked input while no other page drives, and keeps driving until it stops tracking
(closes, hides, ends its session, loses tracking or falls silent for `stale_s`); only then may
another page take over. Answers and re-centring come only from the page in control: the one that
drives the hand (or last drove it and is still open), else the page open longest (a view-only
page). Another page's input, answers and re-centring are refused, never silently: counted
(`page_not_driver`), logged once per page with its address, and the page is told (a "driver"
frame, which names no address). Every change of driver is logged. Re-centring happens at most once
per `recenter_min_s`, and the calibration file is written at most once per `save_min_s` (the last
placement, later if need be, and at the latest when the node stops). What a page sends is logged
with its control characters escaped, within a warning budget of its own. Fail safe: when the
driving page closes, hides, loses tracking or falls silent for `stale_s`, the hand is published
invalid at once and then every `invalid_period_s`, so the tactile node commands zero and the motor node turns every motor off
(within 100 ms); the controller too, except while its page is only silent.

With `touch: page` the page computes the glove hand's touch itself (static/touch.js) and each input
carries what it played for its previous pose: published on `tactile/motors` with that pose's time,
and 0 there while the hand is invalid, no page tracks, the study holds the motors off or a
`safety/stop` holds (`on_stop`: the output's guard, touch4d.web.haptics.PageOutput).

A study (`study/trial`): the frame carries its prompt and options and whether objects are drawn
and touch felt (touch4d.study.gate); a newly pressed answer button (ANSWER_BUTTONS, either controller) or a page's
"response" publishes `study/response`, stamped with the page's clock mapped to this machine's. While
a trial runs, the re-centre button answers instead of re-centring. The response also carries its
arrival on this machine's clock (`received`), so a page whose clock claims too much is seen.
"""
from __future__ import annotations

import collections
import dataclasses
import functools
import logging
import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from touch4d.errors import Touch4dError
from touch4d.messages import (ControllerState, HandJoints, HandPose, MotorCommand, MotorStatus, SceneState, Stop,
                              StudyResponse, StudyTrial, TactileField)
from touch4d.render.camera import OrbitCamera
from touch4d.render.frame import CELL_PALETTE, Style
from touch4d.render.glsl import shader_source
from touch4d.render.hud import AMPLITUDE_RGB, AMPLITUDE_STOPS, TactileCube, hand_skeleton, study_lines
from touch4d.render.scene_geometry import SceneGeometry, data_rows
from touch4d.render.view import SceneView
from touch4d.study.gate import StudyGate
from touch4d.tactile.glove import Glove
from touch4d.tactile.skeleton import OUTLINE_PAIRS, JointsError, ViewHand
from touch4d.tracking import webxr
from touch4d.tracking.calibration import Calibration, Placement

from .haptics import HAPTIC_COUNTERS, PageOutput
from .protocol import PageError, json_members, pack_frame, parse_page_message, printable

log = logging.getLogger(__name__)

# The GPU renderer's shaders the page compiles (as GLSL ES 3.00), by the names of touch4d.render.glsl.
PAGE_SHADERS = ("scene_face.vert", "scene_centre.vert", "scene_edge.vert", "scene.frag", "fullscreen.vert",
                "bounds.frag", "view.frag", "grid.frag", "oit.frag", "line.vert", "flat.vert", "flat.frag",
                "tactile.frag")
PAGE_COUNTERS = ("page_messages", "page_malformed", "page_oversized", "page_non_finite", "page_ignored",
                 "page_unresponsive", "page_not_driver", "page_connections", "recentred", "recenter_limited",
                 "study_answers")
PAGE_WARNINGS = 5        # distinct warnings logged per page; then its problems are only counted
# A study's answers from the controller: the k-th of these buttons picks the k-th option (A, B, the
# thumbstick press, ...); the trigger stays the object's grab. Any of them ends a break.
ANSWER_BUTTONS = ("a", "b", "thumbstick", "squeeze", "touchpad")
BUTTON_LABELS = {"a": "A", "b": "B", "thumbstick": "stick", "squeeze": "grip", "touchpad": "pad"}


@functools.lru_cache(maxsize=16)
def _style_fields(style: Style) -> dict:
    """A style as the frame's `scene_style` (a frozen Style: one dict per style, not one per frame;
    dataclasses.asdict cost a third of building a frame). Read only: it goes into every frame."""
    return dataclasses.asdict(style)


@dataclass(frozen=True)
class BridgeConfig:
    """What the node's parameters say about the pages; see nodes/webxr.py."""

    tracker: bool = False               # the page is the tracker: publish what it tracks
    hand: str = "right"                 # the glove hand
    hand_source: str = "controller"     # "controller" (grip pose) or "hand" (hand-tracking joints)
    controller_hand: str = "right"      # the controller (or tracked hand) that turns the object
    recenter_button: str = "a"          # on the controller: re-centre the screen in front of the user
    stale_s: float = 0.05               # tracker page silent this long -> invalid poses
    frame_period_s: float = 1 / 90      # frames at most this often (a touch's start or end: at once)
    invalid_period_s: float = 0.1       # invalid poses repeat this often while no page tracks
    study_gate: str = "open"            # before any study/trial (touch4d.study.gate.StudyGate)
    motors_stale_s: float = 0.06        # tactile/motors older than this: the page's controller plays 0
    stop_hold_s: float = 1.0            # after a safety/stop the page's output is 0 this long (the glove's default)
    recenter_min_s: float = 1.0         # re-centring at most this often
    save_min_s: float = 5.0             # the calibration file written at most this often
    touch: str = "node"                 # where the touch is computed: "node" (tactile/motors) or "page"
    batch_s: float = 0.0                # > 0: a served page, which sends its frames in batches this often
    gate_stale_s: float = 0.25          # touch: page: no frame for this long, the page's own touch plays 0
    framebuffer_scale: float = 1.0      # the page's XR layer (framebufferScaleFactor), before pacing lowers it
    foveation: float = 0.5              # its fixed foveation 0..1 (where the browser has it), before pacing raises it
    pacing: bool = True                 # the page lowers the two while its frames run late (static/pacing.js)


class ClockMap:
    """Page clock -> this machine's clock: the page's time plus the smallest (arrival - page time)
    seen over the last `window` inputs, so a stamp keeps the delay above the best case (a few
    milliseconds' underestimate on Wi-Fi) whatever the two clocks' offset."""

    def __init__(self, window: int = 256):
        self.window = window
        self._deltas: collections.deque = collections.deque()   # (index, delta), increasing deltas
        self._count = 0

    def stamp(self, page_time_s: float, arrival: float) -> float:
        delta = arrival - page_time_s
        d = self._deltas
        while d and d[-1][1] >= delta:
            d.pop()
        d.append((self._count, delta))
        while d[0][0] <= self._count - self.window:
            d.popleft()
        self._count += 1
        return min(page_time_s + d[0][1], arrival)


@dataclass
class _Page:
    conn: int
    peer: str = ""                   # its address, to name it in the log
    clock: ClockMap = dataclasses.field(default_factory=ClockMap)
    mode: str = "inline"
    last_input: float = 0.0          # arrival of its last input (node clock)
    tracking: bool = False
    buttons: frozenset = frozenset()
    answer_held: frozenset = frozenset()   # answer buttons held at its last input (any controller)
    fps: float = 0.0
    scale: float = 0.0               # its XR layer's scale (0: not in a headset, or not told)
    haptics: str = ""                # what it can vibrate ("pulse", "dual-rumble", "none"; "" untold)
    warned: set = dataclasses.field(default_factory=set)   # its warnings logged (its own budget)


def _shown(trial: StudyTrial) -> tuple:
    """What of a study/trial the pages show (its repeats change nothing)."""
    return (trial.phase, trial.index, trial.condition, trial.prompt, tuple(trial.options), trial.message)


class WebBridge:
    """The node's logic. `publish(topic, msg)`, `broadcast(frame, latest)` and `send(conn, frame)`
    are the node's; `latest` frames may replace an unsent one (per-tick frames), the others never."""

    def __init__(self, config: BridgeConfig, glove: Glove, calibration: Calibration, placement: Placement,
                 publish: Callable, broadcast: Callable, send: Callable,
                 save_calibration: Callable[[Calibration], None] | None = None, now: Callable[[], float] = time.time):
        self.config = config
        self.glove = glove
        self.calibration = calibration
        self.placement = placement
        self.publish, self.broadcast, self.send = publish, broadcast, send
        self.save_calibration = save_calibration
        self.now = now
        self.counts = {name: 0 for name in PAGE_COUNTERS}
        self.pages: dict[int, _Page] = {}
        self.owner: int | None = None       # the page that drives the hand, or last drove it
        self._refused: set[int] = set()     # pages already told another one drives
        self._logged: set[str] = set()
        self._invalid_at = -np.inf          # when invalid poses were last published (node clock)
        self._was_live = False
        self._recentred_at = -np.inf        # node clock
        self._saved_at = -np.inf
        self._unsaved: Calibration | None = None   # a placement waiting for its time to be stored
        # latest bus state, as page arrays; the scene as the desktop renderer models it (render.view)
        self.view = SceneView(style=Style())
        self._geometry: SceneGeometry | None = None
        self._geometries = 0
        self._geometry_frame: bytes | None = None
        self._scene: SceneState | None = None
        self._hand = np.array([0, 0, 0, 0, 0, 0, 1], np.float32)
        self._hand_valid = False
        self._joints = ViewHand(glove)          # the articulated hand, drawn while its joints drive
        self._joints_live = False               # this page's glove hand was last published tracked
        n, m = len(glove.samples), len(glove.motor_names)
        self._h = np.zeros(n, np.float32)
        self._touched = np.zeros(n, np.uint8)
        self._intensity = np.zeros(m, np.float32)
        self._duty = np.zeros(m, np.float32)
        self._haptic = 0.0                  # the page's controller intensity in the last frame
        self._boards: list = []
        self._dirty = False
        self._frame_at = -np.inf            # when the last frame was made (node clock)
        self._last_frame: bytes | None = None
        self._steady: tuple[bytes, dict] | None = None   # the frame's rarely changing part (_steady_part)
        self._frame_count = 0
        self.gate = StudyGate(config.study_gate)
        # the page's output: the level it plays, behind the fail-safe rules every haptic output obeys
        self.output = PageOutput(m, config.motors_stale_s, config.stop_hold_s, gate_open=self.gate.motors)
        self._stop_shown = False            # the frames show a stop's hold (touch_on false) until it ends

    # ---- bus -> pages ----------------------------------------------------------------------------

    def setup_frame(self) -> bytes:
        """Everything a page needs once: the glove (samples, outline, motors), the calibration, the
        tactile cube's layout and colours, the desktop camera, and whether it is the tracker."""
        g = self.glove
        units = g.units_per_metre
        cube = TactileCube()
        camera = OrbitCamera()
        fields = {
            "tracker": self.config.tracker, "hand": self.config.hand, "hand_source": self.config.hand_source,
            "motor_names": list(g.motor_names), "touch_threshold": g.touch_threshold,
            "cube_center": list(cube.center), "cube_half": cube.half,
            "camera": {"yaw": camera.yaw, "pitch": camera.pitch, "distance": camera.distance,
                       "target": [float(v) for v in camera.target], "fov": camera.fov},
            "style": dataclasses.asdict(self.view.style),
            "shaders": {name: shader_source(name, "es300") for name in PAGE_SHADERS},
            # the tactile model for the page's own touch (static/touch.js): eq. 1-3's constants
            "touch": self.config.touch, "alpha": float(g.alpha), "beta": float(g.beta), "gamma": float(g.gamma),
            "batch_s": self.config.batch_s, "gate_stale_s": self.config.gate_stale_s,
            "answer_buttons": list(ANSWER_BUTTONS), "recenter_button": self.config.recenter_button,
            "framebuffer_scale": self.config.framebuffer_scale, "foveation": self.config.foveation,
            "pacing": self.config.pacing, **self._calibration_fields(),
        }
        arrays = {
            "samples": (g.samples * units).astype(np.float32),
            "skeleton": (hand_skeleton(g.hand) * units).astype(np.float32),
            "motor_sample": np.asarray(g.motor_sample, np.uint32),
            "motor_weights": g.weight_matrix.astype(np.float32),
            "outline_pairs": OUTLINE_PAIRS.astype(np.uint32).ravel(),
            "cube_points": cube.layout(g.samples).astype(np.float32),
            "amplitude_stops": AMPLITUDE_STOPS.astype(np.float32),
            "amplitude_rgb": AMPLITUDE_RGB.astype(np.float32),
            "cell_palette": CELL_PALETTE.astype(np.float32),
        }
        return pack_frame("setup", fields, arrays)

    def _calibration_fields(self) -> dict:
        c = self.calibration
        return {"screen_center": [float(v) for v in c.center_m],
                "screen_rotation": [float(v) for v in c.screen_rotation.as_quat()],
                "screen_edge": float(c.edge_m),
                # the glove hand on the controller's grip (calibration.hand_from_controller, for touch.js)
                "hand_offset": [float(v) for v in c.hand_offset_m],
                "hand_rotation": [float(v) for v in c.hand_rotation.as_quat()]}

    def on_scene(self, msg: SceneState) -> None:
        """Adopt a scene; its geometry (the GPU renderer's arrays) goes to the pages only when what the
        scene is made of changed, its transforms with the next frame."""
        try:
            if not self.view.set_scene(msg):
                return
        except Touch4dError as exc:     # MessageError, GeometryError: a scene that cannot be drawn
            self._warn_once(f"scene:{exc}", f"scene/state revision {msg.revision} cannot be drawn: {exc}")
            return
        geometry = self.view.layer.geometry
        if geometry is not self._geometry:
            self._geometry = geometry
            self._geometries += 1
            self._geometry_frame = self.geometry_frame(geometry, f"g{self._geometries}")
            self.broadcast(self._geometry_frame, False)
        self._scene = msg
        self._steady = None
        self._dirty = True

    @staticmethod
    def geometry_frame(g: SceneGeometry, key: str) -> bytes:
        """The scene's geometry for the page: the GPU backend's data textures and vertex arrays."""
        arrays = {name: texture for name, texture in g.textures().items()}
        arrays.update(fills=g.fills, centres=g.centres, edges=g.edges)
        return pack_frame("geometry", {"key": key, "bodies": g.n_bodies, "objects": g.n_objects,
                                       "halfspaces": g.n_halfspaces, "grid_size": g.grid_size}, arrays)

    def on_hand_pose(self, msg: HandPose) -> None:
        self._hand = np.concatenate((msg.position, msg.orientation)).astype(np.float32)   # np.r_: 10x the time
        self._hand_valid = bool(msg.valid)
        self._joints.on_pose(msg.stamp)
        self._dirty = True

    def on_hand_joints(self, msg: HandJoints) -> None:
        """The articulated hand: drawn with its fingers while its joints are fresh (the tactile node's rule)."""
        try:
            self._joints.on_joints(msg)
        except JointsError as exc:
            self._warn_once(f"joints:{exc}", f"hand/joints not drawn: {exc}")
        self._dirty = True

    def on_field(self, msg: TactileField) -> None:
        if len(msg.h) == len(self._h):
            h = msg.h.astype(np.float32)
            # NaN as 0; a finite sum proves every value finite (then nan_to_num would change nothing)
            self._h = h if math.isfinite(h.sum(dtype=np.float64)) else np.nan_to_num(msg.h).astype(np.float32)
            self._touched = np.isfinite(msg.l).astype(np.uint8)
            self._dirty = True

    def on_motors(self, msg: MotorCommand) -> None:
        if len(msg.intensity) == len(self._intensity):
            self._intensity = msg.intensity.astype(np.float32)
            now = self.now()
            self.output.play(self._intensity, now)
            self._dirty = True
            if (self.haptic(now) > 0.0) != (self._haptic > 0.0):
                # a touch starts or ends: its frame now, not up to a tick later (at most as often as
                # tactile/motors, the hand's rate; a level that only changes waits for the tick)
                self.broadcast(self.frame(), True)

    def on_status(self, msg: MotorStatus) -> None:
        if len(msg.duty) == len(self._duty):
            self._duty = msg.duty.astype(np.float32)
        self._boards = [{"id": b["id"], "online": b["online"], "state": b["state"]} for b in msg.boards]
        self._steady = None
        self._dirty = True

    def on_trial(self, msg: StudyTrial) -> None:
        """A study's state: the pages show its prompt and hide objects where its condition says so."""
        previous = self.gate.trial
        self.gate.update(msg)
        self.output.guard.set_gate(self.gate.motors, self.now())
        self._steady = None
        if previous is None or _shown(previous) != _shown(msg):
            self._dirty = True

    def on_stop(self, msg: Stop) -> None:
        """A `safety/stop`: the page's controller and its own touch (`touch_on`) 0 at once, for
        `stop_hold_s` (its guard); the frame that says so goes out now."""
        self.output.guard.stop(self.now())
        self._stop_shown = True
        self._steady = None
        self._dirty = True
        self.broadcast(self.frame(), True)

    def study_fields(self) -> dict:
        """The study's part of a frame; `touch_on`: the page's own touch allowed (no gate or stop holds it)."""
        trial = self.gate.trial
        touch_on = self.output.guard.holds_off(self.now()) is None
        if trial is None:
            return {"draw_objects": self.gate.objects, "touch_on": touch_on, "study": None}
        return {"draw_objects": self.gate.objects, "touch_on": touch_on,
                "study": {"phase": trial.phase, "index": trial.index, "total": trial.total, "prompt": trial.prompt,
                          "options": list(trial.options), "message": trial.message, "practice": trial.practice,
                          "buttons": list(ANSWER_BUTTONS[:len(trial.options)]),
                          "lines": study_lines(trial, [BUTTON_LABELS[b] for b in ANSWER_BUTTONS])}}

    def frame(self) -> bytes | None:
        """The per-tick frame when something changed since the last one (else None)."""
        if not self._dirty:
            return None
        self._dirty = False
        self._frame_count += 1
        now = self._frame_at = self.now()
        self._haptic = self.haptic(now)
        fields = {"n": self._frame_count, "hand_valid": self._hand_valid, "haptic": self._haptic, "time": now}
        arrays = {"hand": self._hand, "h": self._h, "touched": self._touched,
                  "intensity": self._intensity, "duty": self._duty}
        articulated = self._joints.current() if self._hand_valid else None
        fields["hand_source"] = "pose"
        if articulated is not None:
            # the samples where their bones are, and the joints for the outline (screen units)
            fields["hand_source"] = "joints"
            arrays["hand_samples"] = articulated.samples.astype(np.float32).ravel()
            arrays["hand_joints"] = articulated.joints.astype(np.float32).ravel()
        if self._steady is None:
            self._steady = self._steady_part()
        members, steady_arrays = self._steady
        arrays.update(steady_arrays)
        self._last_frame = pack_frame("frame", fields, arrays, members)
        return self._last_frame

    def last_frame(self) -> bytes | None:
        """The last frame made (a served page's heartbeat sends it again: nothing changed)."""
        return self._last_frame

    def _steady_part(self) -> tuple[bytes, dict]:
        """What of a frame changes only with the scene, the study or the boards (on_scene, on_trial,
        on_status drop it): its fields JSON-encoded, and the scene's arrays."""
        fields = {"boards": self._boards, "geometry": f"g{self._geometries}" if self._geometries else None,
                  **self.study_fields()}
        arrays = {}
        layer = self.view.layer
        if layer is not None:
            # the same texels the GPU backend writes into its t_objects texture
            arrays["t_objects"] = data_rows(layer.transforms)[0]
            fields.update(projection=layer.projection, eye=float(layer.perspective_eye or 0.0),
                          touch_section=self.view.touches_section, touch_w=float(self.view.slice_w),
                          selected=int(self._scene.selected), revision=int(self._scene.revision))
            # the view; in the slice and both views the cross-section's triangles, cut here (static/slice.js)
            view = self.view
            fields.update(view=view.view, slice_w=view.slice_w, w_extent=list(view.extent) if view.extent else None,
                          scene_style=_style_fields(layer.style))
            if view.section is not None:
                arrays["section"] = np.ascontiguousarray(view.section, dtype=np.float32).ravel()
        return json_members(fields), arrays

    def haptic(self, now: float) -> float:
        """What the page's controller plays now (touch4d.web.haptics): 0 while the study's condition
        holds the motors off, a stop holds, the hand is invalid or tactile/motors is stale."""
        return self.output.level(now, self._hand_valid)

    def tick(self) -> None:
        """Whatever is due now: the frame of a change (its period allowing), the frame that stops the
        controller when its stimulus went stale, invalid poses while no page tracks, a placement to
        store. Called at `next_due`; calling it more often changes nothing."""
        now = self.now()
        if self.haptic(now) != self._haptic:
            self._dirty = True
        if self._stop_shown and now >= self.output.guard.stop_until:   # a stop's hold ended: touch_on again
            self._stop_shown = False
            self._steady = None
            self._dirty = True
        if now >= self._frame_at + self.config.frame_period_s:
            frame = self.frame()
            if frame is not None:
                self.broadcast(frame, True)
        self.check_tracking(now)
        self._save_due(now)

    def next_due(self) -> float:
        """When (node clock) `tick` next has something to do unless an event comes first: a change's
        frame, the vibration's stimulus going stale (frame at 0), the driving page's input going stale
        (hand invalid), the next invalid pose, a placement's time to be stored. A runner waits for it
        instead of ticking at a rate (a participant's process then wakes for its pages' inputs)."""
        due = self._frame_at + self.config.frame_period_s if self._dirty else math.inf
        if self._haptic != 0.0:   # when the guard next turns the level played to 0 (now: it already did)
            now = self.now()
            guard = self.output.guard
            due = min(due, guard.expires(now) if guard.reason(now) is None else -math.inf)
        if self._stop_shown:   # a stop's hold ends: the frame that allows the page's own touch again
            due = min(due, self.output.guard.stop_until)
        if self.config.tracker:
            driver = self.driving(self.now())
            if driver is not None:
                due = min(due, self.pages[driver].last_input + self.config.stale_s)
            else:
                due = min(due, -math.inf if self._was_live else self._invalid_at + self.config.invalid_period_s)
        if self._unsaved is not None:
            due = min(due, self._saved_at + self.config.save_min_s)
        return due

    # ---- connections -----------------------------------------------------------------------------

    def connected(self, conn: int, peer: str = "") -> None:
        self.pages[conn] = _Page(conn, peer or "?")
        self.counts["page_connections"] += 1
        self.send(conn, self.setup_frame())
        if self._geometry_frame is not None:
            self.send(conn, self._geometry_frame)
        if self._last_frame is not None:
            self.send(conn, self._last_frame)

    def closed(self, conn: int) -> None:
        self.pages.pop(conn, None)
        self._refused.discard(conn)
        if conn == self.owner:
            self.owner = None
            self.check_tracking(self.now())

    def page_message(self, conn: int, data, arrival: float) -> None:
        """One message from a page: parsed, checked, acted on; a bad one is counted and dropped."""
        page = self.pages.get(conn)
        if page is None:
            return
        self.counts["page_messages"] += 1
        try:
            msg = parse_page_message(data)
        except PageError as exc:
            self.counts[f"page_{exc.cause}"] += 1
            self._page_warning(page, f"{exc.cause}:{exc}", f"dropped a {exc.cause.replace('_', '-')} message: {exc}")
            return
        kind = msg["type"]
        if kind == "session":
            page.mode = msg["mode"] if msg["active"] else "inline"
            if not msg["active"] and conn == self.owner:
                page.tracking = False
                self.check_tracking(arrival)
        elif kind == "stats":
            page.fps, page.scale = msg["fps"], msg.get("scale", 0.0)
        elif kind == "haptics":
            if msg["output"] == "none" and page.haptics != "none":
                log.warning("page %d (%s) has no vibration actuator: its participant feels no touch", conn, page.peer)
            page.haptics = msg["output"]
        elif kind == "recenter":
            if self._may_control(page, arrival):
                self.recenter(msg["head"], arrival)
        elif kind == "input":
            self._input(page, msg, arrival)
        elif kind == "response":
            if self._may_control(page, arrival):   # a second page cannot answer for the participant
                self._answer(msg["index"], msg["option"], "page", page.clock.stamp(msg["time"] / 1000.0, arrival),
                             arrival)

    def _answer(self, index: int, option: str, source: str, stamp: float, arrival: float) -> None:
        """A study answer goes on the bus as given; the study node takes the first valid one per trial."""
        self.counts["study_answers"] += 1
        self.publish("study/response", StudyResponse(index=index, response=option, source=source, stamp=stamp,
                                                     received=arrival))

    def _answer_buttons(self, page: _Page, msg: dict, stamp: float, arrival: float) -> frozenset:
        """Newly pressed answer buttons of any controller answer the trial shown (or end a break).
        Returns the buttons they used, which do nothing else."""
        held = frozenset(b for s in msg["sources"] for b in s.buttons if b in ANSWER_BUTTONS)
        pressed, page.answer_held = held - page.answer_held, held
        trial = self.gate.trial
        if trial is None or not pressed or trial.phase not in ("stimulus", "break"):
            return frozenset()
        if trial.phase == "break":
            self._answer(trial.index, "", "controller", stamp, arrival)
            return pressed
        for k, button in enumerate(ANSWER_BUTTONS[:len(trial.options)]):
            if button in pressed:
                self._answer(trial.index, trial.options[k], "controller", stamp, arrival)
                return pressed
        return frozenset()

    # ---- who drives the hand ---------------------------------------------------------------------

    def driving(self, now: float) -> int | None:
        """The page that drives the hand now: the owner while it tracks and is not silent."""
        page = self.pages.get(self.owner) if self.owner is not None else None
        if page is not None and page.tracking and now - page.last_input <= self.config.stale_s:
            return page.conn
        return None

    def in_control(self) -> int | None:
        """The page whose answers and re-centring count: the page that drives the hand, or last drove
        it and is still open; else the page open longest (view-only pages, or none tracked yet)."""
        if self.owner in self.pages:
            return self.owner
        return next(iter(self.pages), None)

    def _may_drive(self, page: _Page, now: float) -> bool:
        """Whether this page's input may drive the hand; a refusal is counted, logged and told."""
        driver = self.driving(now)
        if driver is None or driver == page.conn:
            return True
        self._refuse(page, driver, "sent input")
        return False

    def _may_control(self, page: _Page, now: float) -> bool:
        """Whether this page may answer or re-centre (see in_control); a refusal is counted, logged and told."""
        control = self.in_control()
        if control == page.conn:
            return True
        self._refuse(page, control, "answered or re-centred")
        return False

    def _refuse(self, page: _Page, other_conn: int | None, what: str) -> None:
        self.counts["page_not_driver"] += 1
        if page.conn not in self._refused:
            self._refused.add(page.conn)
            other = self.pages.get(other_conn)
            log.warning("page %d (%s) %s while page %d (%s) is in control: refused until that page stops "
                        "tracking", page.conn, page.peer, what, other_conn or 0, other.peer if other else "?")
            # the page is told another page drives, never where that page is
            self.send(page.conn, pack_frame("driver", {"driver": False}))

    def _take(self, page: _Page) -> None:
        """Make `page` the owner (it may now drive); log and tell it."""
        if self.owner == page.conn:
            return
        before = self.pages.get(self.owner) if self.owner is not None else None
        self.owner = page.conn
        self._refused.discard(page.conn)
        if before is not None:
            log.info("page %d (%s) drives the hand now (page %d, %s, stopped tracking)", page.conn, page.peer,
                     before.conn, before.peer)
        self.send(page.conn, pack_frame("driver", {"driver": True}))

    def _input(self, page: _Page, msg: dict, arrival: float) -> None:
        stamp = page.clock.stamp(msg["time"] / 1000.0, arrival)
        # Only the page in control (that drives the hand, or may take it now) answers a study's trials.
        may_answer = (page.tracking or msg["tracking"]) and (
            self.in_control() == page.conn or (self.config.tracker and msg["tracking"]
                                               and self.driving(arrival) is None))
        answered = self._answer_buttons(page, msg, stamp, arrival) if may_answer else frozenset()
        if not self.config.tracker:
            self.counts["page_ignored"] += 1
            return
        if not msg["tracking"] and page.conn != self.owner:
            self.counts["page_ignored"] += 1   # no hand to drive with (a desktop page being hidden)
            return
        if not self._may_drive(page, arrival):
            return
        self._take(page)
        page.last_input = arrival
        page.tracking = msg["tracking"]
        by_side = {s.handedness: s for s in msg["sources"]}
        glove_side = by_side.get(self.config.hand) if page.tracking else None
        control_side = by_side.get(self.config.controller_hand) if page.tracking else None
        pose = webxr.hand_pose(glove_side, self.config.hand_source, self.calibration, stamp)
        controller = webxr.controller_state(control_side, self.calibration, stamp)
        # the joints first: the tactile node then computes this instant once, from the joints
        for source in msg["sources"]:
            if page.tracking and source.joints is not None and source.handedness in webxr.HANDS:
                glove_hand = source.handedness == self.config.hand
                self.publish("hand/joints" if glove_hand else "hand/joints/other",
                             webxr.hand_joints(source, self.calibration, stamp))
        glove_tracked = glove_side is not None and glove_side.joints is not None
        if self._joints_live and not glove_tracked:
            self._joints_lost(stamp)
        self._joints_live = glove_tracked
        self.publish("hand/pose", pose)
        if self.config.touch == "page":
            self._played(page, msg, stamp, pose.valid)
        self.publish("controller/state", controller)
        self._was_live = pose.valid
        if not pose.valid:
            self._invalid_at = arrival
        held = frozenset(control_side.buttons) if control_side is not None else frozenset()
        if self.config.recenter_button in held - page.buttons - answered and msg["head"] is not None:
            self.recenter(msg["head"], arrival)
        page.buttons = held

    def _played(self, page: _Page, msg: dict, stamp: float, valid: bool) -> None:
        """touch: page: what the page played for its previous pose goes out on tactile/motors, stamped
        with that pose's time on this machine's clock; 0 while the hand is invalid or the output's guard
        holds the motors off (the study's gate, a stop; the page plays 0 then too)."""
        played, n = msg["played"], len(self.glove.motor_names)
        if played is None:
            if not valid:
                self._motors_off(stamp)
            return
        if len(played["intensity"]) != n:
            self.counts["page_malformed"] += 1
            self._page_warning(page, "played", f"played: expected {n} intensities (one per motor of "
                                               f"{self.glove.path}), got {len(played['intensity'])}")
            return
        if not valid or self.output.guard.holds_off(self.now()):
            self._motors_off(stamp)
            return
        source = stamp + (played["time"] - msg["time"]) / 1000.0
        self.publish("tactile/motors", MotorCommand(names=list(self.glove.motor_names),
                                                    intensity=played["intensity"], source_stamp=source))

    def _motors_off(self, stamp: float) -> None:
        self.publish("tactile/motors", MotorCommand(names=list(self.glove.motor_names),
                                                    intensity=np.zeros(len(self.glove.motor_names)),
                                                    source_stamp=stamp))

    # ---- safety ----------------------------------------------------------------------------------

    def check_tracking(self, now: float) -> None:
        """Publish the hand invalid when no page tracks: at once when tracking ends, then every
        `invalid_period_s` (tracker mode only). The controller too, unless its page only fell silent
        for a moment: a silent controller moves nothing, and a grab (§4.4) survives the hiccup."""
        if not self.config.tracker:
            return
        if self.driving(now) is not None:
            return
        page = self.pages.get(self.owner) if self.owner is not None else None
        tracking = page is not None and page.tracking
        if self._was_live or now - self._invalid_at >= self.config.invalid_period_s:
            self._was_live = False
            self._invalid_at = now
            if self._joints_live:
                self._joints_live = False
                self._joints_lost(0.0)
            self.publish("hand/pose", HandPose(position=np.zeros(3), valid=False))
            if self.config.touch == "page":
                self._motors_off(now)
            if not tracking:
                self.publish("controller/state", ControllerState(position=np.zeros(3), valid=False))

    def _joints_lost(self, stamp: float) -> None:
        """The glove hand's joints are no longer tracked: say so at once (the tactile node falls back)."""
        self.publish("hand/joints", HandJoints(handedness=self.config.hand, names=[], positions=np.zeros((0, 3)),
                                               orientations=np.zeros((0, 4)), radii=np.zeros(0), valid=False,
                                               stamp=stamp, source_stamp=stamp))

    # ---- calibration -----------------------------------------------------------------------------

    def recenter(self, head: np.ndarray, now: float) -> None:
        """Put the screen in front of the head, store it (at most every `save_min_s`), and tell every
        page; at most once per `recenter_min_s` (more are counted as `recenter_limited`)."""
        if now - self._recentred_at < self.config.recenter_min_s:
            self.counts["recenter_limited"] += 1
            return
        self._recentred_at = now
        p = self.placement
        self.calibration = self.calibration.placed_in_front(head[:3], head[3:7], p.distance_m, p.below_eye_m)
        self.counts["recentred"] += 1
        self._unsaved = self.calibration
        self._save_due(now)
        self.broadcast(pack_frame("calibration", self._calibration_fields()), False)

    def _save_due(self, now: float) -> None:
        """Store the last placement if one waits and the file was not written within `save_min_s`."""
        if self._unsaved is None or now - self._saved_at < self.config.save_min_s:
            return
        calibration, self._unsaved = self._unsaved, None
        self._saved_at = now
        if self.save_calibration is not None:
            self.save_calibration(calibration)

    def save_pending(self) -> None:
        """Store a placement still waiting for its time (the node stops: the last re-centre is kept)."""
        self._save_due(float("inf"))

    def _warn_once(self, cause: str, text: str) -> None:
        if cause not in self._logged and len(self._logged) < 100:
            self._logged.add(cause)
            log.warning("%s (further identical problems are only counted)", text)

    def haptic_outputs(self) -> dict[str, int]:
        """How many connected pages vibrate a controller, a gamepad, or nothing (for the heartbeat)."""
        kinds = [p.haptics for p in self.pages.values()]
        return {name: kinds.count(output) for output, name in HAPTIC_COUNTERS.items()}

    def _page_warning(self, page: _Page, cause: str, text: str) -> None:
        """A problem with what a page sent: logged once per cause within the page's own budget (a
        page cannot use up the node's), its text with control characters escaped."""
        if cause in page.warned or len(page.warned) > PAGE_WARNINGS:
            return
        page.warned.add(cause)
        if len(page.warned) > PAGE_WARNINGS:
            log.warning("page %d (%s): more problems; from now on they are only counted", page.conn, page.peer)
            return
        log.warning("page %d (%s): %s (further identical problems are only counted)", page.conn, page.peer,
                    printable(text))

    def page_fps(self) -> float:
        """The frame rate the tracker page (else any page) reports."""
        return max((p.fps for p in self._reporting()), default=0.0)

    def page_scale(self) -> float:
        """The XR layer's scale the tracker page (else any page in a headset) draws at now; 0: none."""
        return max((p.scale for p in self._reporting()), default=0.0)

    def _reporting(self) -> list[_Page]:
        return [self.pages[self.owner]] if self.owner in self.pages else list(self.pages.values())
