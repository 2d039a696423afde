"""A 4D lesson without a network: one scene (an in-process SceneControl), a teacher and a class, each
page showing it and touching it on its own headset.

Every page gets the WebXR node's frames (touch4d.web.bridge.WebBridge: setup, geometry, frame), its
setup saying `tracker: true, touch: "page"`, so static/touch.js computes each one's touch and pulses
its own controller in the frame it tracked the hand (no round trip). The teacher (their page or
`touch4d lesson command`) changes the one scene: every page gets the new frame at once; a page
connecting later gets setup, geometry and the last frame. A student may view the scene their own way
(their view and slice: a frame of their own, cut here) unless the teacher locks it; the teacher's
controller turns the object, or a student's the teacher lets drive.

Pages send the WebXR page's messages (touch4d.web.protocol) and the lesson's own (LESSON_TYPES):

    {"type": "hello", "name": str}                           a display name (anonymous without)
    {"type": "own", "view": VIEW|null, "slice": number|null}  a student's own view / slice (null: the class's)
    {"type": "command", "verb": str, "argument": str}        the teacher's (and the terminal's) command

and get, besides the node's frames, "lesson" frames (their role, name, the lock, the driver, their own
view, whose hand is in the spotlight; the teacher's also the class: who is connected, with what
haptics, who touches what) and "result" frames answering a command. The teacher may put a student's
hand in the spotlight: every page draws it (the frame's hand).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable, Literal

import msgspec
import numpy as np

from touch4d.errors import Touch4dError
from touch4d.geometry.rotation import PLANES, plane_axes, plane_rotation
from touch4d.geometry.scene import Scene
from touch4d.messages import HandPose, MotorCommand, SceneCommand, SceneState
from touch4d.messages.scene import VIEWS
from touch4d.render.view import SceneView
from touch4d.tactile.glove import Glove
from touch4d.tracking import webxr
from touch4d.tracking.calibration import Calibration, Placement
from touch4d.tracking.scene_control import SceneCommandError, SceneControl

from .bridge import BridgeConfig, WebBridge, _style_fields
from .protocol import PageError, message_type, pack_frame, parse_page_message, printable, unpack_frame

TEACHER, CLASS, TERMINAL = "teacher", "class", "terminal"   # the lesson's links (holders of touch4d.web.access)
SCENE_VERBS = ("next", "select", "reset", "projection", "view", "slice", "load")   # SceneControl.command's
LESSON_VERBS = ("rotate", "lock", "unlock", "drive", "spotlight", "remove")
VERBS = SCENE_VERBS + LESSON_VERBS
LESSON_TYPES = ("hello", "own", "command")
MAX_NAME = 32                   # characters of a display name
HEARTBEAT_S = 0.1               # the last frame again at least this often: a page's touch needs fresh frames
                                # (main.js GATE_STALE_MS: 250 ms), and the teacher's class list refreshes
RECORD_HZ = 10.0                # each member's hand and touch recorded at most this often


class LessonError(Touch4dError, ValueError):
    """A lesson command or page message that cannot be carried out; says what was expected."""


class _Hello(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="hello"):
    name: str


class _Own(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="own"):
    view: Literal[VIEWS] | None = None
    slice: float | None = None


class _Command(msgspec.Struct, forbid_unknown_fields=True, tag_field="type", tag="command"):
    verb: str
    argument: str = ""


_DECODE = msgspec.json.Decoder(_Hello | _Own | _Command)


@dataclass
class Member:
    """One open page of the lesson: the teacher's or a student's."""

    conn: int
    holder: str                       # its access holder (the teacher, or the student's own)
    role: str                         # "teacher" | "student"
    name: str
    haptics: str = ""                 # what its page vibrates ("pulse", "dual-rumble", "none"; "" untold)
    own_view: str | None = None       # its own view and slice (None: the class's)
    own_slice: float | None = None
    view: SceneView | None = None     # its own cut of the scene, while it has one
    frame: bytes | None = None        # its own frame, and the class frame it was made from
    made_from: bytes | None = None
    level: float = 0.0                # what its controller played last (0..1)
    near: str = ""                    # the object its hand is nearest while it touches
    tracking: bool = False
    recorded_at: float = -math.inf
    told: bytes | None = None         # the last lesson frame it was sent


def clean_name(text: str) -> str:
    """A display name fit to show and log: control characters escaped, at most MAX_NAME characters."""
    return printable(" ".join(str(text).split()))[:MAX_NAME]


class Lesson:
    """The lesson's logic. `send(conn, frame)`: in order, never dropped; `send_latest(conn, frame)`:
    replaces one not yet sent; `record(topic, msg)`: the lesson's log (or None); `revoke(holder)`:
    a student's access ended, their pages closed (`remove NAME`)."""

    def __init__(self, scene: Scene, glove: Glove, calibration: Calibration, placement: Placement,
                 send: Callable[[int, bytes], None], send_latest: Callable[[int, bytes], None],
                 record: Callable[[str, object], None] | None = None, now: Callable[[], float] = time.time,
                 revoke: Callable[[str], None] | None = None):
        self.glove, self.calibration = glove, calibration
        self.send, self.send_latest = send, send_latest
        self.record = record or (lambda topic, msg: None)
        self.revoke = revoke or (lambda holder: None)   # ends a holder's access and closes its pages
        self.now = now
        self.control = SceneControl(scene, calibration)
        self.bridge = WebBridge(BridgeConfig(tracker=True, touch="page"), glove, calibration, placement,
                                publish=lambda topic, msg: None, broadcast=self._broadcast, send=send, now=now)
        self.members: dict[int, Member] = {}
        self.terminals: set[int] = set()
        self.names: dict[str, str] = {}      # holder -> display name (kept across its reconnections)
        self.locked = False
        self.driver = TEACHER                # "teacher" or a student's name: whose controller turns the object
        self.spotlight: str | None = None    # a student whose hand every page shows (None: nobody's)
        self.counts = {"commands": 0, "refused": 0, "malformed": 0, "frames": 0}
        self.shared: bytes | None = None     # the class's last frame
        self.scene: SceneState | None = None  # and its scene
        self._class_changed = True
        self._students = 0
        self._scene_changed()

    # ---- the scene ---------------------------------------------------------------------------------

    def _scene_changed(self) -> None:
        msg = self.scene = self.control.message()
        self.record("scene/state", msg)
        self.bridge.on_scene(msg)
        frame = self.bridge.frame()
        if frame is not None:
            self._distribute(frame)

    def _broadcast(self, data: bytes, latest: bool) -> None:
        """The bridge's frames for every page: geometry and placements in order, frames the latest."""
        if latest:
            self._distribute(data)
            return
        for conn in self.members:
            self.send(conn, data)

    def _distribute(self, shared: bytes) -> None:
        self.shared = shared
        self.counts["frames"] += 1
        for member in self.members.values():
            self.send_latest(member.conn, self.frame_for(member))

    def heartbeat(self) -> None:
        """Every HEARTBEAT_S: the last frames again (a page's own touch stops on stale frames), and the
        teacher's class list if it changed."""
        if self.shared is not None:
            for member in self.members.values():
                self.send_latest(member.conn, self.frame_for(member))
        if self._class_changed:
            self._class_changed = False
            for member in self.members.values():
                self._tell(member)

    def frame_for(self, member: Member) -> bytes:
        """The class's frame, or the member's own: its view and slice, cut here (SceneView, as the
        bridge cuts the class's)."""
        if self.locked or (member.own_view is None and member.own_slice is None) or self.shared is None:
            return self.shared
        if member.made_from is self.shared and member.frame is not None:
            return member.frame
        if member.view is None:
            member.view = SceneView(style=self.bridge.view.style, view=member.own_view, slice_w=member.own_slice)
        try:
            member.view.set_scene(self.scene)
        except Touch4dError:          # a scene that cannot be cut (the bridge said why): the class's frame
            return self.shared
        view = member.view
        fields, arrays = unpack_frame(self.shared)
        fields.pop("kind", None)
        fields.update(view=view.view, slice_w=view.slice_w, w_extent=list(view.extent) if view.extent else None,
                      scene_style=_style_fields(view.layer.style), touch_section=view.touches_section,
                      touch_w=float(view.slice_w))
        arrays.pop("section", None)
        if view.section is not None:
            arrays["section"] = np.ascontiguousarray(view.section, dtype=np.float32).ravel()
        member.frame, member.made_from = pack_frame("frame", fields, arrays), self.shared
        return member.frame

    def warm(self) -> None:
        """Cut the scene once: the cut is compiled on its first use (seconds), which must not delay
        the first slice view the teacher shows."""
        view = SceneView(style=self.bridge.view.style, view="slice", slice_w=self.control.scene.slice_w)
        view.set_scene(self.scene)

    # ---- commands ----------------------------------------------------------------------------------

    def command(self, verb: str, argument: str = "", by: str = TEACHER) -> str:
        """Carry out a teacher's command; returns what it did (one line). A bad one raises LessonError
        (a SceneCommandError's or ConfigError's text for the scene's verbs) and changes nothing."""
        argument = argument.strip() if verb != "load" else argument
        if verb not in VERBS:
            raise LessonError(f"unknown lesson command {verb!r}; expected one of {', '.join(VERBS)}")
        try:
            if verb in SCENE_VERBS:
                changed = self.control.command(verb, argument)
            elif verb == "rotate":
                changed = self._rotate(argument)
            else:
                changed = self._lesson_command(verb, argument)
        except (SceneCommandError, Touch4dError) as exc:
            raise LessonError(str(exc)) from None
        self.counts["commands"] += 1
        # every command carried out, in order: the scene's and the class's (lock, drive, spotlight, ...)
        self.record("lesson/command", SceneCommand(command=verb, argument=argument))
        if changed and verb in SCENE_VERBS + ("rotate",):
            self._scene_changed()
        shown = argument if verb != "load" else f"{len(argument)} characters of scene"
        return f"{verb} {shown}".strip() + ("" if changed else " (nothing changed)")

    def _rotate(self, argument: str) -> bool:
        words = argument.split()
        try:
            plane, degrees = words[0], float(words[1])
            plane_axes(plane)
            ok = len(words) == 2 and math.isfinite(degrees)
        except (IndexError, ValueError):
            ok = False
        if not ok:
            raise LessonError(f"rotate: expected PLANE DEG (a plane of {', '.join(PLANES)}, then degrees), "
                              f"got {argument!r}")
        if degrees == 0:
            return False
        self.control.rotate(plane_rotation(plane, math.radians(degrees)))
        return True

    def _lesson_command(self, verb: str, argument: str) -> bool:
        if verb in ("lock", "unlock"):
            if argument:
                raise LessonError(f"{verb}: takes no argument, got {argument!r}")
            locked = verb == "lock"
            if locked == self.locked:
                return False
            self.locked = locked
            for member in self.members.values():
                member.own_view = member.own_slice = member.view = member.frame = None
            self._everyone_told()
            if self.shared is not None:
                self._distribute(self.shared)
            return True
        names = [m.name for m in self.members.values() if m.role == "student"]
        if verb == "spotlight":
            return self._spotlight(argument, names)
        if verb == "remove":
            holders = {m.holder for m in self.members.values() if m.role == "student" and m.name == argument}
            if not holders:
                raise LessonError(f"remove: expected a connected student's name ({', '.join(names) or 'none connected'}),"
                                  f" got {argument!r}")
            for holder in holders:
                self.revoke(holder)
            return True
        # drive NAME|teacher
        if argument != TEACHER and argument not in names:
            raise LessonError(f"drive: expected 'teacher' or a connected student's name "
                              f"({', '.join(names) or 'none connected'}), got {argument!r}")
        if argument == self.driver:
            return False
        self.driver = argument
        self._everyone_told()
        return True

    def _spotlight(self, argument: str, names: list[str]) -> bool:
        """spotlight NAME|off: every page shows that student's hand (the frame's hand), or nobody's."""
        if argument != "off" and argument not in names:
            raise LessonError(f"spotlight: expected 'off' or a connected student's name "
                              f"({', '.join(names) or 'none connected'}), got {argument!r}")
        chosen = None if argument == "off" else argument
        if chosen == self.spotlight:
            return False
        self.spotlight = chosen
        self._show_hand(HandPose(position=np.zeros(3), valid=False))
        self._everyone_told()
        return True

    def _show_hand(self, pose: HandPose) -> None:
        """The hand every page draws (the spotlit student's), in the next frame, sent now."""
        self.bridge.on_hand_pose(pose)
        frame = self.bridge.frame()
        if frame is not None:
            self._distribute(frame)

    def _everyone_told(self) -> None:
        self._class_changed = True
        for member in self.members.values():
            self._tell(member)

    # ---- pages -------------------------------------------------------------------------------------

    def connected(self, conn: int, holder: str | None, peer: str = "") -> None:
        """A page (or the terminal) connected: a page gets setup, geometry, the last frame (the bridge's
        late joiner's), its own lesson frame, and the teacher hears of it."""
        if holder == TERMINAL:
            self.terminals.add(conn)
            return
        role = "teacher" if holder == TEACHER else "student"
        if role == "student" and holder not in self.names:   # a page back (a reconnect) keeps its number
            self._students += 1
        name = self.names.get(holder) or ("teacher" if role == "teacher" else f"student {self._students}")
        self.names[holder] = name
        member = self.members[conn] = Member(conn, holder, role, name)
        self.bridge.connected(conn, peer)
        if self.shared is not None:
            self.send_latest(conn, self.frame_for(member))
        self._tell(member)
        self._class_changed = True

    def closed(self, conn: int) -> None:
        self.terminals.discard(conn)
        member = self.members.pop(conn, None)
        if member is not None:
            self.bridge.closed(conn)
            self._class_changed = True
            if member.name == self.spotlight and member.name not in {m.name for m in self.members.values()}:
                self.spotlight = None
                self._show_hand(HandPose(position=np.zeros(3), valid=False))
                self._everyone_told()

    def message(self, conn: int, data, arrival: float) -> None:
        """One message from a page or the terminal: the lesson's own, or the WebXR page's; a bad one
        is counted and answered (a command) or dropped."""
        kind = message_type(data)
        member = self.members.get(conn)
        if conn in self.terminals:
            if kind == "command":
                self._answer(conn, data, TEACHER)
            else:
                self.counts["malformed"] += 1
            return
        if member is None:
            return
        if kind in LESSON_TYPES:
            self._lesson_message(member, data)
            return
        try:
            msg = parse_page_message(data)
        except PageError:
            self.counts["malformed"] += 1
            return
        if msg["type"] == "haptics":
            member.haptics = msg["output"]
            self._class_changed = True
        elif msg["type"] == "session" and not msg["active"]:
            member.tracking = False
            self._class_changed = True
        elif msg["type"] == "input":
            self._input(member, msg, arrival)

    def _lesson_message(self, member: Member, data) -> None:
        try:
            msg = _DECODE.decode(data)
        except (msgspec.DecodeError, msgspec.ValidationError):
            self.counts["malformed"] += 1
            return
        if isinstance(msg, _Hello):
            name = clean_name(msg.name)
            taken = {m.name for m in self.members.values() if m is not member}
            if name and name not in taken and name != TEACHER:
                member.name = self.names[member.holder] = name
                self._class_changed = True
            self._tell(member)
        elif isinstance(msg, _Command):
            if member.role != "teacher":
                self.counts["refused"] += 1
                return
            self._answer(member.conn, data, member.name)
        elif self.locked or (msg.slice is not None and not math.isfinite(msg.slice)):
            self.counts["refused"] += 1
            self._tell(member, force=True)
        else:
            member.own_view, member.own_slice = msg.view, msg.slice
            member.view = member.frame = None
            if self.shared is not None:
                self.send_latest(member.conn, self.frame_for(member))
            self._tell(member)
            self._class_changed = True

    def _answer(self, conn: int, data, by: str) -> None:
        """A command from the teacher's page or the terminal, answered with a "result" frame."""
        try:
            msg = _DECODE.decode(data)
            if not isinstance(msg, _Command):
                raise LessonError("expected a command")
            text, ok = self.command(msg.verb, msg.argument, by), True
        except (msgspec.DecodeError, msgspec.ValidationError) as exc:
            text, ok = f"a command message is {{type, verb, argument}}: {exc}", False
        except LessonError as exc:
            text, ok = str(exc), False
        if not ok:
            self.counts["refused"] += 1
        self.send(conn, pack_frame("result", {"ok": ok, "text": text}))

    def _input(self, member: Member, msg: dict, arrival: float) -> None:
        """A page's tracked input: what it touched (the class list), recorded at RECORD_HZ; the
        driver's controller turns the object."""
        by_side = {s.handedness: s for s in msg["sources"]} if msg["tracking"] else {}
        played = msg["played"]
        level = max(played["intensity"], default=0.0) if played is not None else member.level
        pose = webxr.hand_pose(by_side.get(self.bridge.config.hand), "controller", self.calibration, arrival)
        touching = bool(pose.valid and level > self.glove.touch_threshold)
        near = self._nearest(pose.position) if touching else ""
        if (touching, near, msg["tracking"]) != (member.level > self.glove.touch_threshold, member.near,
                                                 member.tracking):
            self._class_changed = True
        member.level, member.near, member.tracking = min(float(level), 1.0), near, msg["tracking"]
        if arrival - member.recorded_at >= 1.0 / RECORD_HZ:
            member.recorded_at = arrival
            topic = f"lesson/{'teacher' if member.role == 'teacher' else 'student'}{member.conn}"
            self.record(f"{topic}/hand/pose", pose)
            if played is not None:
                self.record(f"{topic}/tactile/motors", MotorCommand(names=list(self.glove.motor_names),
                                                                    intensity=played["intensity"],
                                                                    source_stamp=arrival))
        if member.role == "student" and member.name == self.spotlight:
            self._show_hand(pose)
        if member.name == self.driver or (self.driver == TEACHER and member.role == "teacher"):
            side = by_side.get(self.bridge.config.controller_hand)
            c = webxr.controller_state(side, self.calibration, arrival)
            if self.control.on_controller(c.position, c.orientation, c.trigger, c.buttons, c.valid):
                self._scene_changed()

    def _nearest(self, position) -> str:
        """The object whose centre (x, y, z) is nearest the hand: what it touches, for the class list."""
        objects = self.control.scene.objects
        if not objects:
            return ""
        d = [float(np.linalg.norm(np.asarray(o.position[:3]) - position)) for o in objects]
        return objects[int(np.argmin(d))].name

    # ---- what the pages are told -------------------------------------------------------------------

    def roster(self) -> list[dict]:
        """The class as the teacher sees it: every page, what it vibrates, whether and what it touches."""
        return [{"name": m.name, "role": m.role, "haptics": m.haptics or "?", "tracking": m.tracking,
                 "touching": m.level > self.glove.touch_threshold, "near": m.near, "level": round(m.level, 2),
                 "view": m.own_view, "slice": m.own_slice} for m in self.members.values()]

    def _tell(self, member: Member, force: bool = False) -> None:
        """The member's lesson frame, when it changed (`force`: again, a refusal's answer)."""
        fields = {"role": member.role, "name": member.name, "locked": self.locked, "driver": self.driver,
                  "spotlight": self.spotlight,
                  "own": {"view": member.own_view, "slice": member.own_slice}}
        if member.role == "teacher":
            fields["roster"] = self.roster()
        frame = pack_frame("lesson", fields)
        if force or frame != member.told:
            member.told = frame
            self.send(member.conn, frame)

