"""The WebXR node's logic without a bus or a browser: what pages receive, what they publish, and the
fail-safe (a page that closes, hides, loses tracking or falls silent makes the hand invalid)."""
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from touch4d.geometry.scene import load_scene
from touch4d.messages import HandPose, MotorCommand, MotorStatus, StudyTrial, TactileField
from touch4d.tactile.glove import load_glove
from touch4d.tracking.calibration import Placement, load_calibration
from touch4d.web.bridge import BridgeConfig, ClockMap, WebBridge
from touch4d.web.protocol import unpack_frame

REPO = Path(__file__).resolve().parents[1]
GLOVE = load_glove()
SCENE = load_scene(REPO / "config/scenes/hypercube.yaml")


class Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


class Rig:
    def __init__(self, tracker=True, **config):
        self.published, self.broadcasts, self.sent, self.saved = [], [], [], []
        self.clock = Clock()
        self.bridge = WebBridge(BridgeConfig(tracker=tracker, **config), GLOVE,
                                load_calibration(REPO / "config/calibration.yaml", "hand_in_grip"), Placement(0.5, 0.3),
                                publish=lambda topic, msg: self.published.append((topic, msg)),
                                broadcast=lambda data, latest: self.broadcasts.append((unpack_frame(data), latest)),
                                send=lambda conn, data: self.sent.append((conn, unpack_frame(data))),
                                save_calibration=self.saved.append, now=self.clock)

    def input(self, conn, grip=(0.0, 1.2, -0.45, 0, 0, 0, 1), tracking=True, buttons=(), page_time=None, head=None,
              sources=None):
        if sources is None:
            sources = [{"handedness": "right", "grip": list(grip) if grip is not None else None, "trigger": 0.0,
                        "buttons": list(buttons), "joints": None}]
        text = json.dumps({"type": "input", "time": 1000.0 * (page_time if page_time is not None else self.clock.t),
                           "tracking": tracking, "head": head, "sources": sources})
        self.bridge.page_message(conn, text, self.clock.t)

    def topic(self, name):
        return [msg for topic, msg in self.published if topic == name]


def test_a_page_gets_setup_geometry_and_the_latest_frame_on_connect():
    rig = Rig(tracker=False)
    rig.bridge.on_scene(SCENE.to_message())
    assert rig.bridge.frame() is not None
    rig.bridge.connected(7)
    kinds = [frame[0]["kind"] for conn, frame in rig.sent if conn == 7]
    assert kinds == ["setup", "geometry", "frame"]
    header, arrays = rig.sent[0][1]
    assert header["tracker"] is False and len(header["motor_names"]) == 30
    assert arrays["samples"].shape == (len(GLOVE.samples), 3)
    np.testing.assert_allclose(arrays["samples"], GLOVE.samples * 4.0, rtol=1e-6)   # 0.5 m screen: 4 units per m
    assert header["screen_edge"] == 0.5 and header["screen_center"] == [0.0, 1.2, -0.45]


def test_geometry_is_sent_once_per_change_of_shape_and_frames_carry_only_transforms():
    rig = Rig(tracker=False)
    rig.bridge.on_scene(SCENE.to_message())
    turned = SCENE.copy()
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    turned.objects[0].orientation = turn
    turned.revision = 5
    rig.bridge.on_scene(turned.to_message())
    geometry = [(f, latest) for f, latest in rig.broadcasts if f[0]["kind"] == "geometry"]
    assert len(geometry) == 1 and geometry[0][1] is False          # sent once, never dropped
    (header, arrays), _ = geometry[0]
    # a tesseract: 16 vertices, 8 cells, 24 square 2-faces (48 triangles), 32 edges
    assert header["bodies"] == 1 and header["objects"] == 1
    assert arrays["t_vertices"].reshape(-1, 4)[:16].shape == (16, 4) and arrays["fills"].shape == (144, 7)
    assert arrays["edges"].shape == (32, 17) and arrays["t_halfspaces"].reshape(-1, 4).shape[0] >= 8
    header, arrays = unpack_frame(rig.bridge.frame())
    assert header["revision"] == 5 and header["geometry"] == geometry[0][0][0]["key"]
    # per frame the scene is 6 texels per object: the orientation's columns, the position, the size
    assert arrays["t_objects"].nbytes == 96
    texels = arrays["t_objects"].reshape(-1, 4)
    obj = turned.objects[0]
    np.testing.assert_allclose(texels[:4], turn.T, atol=1e-7)
    np.testing.assert_allclose(texels[4], obj.position)
    assert texels[5][0] == pytest.approx(obj.size)
    assert not {"fills", "edges", "centres", "t_vertices"} & arrays.keys()
    other = SCENE.copy()
    other.objects[0].shape = "16-cell"
    rig.bridge.on_scene(other.to_message())
    assert len([f for f, _ in rig.broadcasts if f[0]["kind"] == "geometry"]) == 2


