"""The lesson's logic without a network (touch4d.web.lesson): one scene, every page's frames, the
teacher's commands, a student's own slice and the lock, the class list, the driver, the recording."""
from __future__ import annotations

import json
from collections import defaultdict

import numpy as np
import pytest

from touch4d.commands.lesson import Recording
from touch4d.geometry.scene import load_scene
from touch4d.log.reader import LogReader
from touch4d.log.replay import Plan, ReplayOptions, Replayer
from touch4d.messages import SceneState, decode
from touch4d.render.view import SceneView
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import load_calibration, load_placement
from touch4d.web.lesson import Lesson, LessonError
from touch4d.web.protocol import unpack_frame

SCENE = "config/scenes/hypercube.yaml"
GLOVE = "config/gloves/quest-controller.yaml"
TEACHER, S1, S2, S3 = 1, 2, 3, 4
CLASS_W = 1.5        # the scene file's slice_w (the hypercube spans w 0.9 .. 2.1)


class Pages:
    """What the lesson sent each page, decoded: (kind, fields, arrays), in order."""

    def __init__(self):
        self.sent = defaultdict(list)

    def send(self, conn, data):
        fields, arrays = unpack_frame(data)
        self.sent[conn].append((fields["kind"], fields, arrays))

    def kinds(self, conn):
        return [k for k, _, _ in self.sent[conn]]

    def last(self, conn, kind):
        return next((f, a) for k, f, a in reversed(self.sent[conn]) if k == kind)


def lesson_with_pages(record=None, revoked=None):
    pages = Pages()
    calibration = load_calibration(None, "hand_in_grip")
    lesson = Lesson(load_scene(SCENE), load_glove(GLOVE), calibration, load_placement(None), pages.send, pages.send,
                    record, revoke=None if revoked is None else revoked.append)
    lesson.connected(TEACHER, "teacher")
    lesson.connected(S1, "s1")
    lesson.connected(S2, "s2")
    return lesson, pages, calibration


def test_every_page_gets_the_setup_of_its_own_touch_the_geometry_and_the_scene():
    lesson, pages, _ = lesson_with_pages()
    for conn in (TEACHER, S1, S2):
        assert pages.kinds(conn)[:3] == ["setup", "geometry", "frame"]
        setup, _ = pages.last(conn, "setup")
        assert setup["tracker"] is True and setup["touch"] == "page"   # static/touch.js computes its touch
    assert pages.last(TEACHER, "lesson")[0]["role"] == "teacher"
    assert pages.last(S1, "lesson")[0]["role"] == "student"
    lesson.heartbeat()                                    # the class list: refreshed with the heartbeat
    roster = pages.last(TEACHER, "lesson")[0]["roster"]
    assert [m["role"] for m in roster] == ["teacher", "student", "student"]


def test_a_command_reaches_every_page_and_a_late_joiner_gets_the_current_state():
    lesson, pages, _ = lesson_with_pages()
    before = pages.last(S1, "frame")[0]["revision"]
    lesson.command("view", "slice")
    lesson.command("slice", "1.3")
    for conn in (TEACHER, S1, S2):
        frame, arrays = pages.last(conn, "frame")
        assert frame["view"] == "slice" and frame["slice_w"] == 1.3 and frame["revision"] == before + 2
        assert arrays["section"].size > 0          # the hypercube (w 0.9 .. 2.1) cut at w = 1.3: a solid
    lesson.connected(S3, "s3")
    assert pages.kinds(S3)[:3] == ["setup", "geometry", "frame"]
    frame, arrays = pages.last(S3, "frame")
    assert frame["view"] == "slice" and frame["slice_w"] == 1.3 and frame["revision"] == before + 2
    assert np.array_equal(arrays["section"], pages.last(S1, "frame")[1]["section"])


def test_rotate_turns_the_selected_object_in_its_plane():
    lesson, pages, _ = lesson_with_pages()
    before = np.array(lesson.control.scene.objects[0].orientation)
    lesson.command("rotate", "xw 90")
    turned = np.array(lesson.control.scene.objects[0].orientation)
    # x -> w, w -> -x (the plane rotation x_a' = cos x_a - sin x_b, x_b' = sin x_a + cos x_b)
    quarter = np.eye(4)
    quarter[[0, 3], [0, 3]] = 0
    quarter[3, 0], quarter[0, 3] = 1, -1
    assert np.allclose(turned, quarter @ before)
    assert pages.last(S2, "frame")[0]["revision"] == lesson.control.scene.revision


