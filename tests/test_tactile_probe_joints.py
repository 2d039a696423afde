"""`touch4d hand joints` and `touch4d tactile probe --joints`: the articulated hand from the command line."""
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import tilted_tesseract
from touch4d.cli import main
from touch4d.tactile.glove import load_glove


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "tilted.yaml"
    path.write_text(tilted_tesseract.SCENE_YAML)
    return path


def run_json(capsys, *args):
    assert main(list(args)) == 0
    return json.loads(capsys.readouterr().out)


def test_hand_joints_flat_prints_the_straight_hand_at_the_pose(capsys):
    q = Rotation.from_euler("z", 90, degrees=True).as_quat()
    out = run_json(capsys, "hand", "joints", "--flat", "--position", "0.1", "0.2", "0.3",
                   "--orientation", *map(str, q))
    assert set(out) == {"handedness", "names", "positions", "orientations", "radii"}
    assert len(out["names"]) == 25 and out["names"][0] == "wrist" and out["names"][-1] == "pinky-finger-tip"
    p = dict(zip(out["names"], np.array(out["positions"])))
    # the glove's index tip (0.035, 0.1225, 0) m, 4 units per metre, turned 90 degrees about z
    np.testing.assert_allclose(p["index-finger-tip"], [0.1 - 0.49, 0.2 + 0.14, 0.3], atol=1e-12)
    np.testing.assert_allclose(p["wrist"], [0.1 + 0.19, 0.2, 0.3], atol=1e-12)
    np.testing.assert_allclose(out["radii"][out["names"].index("index-finger-tip")], 0.036, atol=1e-12)
    # the hand frame is the wrist joint's turned -90 degrees about x (WebXR's axes; tracking.webxr)
    wrist = Rotation.from_quat(out["orientations"][0])
    hand = wrist * Rotation.from_euler("x", -90, degrees=True)
    assert (hand * Rotation.from_quat(q).inv()).magnitude() < 1e-9


def test_probe_with_the_flat_joint_set_matches_the_rigid_pose(capsys, scene_file, tmp_path):
    joints = tmp_path / "flat.json"
    joints.write_text(json.dumps(run_json(capsys, "hand", "joints", "--flat", "--position", "-0.34", "-0.18", "0")))
    rigid = run_json(capsys, "tactile", "probe", "--scene", str(scene_file), "--position", "-0.34", "-0.18", "0",
                     "--json")
    jointed = run_json(capsys, "tactile", "probe", "--scene", str(scene_file), "--joints", str(joints), "--json")
    glove = load_glove()
    # the rigid pose's stimulus worked by hand (tilted_tesseract) is what the joint set gives too
    _, l, s, h, v = tilted_tesseract.stimulus(glove.samples, [-0.34, -0.18, 0], 3.0, 0.5, 1.0, glove.motor_sample)
    assert jointed.keys() == rigid.keys()
    np.testing.assert_allclose([x["l"] for x in jointed["samples"]], l, atol=1e-9)
    np.testing.assert_allclose([x["h"] for x in jointed["samples"]], h, atol=1e-9)
    np.testing.assert_allclose([m["V"] for m in jointed["motors"]], v, atol=1e-9)
    assert [m["name"] for m in jointed["motors"]] == [m["name"] for m in rigid["motors"]]


def test_probe_with_a_curled_index_feels_nothing_on_it_where_the_hand_leaves_the_object(capsys, scene_file, tmp_path):
    # the tilted tesseract spans z in [-0.6, 0.6]: a hand at z = -0.54 curling its index bends it
    # 0.14 units and more toward -z, out of the object
    joints = tmp_path / "curl.json"
    joints.write_text(json.dumps(run_json(capsys, "hand", "joints", "--curl", "index=1", "--position",
                                          "-0.34", "-0.18", "-0.54")))
    out = run_json(capsys, "tactile", "probe", "--scene", str(scene_file), "--joints", str(joints), "--json")
    v = {m["name"]: m["V"] for m in out["motors"]}
    assert all(v[n] == 0 for n in v if n.startswith("index-")) and v["palm-center"] > 0 and v["middle-back-distal"] > 0


@pytest.mark.parametrize("args, words", [
    (["--curl", "pinky=1"], "--curl"), (["--curl", "index=2"], "--curl"), (["--flat", "--curl", "index=1"], "--flat"),
    (["--orientation", "0", "0", "0", "2"], "unit quaternion"),
])
def test_hand_joints_bad_arguments_are_named(capsys, args, words):
    assert main(["hand", "joints", *args]) == 2
    assert words in capsys.readouterr().err


def test_probe_joints_file_mistakes_are_named(capsys, scene_file, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"names": ["wrist"], "positions": [[0, 0, 0]], "orientations": [[0, 0, 0, 1]]}')
    assert main(["tactile", "probe", "--scene", str(scene_file), "--joints", str(bad)]) == 2
    assert "bad.json" in (err := capsys.readouterr().err) and "missing thumb-metacarpal" in err
    bad.write_text('{"names": [], "positions": [[0, 0]], "orientations": []}')
    assert main(["tactile", "probe", "--scene", str(scene_file), "--joints", str(bad)]) == 2
    assert "positions[0]" in capsys.readouterr().err
    assert main(["tactile", "probe", "--scene", str(scene_file)]) == 2
    assert "--joints" in capsys.readouterr().err


def test_the_right_hand_is_the_glove_mirrored_and_feels_the_mirrored_object(capsys, scene_file, tmp_path):
    """The right hand at x = +0.34 in the tilted tesseract feels what the left glove feels at x = -0.34
    in the mirror image of that scene (the tesseract turned +20 degrees in xw, not -20)."""
    right = tmp_path / "right.json"
    right.write_text(json.dumps(run_json(capsys, "hand", "joints", "--handedness", "right", "--curl", "index=0.5",
                                         "--position", "0.34", "-0.18", "0")))
    left = tmp_path / "left.json"
    left.write_text(json.dumps(run_json(capsys, "hand", "joints", "--curl", "index=0.5",
                                        "--position", "-0.34", "-0.18", "0")))
    mirrored_scene = tmp_path / "mirrored.yaml"
    mirrored_scene.write_text(scene_file.read_text().replace("[[xw, -20]]", "[[xw, 20]]"))
    a = run_json(capsys, "tactile", "probe", "--scene", str(scene_file), "--joints", str(right), "--json")
    b = run_json(capsys, "tactile", "probe", "--scene", str(mirrored_scene), "--joints", str(left), "--json")
    pa = np.array([x["position"] for x in a["samples"]])
    pb = np.array([x["position"] for x in b["samples"]])
    np.testing.assert_allclose(pa, pb * [-1, 1, 1], atol=1e-12)
    np.testing.assert_allclose([m["V"] for m in a["motors"]], [m["V"] for m in b["motors"]], atol=1e-9)
    assert max(m["V"] for m in a["motors"]) > 0.3


def test_a_misspelt_finger_of_curl_gets_a_did_you_mean(capsys):
    assert main(["hand", "joints", "--curl", "indx=1"]) == 2
    err = capsys.readouterr().err
    assert "'--curl'" in err and "got 'indx=1'" in err and "(did you mean 'index'?)" in err
    assert main(["hand", "joints", "--curl", "index=2"]) == 2
    assert "did you mean" not in capsys.readouterr().err          # the finger is right, the amount is not