def test_the_page_gets_the_renderers_shaders_as_glsl_es():
    header, _ = unpack_frame(Rig().bridge.setup_frame())
    shaders = header["shaders"]
    assert {"scene_face.vert", "scene.frag", "oit.frag", "line.vert"} <= shaders.keys()
    assert all(src.startswith("#version 300 es\n") for src in shaders.values())
    assert "#include" not in shaders["scene.frag"] and "bool hidden(" in shaders["scene.frag"]


def test_frames_only_when_something_changed_and_carry_the_tactile_values():
    rig = Rig(tracker=False)
    assert rig.bridge.frame() is None
    n, m = len(GLOVE.samples), len(GLOVE.motor_names)
    l = np.full(n, np.nan)
    l[:10] = 0.2
    h = np.zeros(n)
    h[:10] = 0.7
    rig.bridge.on_field(TactileField(positions=np.zeros((n, 3)), l=l, s=h, h=h))
    rig.bridge.on_motors(MotorCommand(names=list(GLOVE.motor_names), intensity=np.full(m, 0.3)))
    rig.bridge.on_hand_pose(HandPose(position=[0.1, 0.2, 0.3], valid=True))
    rig.bridge.on_status(MotorStatus(boards=[dict(id=1, online=True, faults=[], last_frame=1.0, state="operational")],
                                     duty=np.full(m, 0.5), bus_load=0.4, errors={}))
    header, arrays = unpack_frame(rig.bridge.frame())
    assert header["hand_valid"] and header["boards"] == [{"id": 1, "online": True, "state": "operational"}]
    np.testing.assert_allclose(arrays["h"][:10], 0.7, rtol=1e-6)
    assert arrays["touched"].tolist() == [1] * 10 + [0] * (n - 10)
    np.testing.assert_allclose(arrays["hand"], [0.1, 0.2, 0.3, 0, 0, 0, 1], rtol=1e-6)
    np.testing.assert_allclose(arrays["duty"], 0.5)
    assert rig.bridge.frame() is None


def test_the_tracker_page_publishes_the_hand_in_screen_coordinates():
    rig = Rig()
    rig.bridge.connected(1)
    rig.input(1, grip=(0.05, 1.2, -0.45, 0, 0, 0, 1))
    (pose,) = rig.topic("hand/pose")
    assert pose.valid and np.allclose(pose.position, [0.2, 0.0, 0.0])
    (state,) = rig.topic("controller/state")
    assert state.valid and np.allclose(state.position, [0.05, 1.2, -0.45])


def test_a_tracked_hand_publishes_its_joints():
    rig = Rig(hand_source="hand")
    rig.bridge.connected(1)
    joints = [[0.0, 1.2, -0.45 + 0.01 * k, 0, 0, 0, 1, 0.01] for k in range(25)]
    rig.input(1, sources=[{"handedness": "right", "grip": None, "trigger": 0.0, "buttons": [], "joints": joints}])
    (msg,) = rig.topic("hand/joints")
    assert msg.valid and msg.positions.shape == (25, 3) and np.allclose(msg.positions[3], [0, 0, 0.12])
    assert rig.topic("hand/pose")[0].valid