def test_a_students_own_slice_is_theirs_alone_until_the_teacher_locks_it():
    lesson, pages, _ = lesson_with_pages()
    lesson.command("rotate", "xw 30")          # turned: its cross-sections differ with w
    lesson.command("view", "slice")
    lesson.message(S1, json.dumps({"type": "own", "view": "slice", "slice": 1.7}), 0.0)
    mine, mine_arrays = pages.last(S1, "frame")
    theirs, theirs_arrays = pages.last(S2, "frame")
    assert mine["slice_w"] == 1.7 and theirs["slice_w"] == CLASS_W
    # each page touches the cross-section it shows: its own cut, the class's
    assert mine["touch_section"] and mine["touch_w"] == 1.7
    assert theirs["touch_section"] and theirs["touch_w"] == CLASS_W
    expected = SceneView(view="slice", slice_w=1.7)
    expected.set_scene(lesson.control.message())
    assert np.allclose(mine_arrays["section"], np.asarray(expected.section, np.float32).ravel())
    assert not np.array_equal(mine_arrays["section"], theirs_arrays["section"])
    assert pages.last(S1, "lesson")[0]["own"] == {"view": "slice", "slice": 1.7}
    lesson.heartbeat()                                    # the heartbeat keeps each page's own frame
    assert pages.last(S1, "frame")[0]["slice_w"] == 1.7
    lesson.command("lock")
    assert pages.last(S1, "frame")[0]["slice_w"] == CLASS_W
    assert pages.last(S1, "lesson")[0]["locked"] is True
    lesson.message(S1, json.dumps({"type": "own", "view": "both", "slice": 1.9}), 0.0)
    lesson.heartbeat()
    assert pages.last(S1, "frame")[0]["slice_w"] == CLASS_W and pages.last(S1, "frame")[0]["view"] == "slice"
    assert lesson.counts["refused"] == 1
    lesson.command("unlock")
    lesson.message(S1, json.dumps({"type": "own", "view": "both", "slice": 1.9}), 0.0)
    assert pages.last(S1, "frame")[0]["slice_w"] == 1.9 and pages.last(S1, "frame")[0]["view"] == "both"
    assert not pages.last(S1, "frame")[0]["touch_section"]   # the both view: the projection is touched


@pytest.mark.parametrize("verb, argument, expected", [
    ("fly", "", "expected one of next"),
    ("rotate", "zz 10", "expected PLANE DEG"),
    ("rotate", "xw many", "expected PLANE DEG"),
    ("slice", "deep", "slice: expected where to cut"),
    ("view", "sideways", "view: expected projection, slice, both"),
    ("drive", "nobody", "drive: expected 'teacher' or a connected student's name"),
    ("lock", "now", "lock: takes no argument"),
    ("spotlight", "nobody", "spotlight: expected 'off' or a connected student's name"),
    ("remove", "teacher", "remove: expected a connected student's name"),
    ("load", "objects: [", "scene/command load"),
])
def test_a_bad_command_says_what_was_expected_and_changes_nothing(verb, argument, expected):
    lesson, pages, _ = lesson_with_pages()
    revision, frames = lesson.control.scene.revision, len(pages.sent[S1])
    with pytest.raises(LessonError, match=expected):
        lesson.command(verb, argument)
    assert lesson.control.scene.revision == revision and len(pages.sent[S1]) == frames


def test_only_the_teacher_commands_and_bad_messages_are_counted_not_fatal():
    lesson, pages, _ = lesson_with_pages()
    revision = lesson.control.scene.revision
    lesson.message(S1, json.dumps({"type": "command", "verb": "next", "argument": ""}), 0.0)
    assert lesson.counts["refused"] == 1 and lesson.control.scene.revision == revision
    for bad in ("{", '{"type": "own", "slice": NaN}', '{"type": "own", "view": "inside"}', "x" * 100000,
                '{"type": "input", "time": -1}', b"\xff\xfe", '{"type": "hello", "name": 7}'):
        lesson.message(S2, bad, 0.0)
    assert lesson.counts["malformed"] == 7
    lesson.message(TEACHER, json.dumps({"type": "command", "verb": "slice", "argument": "0.2"}), 0.0)
    assert pages.last(TEACHER, "result")[0] == {"kind": "result", "ok": True, "text": "slice 0.2"}
    assert pages.last(S2, "frame")[0]["slice_w"] == 0.2
    lesson.message(TEACHER, json.dumps({"type": "command", "verb": "slice", "argument": "no"}), 0.0)
    assert pages.last(TEACHER, "result")[0]["ok"] is False