def test_view_only_pages_publish_nothing():
    rig = Rig(tracker=False)
    rig.bridge.connected(1)
    rig.input(1)
    rig.clock.t += 1.0
    rig.bridge.tick()
    assert rig.published == [] and rig.bridge.counts["page_ignored"] == 1


def test_a_second_page_cannot_drive_while_the_first_tracks_and_is_told_so_not_silently(caplog):
    rig = Rig()
    rig.bridge.connected(1, "192.168.1.20:50000")
    rig.bridge.connected(2, "192.168.1.66:50001")
    rig.input(1, grip=(0.05, 1.2, -0.45, 0, 0, 0, 1))
    # The second page (same token) enters VR and sends a hand elsewhere: refused while page 1 tracks.
    rig.bridge.page_message(2, '{"type": "session", "mode": "immersive", "active": true}', rig.clock.t)
    with caplog.at_level("WARNING", logger="touch4d.web.bridge"):
        for _ in range(3):
            rig.clock.t += 0.01
            rig.input(2, grip=(-0.05, 1.2, -0.45, 0, 0, 0, 1))
            rig.input(1, grip=(0.05, 1.2, -0.45, 0, 0, 0, 1))
    poses = rig.topic("hand/pose")
    assert len(poses) == 4 and all(np.allclose(p.position, [0.2, 0.0, 0.0]) for p in poses)   # page 1's only
    assert rig.bridge.counts["page_not_driver"] == 3
    warned = [r.getMessage() for r in caplog.records]
    assert len(warned) == 1 and "192.168.1.66" in warned[0] and "192.168.1.20" in warned[0]
    told = [frame for conn, frame in rig.sent if conn == 2 and frame[0]["kind"] == "driver"]
    assert len(told) == 1 and told[0][0]["driver"] is False
    # ... and never where the other page is: no frame to a page carries another page's address
    assert not any("192.168.1" in json.dumps(frame[0]) for conn, frame in rig.sent)
    # Re-centring from the other page is refused too.
    rig.bridge.page_message(2, json.dumps({"type": "recenter", "head": [0, 1.6, 0, 0, 0, 0, 1]}), rig.clock.t)
    assert rig.bridge.counts["recentred"] == 0 and rig.bridge.counts["page_not_driver"] == 4


@pytest.mark.parametrize("how", ["tracking lost", "silent", "session end", "close"])
def test_when_the_driving_page_stops_tracking_another_takes_over(how):
    rig = Rig()
    rig.bridge.connected(1, "a")
    rig.bridge.connected(2, "b")
    rig.input(1)
    if how == "tracking lost":
        rig.input(1, tracking=False)
    elif how == "silent":
        rig.clock.t += 0.051   # stale_s
    elif how == "session end":
        rig.bridge.page_message(1, '{"type": "session", "mode": "immersive", "active": false}', rig.clock.t)
    else:
        rig.bridge.closed(1)
    rig.input(2, grip=(-0.05, 1.2, -0.45, 0, 0, 0, 1))
    assert rig.bridge.owner == 2 and rig.bridge.counts["page_not_driver"] == 0
    assert np.allclose(rig.topic("hand/pose")[-1].position, [-0.2, 0.0, 0.0]) and rig.topic("hand/pose")[-1].valid
    assert [frame[0]["driver"] for conn, frame in rig.sent if conn == 2 and frame[0]["kind"] == "driver"] == [True]
    if how != "close":   # and the first page, back, waits its turn
        rig.input(1)
        assert rig.bridge.owner == 2 and rig.bridge.counts["page_not_driver"] == 1


@pytest.mark.parametrize("how", ["close", "hide", "tracking lost", "silent", "session end"])
def test_the_hand_turns_invalid_at_once_when_the_page_stops_tracking(how):
    rig = Rig()
    rig.bridge.connected(1)
    rig.input(1)
    assert rig.topic("hand/pose")[-1].valid
    rig.clock.t += 0.01
    if how == "close":
        rig.bridge.closed(1)
    elif how == "hide":
        rig.input(1, tracking=False, sources=[])     # what the page sends when hidden
    elif how == "tracking lost":
        rig.input(1, grip=None)                      # the controller's grip pose is gone
    elif how == "silent":
        rig.clock.t += 0.07            # over stale_s (0.05 s)
        rig.bridge.tick()
    else:
        rig.bridge.page_message(1, '{"type": "session", "mode": "immersive", "active": false}', rig.clock.t)
    poses, states = rig.topic("hand/pose"), rig.topic("controller/state")
    assert not poses[-1].valid
    # a controller that only fell silent moved nothing: its grab survives; otherwise it is gone too
    assert states[-1].valid == (how == "silent")
    # and again while nobody tracks, so the motors stay off
    count = len(poses)
    rig.clock.t += 0.11
    rig.bridge.tick()
    assert len(rig.topic("hand/pose")) == count + 1 and not rig.topic("hand/pose")[-1].valid


def test_a_tracker_bridge_is_next_due_when_its_page_would_fall_silent_then_every_invalid_period():
    """WebBridge.next_due, on a hand-moved clock: stale_s after the driving page's last input (each
    input moves it on), then the invalid pose, then every invalid_period_s while nobody tracks."""
    rig = Rig()
    rig.bridge.connected(1)
    t1 = rig.clock.t
    rig.input(1)
    rig.bridge.tick()
    assert rig.bridge.next_due() == t1 + 0.05
    rig.clock.t = t1 + 0.02
    rig.input(1)
    rig.bridge.tick()
    assert rig.bridge.next_due() == (t1 + 0.02) + 0.05
    rig.clock.t = (t1 + 0.02) + 0.05 + 1e-6
    rig.bridge.tick()
    assert not rig.topic("hand/pose")[-1].valid
    assert rig.bridge.next_due() == rig.clock.t + 0.1
    count = len(rig.topic("hand/pose"))
    rig.clock.t += 0.1
    rig.bridge.tick()
    assert len(rig.topic("hand/pose")) == count + 1 and rig.bridge.next_due() == rig.clock.t + 0.1


def test_no_invalid_pose_while_the_page_tracks():
    rig = Rig()
    rig.bridge.connected(1)
    for _ in range(10):
        rig.clock.t += 0.03
        rig.input(1)
        rig.bridge.tick()
    assert all(p.valid for p in rig.topic("hand/pose"))


def test_bad_messages_are_counted_by_cause_and_the_page_keeps_working():
    rig = Rig()
    rig.bridge.connected(1)
    for text in ("{oops", '{"type": "input", "time": NaN}', "x" * 20000, b"\x00"):
        rig.bridge.page_message(1, text, rig.clock.t)
    c = rig.bridge.counts
    assert (c["page_malformed"], c["page_non_finite"], c["page_oversized"]) == (2, 1, 1)
    rig.input(1)
    assert rig.topic("hand/pose")[-1].valid and c["page_messages"] == 5


def test_recentre_button_moves_the_screen_stores_it_and_tells_every_page():
    rig = Rig()
    rig.bridge.connected(1)
    head = [0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0]
    rig.input(1, buttons=("a",), head=head)
    rig.input(1, buttons=("a",), head=head)        # held: one re-centre, not one per frame
    assert rig.bridge.counts["recentred"] == 1 and len(rig.saved) == 1
    assert np.allclose(rig.saved[0].center_m, [0.0, 1.4, -0.5])
    (frame,) = [f for f, _ in rig.broadcasts if f[0]["kind"] == "calibration"]
    assert frame[0]["screen_center"] == pytest.approx([0.0, 1.4, -0.5])
    # the hand is now placed against the new screen
    rig.input(1, grip=(0.0, 1.4, -0.5, 0, 0, 0, 1))
    assert np.allclose(rig.topic("hand/pose")[-1].position, 0.0, atol=1e-9)