def test_a_name_is_shown_escaped_and_short_and_never_twice():
    lesson, pages, _ = lesson_with_pages()
    lesson.message(S1, json.dumps({"type": "hello", "name": "Ann\x1b[31m\u202e" + "x" * 60}), 0.0)
    name = pages.last(S1, "lesson")[0]["name"]
    assert name.startswith("Ann\\x1b[31m\\u202e") and len(name) == 32
    lesson.message(S2, json.dumps({"type": "hello", "name": name}), 0.0)
    assert pages.last(S2, "lesson")[0]["name"] == "student 2"


def input_message(calibration, hand_at, trigger=0.0, played=None, time_ms=1000.0):
    """A page's input whose glove hand (the right controller) is at `hand_at` (screen units)."""
    room, quat = calibration.controller_from_hand(np.asarray(hand_at, float), np.array([0.0, 0.0, 0.0, 1.0]))
    source = {"handedness": "right", "trigger": trigger, "buttons": [], "grip": [*room.tolist(), *quat.tolist()]}
    return json.dumps({"type": "input", "time": time_ms, "tracking": True, "head": None, "sources": [source],
                       "played": played})


def test_the_teacher_sees_who_touches_what_with_what_haptics():
    lesson, pages, calibration = lesson_with_pages()
    lesson.message(S1, json.dumps({"type": "haptics", "output": "pulse"}), 0.0)
    lesson.message(S1, input_message(calibration, [0, 0, 0], played={"time": 900.0, "intensity": [1.0]}), 1.0)
    lesson.message(S2, input_message(calibration, [0, 0, 0], played={"time": 900.0, "intensity": [0.0]}), 1.0)
    lesson.heartbeat()
    roster = {m["name"]: m for m in pages.last(TEACHER, "lesson")[0]["roster"]}
    assert roster["student 1"]["haptics"] == "pulse" and roster["student 1"]["touching"] is True
    assert roster["student 1"]["near"] == lesson.control.scene.objects[0].name
    assert roster["student 2"]["touching"] is False and roster["student 2"]["haptics"] == "?"
    lesson.closed(S2)
    lesson.heartbeat()
    assert [m["name"] for m in pages.last(TEACHER, "lesson")[0]["roster"]] == ["teacher", "student 1"]


def test_the_driver_alone_turns_the_object():
    lesson, pages, calibration = lesson_with_pages()
    revision = lesson.control.scene.revision
    for k, x in enumerate((0.0, 0.3, 0.6)):      # a student's trigger held while moving: not the driver
        lesson.message(S1, input_message(calibration, [x, 0, 0], trigger=1.0, time_ms=1000.0 + k), 1.0 + k)
    assert lesson.control.scene.revision == revision
    lesson.command("drive", "student 1")
    assert pages.last(S2, "lesson")[0]["driver"] == "student 1"
    for k, x in enumerate((0.0, 0.3, 0.6)):
        lesson.message(S1, input_message(calibration, [x, 0, 0], trigger=1.0, time_ms=2000.0 + k), 5.0 + k)
    assert lesson.control.scene.revision > revision
    assert pages.last(S2, "frame")[0]["revision"] == lesson.control.scene.revision


def test_the_lesson_is_recorded_for_replay(tmp_path):
    recording = Recording(tmp_path / "lesson.mcap")
    lesson, pages, calibration = lesson_with_pages(recording)
    lesson.command("slice", "0.25")
    lesson.message(S1, input_message(calibration, [0, 0, 0], played={"time": 900.0, "intensity": [0.5]}), 1.0)
    lesson.message(S1, input_message(calibration, [0, 0, 0], time_ms=1001.0), 1.01)   # within 1 / RECORD_HZ
    lesson.command("lock")
    with pytest.raises(LessonError):
        lesson.command("drive", "nobody")                # refused: not recorded
    lesson.command("unlock")
    recording.close()
    messages = list(LogReader(tmp_path / "lesson.mcap").messages())
    topics = [m.topic for m in messages]
    assert topics.count("scene/state") == 2
    # the class's commands too, in order
    assert [(c["command"], c["argument"]) for c in (m.decode() for m in messages if m.topic == "lesson/command")] \
        == [("slice", "0.25"), ("lock", ""), ("unlock", "")]
    assert topics.count(f"lesson/student{S1}/hand/pose") == 1
    assert topics.count(f"lesson/student{S1}/tactile/motors") == 1
    states = [m.decode() for m in messages if m.topic == "scene/state"]
    assert states[-1]["slice_w"] == 0.25
    command = next(m.decode() for m in messages if m.topic == "lesson/command")
    assert (command["command"], command["argument"]) == ("slice", "0.25")


def test_touch4d_replay_plays_the_recorded_lesson(tmp_path):
    """What `touch4d replay` sends (its Replayer): the lesson's scenes in order, as the bus carries them."""
    recording = Recording(tmp_path / "lesson.mcap")
    lesson, _, calibration = lesson_with_pages(recording)
    lesson.command("rotate", "xw 30")
    lesson.command("view", "both")
    lesson.message(S1, input_message(calibration, [0.1, 0, 0]), 1.0)
    recording.close()
    reader = LogReader(tmp_path / "lesson.mcap")
    options = ReplayOptions(realtime=False, rate=100.0)
    sent = []
    Replayer(reader, Plan(reader, options), options, lambda topic, data: sent.append((topic, data))).run()
    scenes = [decode(data) for topic, data in sent if topic == "scene/state"]
    assert all(isinstance(s, SceneState) for s in scenes)
    assert [s.view for s in scenes] == ["projection", "projection", "both"]
    assert np.allclose(scenes[-1].objects[0]["orientation"], lesson.control.scene.objects[0].orientation)
    hands = [decode(data) for topic, data in sent if topic == f"lesson/student{S1}/hand/pose"]
    assert len(hands) == 1 and hands[0].valid and np.allclose(hands[0].position, [0.1, 0, 0], atol=1e-6)


def test_every_page_shows_the_spotlit_students_hand():
    lesson, pages, calibration = lesson_with_pages()
    lesson.message(S1, input_message(calibration, [0.2, -0.1, 0.3]), 1.0)
    assert pages.last(S2, "frame")[0]["hand_valid"] is False          # nobody's hand yet
    lesson.command("spotlight", "student 1")
    lesson.message(S1, input_message(calibration, [0.2, -0.1, 0.3], time_ms=1100.0), 1.1)
    for conn in (TEACHER, S2):
        frame, arrays = pages.last(conn, "frame")
        assert frame["hand_valid"] is True and np.allclose(arrays["hand"][:3], [0.2, -0.1, 0.3], atol=1e-5)
    assert pages.last(S2, "lesson")[0]["spotlight"] == "student 1"
    lesson.message(S2, input_message(calibration, [-0.5, 0, 0], time_ms=1200.0), 1.2)   # not the spotlit one
    assert np.allclose(pages.last(TEACHER, "frame")[1]["hand"][:3], [0.2, -0.1, 0.3], atol=1e-5)
    lesson.closed(S1)                                                    # the spotlit student leaves
    assert pages.last(S2, "frame")[0]["hand_valid"] is False
    assert pages.last(S2, "lesson")[0]["spotlight"] is None


def test_remove_ends_that_students_access_alone():
    revoked = []
    lesson, pages, _ = lesson_with_pages(revoked=revoked)
    lesson.message(S2, json.dumps({"type": "hello", "name": "Bo"}), 0.0)
    assert lesson.command("remove", "Bo") == "remove Bo"
    assert revoked == ["s2"]


def test_a_recording_that_fails_stops_and_the_lesson_goes_on(tmp_path, capsys):
    recording = Recording(tmp_path / "lesson.mcap")
    lesson, pages, _ = lesson_with_pages(recording)

    def full(*args):
        raise OSError(28, "No space left on device")

    recording.writer.write = full
    lesson.command("slice", "1.2")                       # recorded: fails; carried out all the same
    assert pages.last(S1, "frame")[0]["slice_w"] == 1.2
    assert recording.failed and "recording stopped" in capsys.readouterr().err
    lesson.command("slice", "1.4")
    assert pages.last(S1, "frame")[0]["slice_w"] == 1.4


def test_a_student_page_that_reconnects_keeps_its_number_and_the_next_student_gets_the_next():
    lesson, pages, _ = lesson_with_pages()
    lesson.closed(S1)
    lesson.connected(5, "s1")                             # s1's page back on a new connection
    lesson.connected(S3, "s3")
    lesson.heartbeat()
    names = {m["name"] for m in pages.last(TEACHER, "lesson")[0]["roster"]}
    assert names == {"teacher", "student 1", "student 2", "student 3"}