def test_clock_map_removes_the_offset_and_keeps_the_delay_above_the_best():
    clock = ClockMap(window=50)
    offset = 123.456                          # page clock behind by this much
    kept = []
    for k, delay in enumerate([0.004, 0.002, 0.010, 0.003]):
        page = 10.0 + k
        arrival = page + offset + delay
        kept.append(arrival - clock.stamp(page, arrival))
    # what the stamp keeps of each delay: all of it above the best one seen so far (4 ms, then 2 ms)
    assert kept == pytest.approx([0.0, 0.0, 0.008, 0.001], abs=1e-9)


def test_each_change_of_boards_study_or_scene_shows_in_the_next_frame_and_stays():
    # the frame's rarely changing fields are encoded once per change: every change must still reach the page
    rig = Rig(tracker=False)
    rig.bridge.on_scene(SCENE.to_message())
    first, _ = unpack_frame(rig.bridge.frame())
    assert first["boards"] == [] and first["study"] is None and first["revision"] == SCENE.revision
    board = dict(id=2, online=False, faults=[], last_frame=1.0, state="bus-off")
    rig.bridge.on_status(MotorStatus(boards=[board], duty=np.zeros(len(GLOVE.motor_names)), bus_load=0.1, errors={}))
    header, _ = unpack_frame(rig.bridge.frame())
    assert header["boards"] == [{"id": 2, "online": False, "state": "bus-off"}]
    rig.bridge.on_trial(StudyTrial(study="s", participant="P01", phase="stimulus", index=3, total=9,
                                   condition="visual", prompt="Which?", options=["x", "y"], onset=1.0))
    header, _ = unpack_frame(rig.bridge.frame())
    assert header["study"]["prompt"] == "Which?" and header["study"]["index"] == 3
    assert header["boards"] == [{"id": 2, "online": False, "state": "bus-off"}]
    turned = SCENE.copy()
    turned.revision, turned.selected = SCENE.revision + 7, 0
    turned.objects[0].position = turned.objects[0].position + np.array([0.25, 0, 0, 0])
    rig.bridge.on_scene(turned.to_message())
    header, arrays = unpack_frame(rig.bridge.frame())
    assert header["revision"] == SCENE.revision + 7 and header["study"]["prompt"] == "Which?"
    np.testing.assert_allclose(arrays["t_objects"].reshape(-1, 4)[4], turned.objects[0].position, rtol=1e-6)
    rig.clock.t += 1.0
    rig.bridge.on_hand_pose(HandPose(position=[0.1, 0.2, 0.3], valid=True))
    again, _ = unpack_frame(rig.bridge.frame())
    assert again["n"] == header["n"] + 1 and again["time"] == rig.clock.t and again["hand_valid"] is True
    assert {k: v for k, v in again.items() if k not in ("n", "time", "hand_valid", "arrays")} == \
        {k: v for k, v in header.items() if k not in ("n", "time", "hand_valid", "arrays")}


def test_the_frame_shows_a_nan_strength_as_zero_and_keeps_the_others():
    rig = Rig(tracker=False)
    n = len(GLOVE.samples)
    h = np.linspace(0.0, 1.0, n)
    h[3] = np.nan                                  # a field handed over unchecked (on_field is called directly)
    rig.bridge.on_field(TactileField(positions=np.zeros((n, 3)), l=np.full(n, 0.5), s=h, h=h))
    _, arrays = unpack_frame(rig.bridge.frame())
    expected = np.linspace(0.0, 1.0, n).astype(np.float32)
    expected[3] = 0.0
    np.testing.assert_array_equal(arrays["h"], expected)
    rig.bridge.on_field(TactileField(positions=np.zeros((n, 3)), l=np.full(n, 0.5), s=h, h=np.full(n, 0.25)))
    _, arrays = unpack_frame(rig.bridge.frame())
    assert arrays["h"].tolist() == [0.25] * n
