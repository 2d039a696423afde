"""Scene files and scene/state messages."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from touch4d.errors import ConfigError
from touch4d.geometry import scene as scene_mod
from touch4d.geometry.rotation import plane_rotation
from touch4d.geometry.scene import Scene, load_scene, parse_scene
from touch4d.messages import SceneState, decode, encode

SCENES = Path(__file__).parent / "data" / "scenes"


def test_tesseract_scene_places_the_front_cell_at_one():
    scene = load_scene(SCENES / "tesseract_front.yaml")
    assert scene.projection == "orthographic" and len(scene.objects) == 1
    (index, poly), = scene.world_parts()
    assert index == 0
    front = np.argmin(poly.normals[:, 3])
    assert np.allclose(poly.normals[front], [0, 0, 0, -1]) and poly.offsets[front] == pytest.approx(-1.0)
    assert np.allclose(scene.objects[0].color, [0.3, 0.65, 1.0, 1.0])
    t, hit = scene.ray_caster().cast([[0.1, 0.2, -0.3]])
    assert t[0] == pytest.approx(1.0) and hit[0] == 0


def test_mixed_scene_rotation_order_custom_shapes_and_perspective():
    scene = load_scene(SCENES / "mixed.yaml")
    assert scene.projection == "perspective" and scene.eye_distance == 4
    duo = scene.objects[0]
    expected = plane_rotation("yz", np.radians(10)) @ plane_rotation("xw", np.radians(30))
    assert np.allclose(duo.orientation, expected)
    assert duo.params == {"p": 5, "q": 6}
    assert scene.objects[1].name == "24-cell1"
    simplex = scene.objects[2]
    assert simplex.shape == "custom" and len(simplex.custom_parts) == 1
    world = simplex.world_parts()[0]
    # vertices are multiplied by size, then placed.
    assert np.allclose(np.sort(world.vertices, axis=0), np.sort(0.5 * np.array(
        [[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]) + [0, -0.6, 0, 1], axis=0))
    step = scene.objects[3]
    assert len(step.custom_parts) == 2 and len(step.world_parts()) == 2
    assert [i for i, _ in scene.world_parts()] == [0, 1, 2, 3, 3]


def test_halfspaces_scale_with_size(tmp_path):
    rows = [[*s * np.eye(4)[i], 1.0] for i in range(4) for s in (1, -1)]
    f = tmp_path / "h.yaml"
    f.write_text(yaml.safe_dump({"objects": [{"halfspaces": [list(map(float, r)) for r in rows], "size": 0.25}]}))
    (_, poly), = load_scene(f).world_parts()
    assert np.allclose(np.abs(poly.vertices), 0.25)


@pytest.mark.parametrize("name", ["tesseract_front", "mixed", "stacked"])
def test_message_round_trip_over_the_wire(name):
    scene = load_scene(SCENES / f"{name}.yaml")
    scene.revision = 7
    msg = scene.to_message()
    assert isinstance(msg, SceneState)
    back = Scene.from_message(decode(encode(msg)))
    assert back.projection == scene.projection and back.eye_distance == scene.eye_distance
    assert back.revision == 7 and back.selected == scene.selected
    for (i, a), (j, b) in zip(scene.world_parts(), back.world_parts(), strict=True):
        assert i == j and np.allclose(a.vertices, b.vertices) and np.allclose(a.offsets, b.offsets)
    maps = msg.objects
    assert all(("parts" in m) == (m["shape"] == "custom") for m in maps)


def test_rebuilding_a_rotated_scene_runs_no_hull(monkeypatch):
    scene = load_scene(SCENES / "mixed.yaml")
    Scene.from_message(scene.to_message())                     # warm the caches
    for obj in scene.objects:
        obj.orientation = plane_rotation("zw", 0.3) @ obj.orientation
    calls = []
    monkeypatch.setattr(scene_mod.Polytope, "from_vertices", classmethod(lambda cls, *a, **k: calls.append(1)))
    monkeypatch.setattr(scene_mod.Polytope, "from_halfspaces", classmethod(lambda cls, *a, **k: calls.append(1)))
    back = Scene.from_message(scene.to_message())
    assert len(back.world_parts()) == 5 and not calls


BASE = {"objects": [{"shape": "tesseract", "position": [0, 0, 0, 1.5]}]}


def with_object(**changes):
    obj = {**BASE["objects"][0], **changes}
    return {"objects": [obj]}


BAD = [
    ("not a mapping", [1, 2], "(top level)", "mapping"),
    ("no objects", {"projection": "orthographic"}, "objects", "non-empty list"),
    ("unknown top key", {**BASE, "camera": 1}, "camera", "one of the keys"),
    ("projection", {**BASE, "projection": "fisheye"}, "projection", "one of orthographic, perspective"),
    ("eye distance", {**BASE, "eye_distance": -1}, "eye_distance", "number > 0, got -1"),
    ("unknown shape", with_object(shape="hypersphere"), "objects[0].shape", "catalog shape"),
    ("shape typo", with_object(shape="tesseractt"), "objects[0].shape", "did you mean 'tesseract'?"),
    ("key typo", with_object(positon=[0, 0, 0, 1]), "objects[0].positon", "did you mean 'position'?"),
    ("rotation typo", with_object(rotaton=[]), "objects[0].rotaton", "did you mean 'rotation'?"),
    ("colour typo", with_object(color="organge"), "objects[0].color", "did you mean 'orange'?"),
    ("nan position", with_object(position=[0, 0, float("nan"), 1]), "objects[0].position[2]", "a finite number"),
    ("bad params", with_object(shape="duoprism", params={"p": 1}), "objects[0].params", "valid parameters"),
    ("two kinds", with_object(vertices=[[0, 0, 0, 0]]), "objects[0]", "exactly one of"),
    ("size", with_object(size=0), "objects[0].size", "number > 0, got 0"),
    ("position length", with_object(position=[0, 0, 1]), "objects[0].position", "4 numbers"),
    ("position type", with_object(position=[0, 0, "a", 1]), "objects[0].position[2]", "finite number, got 'a'"),
    ("rotation plane", with_object(rotation=[["xq", 30]]), "objects[0].rotation[0]", "plane"),
    ("rotation pair", with_object(rotation=[["xw"]]), "objects[0].rotation[0]", "pair"),
    ("color range", with_object(color=[2, 0, 0]), "objects[0].color", "between 0 and 1"),
    ("typo key", with_object(positon=[0, 0, 0, 1]), "objects[0].positon", "one of the keys"),
    ("flat vertices", {"objects": [{"vertices": [[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [1, 1, 1, 0]]}]},
     "objects[0].vertices", "bounded convex 4-polytope"),
    ("open halfspaces", {"objects": [{"halfspaces": [[1, 0, 0, 0, 1]] * 5}]}, "objects[0].halfspaces", "bounded"),
    ("bad part", {"objects": [{"parts": [{"points": []}]}]}, "objects[0].parts[0].points",
     "one of the keys vertices, halfspaces"),
    ("ragged rows", {"objects": [{"vertices": [[0, 0, 0], [1, 0, 0, 0]]}]}, "objects[0].vertices[0]", "4 numbers"),
    ("selected", {**BASE, "selected": 3}, "selected", "object index"),
]


@pytest.mark.parametrize("label,data,key,reason", BAD, ids=[b[0] for b in BAD])
def test_bad_scene_files_name_file_key_and_reason(tmp_path, label, data, key, reason):
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as info:
        load_scene(path)
    assert info.value.key == key
    assert str(path) in str(info.value) and reason in str(info.value)


def test_unreadable_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="existing scene file"):
        load_scene(tmp_path / "missing.yaml")
    path = tmp_path / "broken.yaml"
    path.write_text("objects: [\n")
    with pytest.raises(ConfigError, match="valid YAML"):
        load_scene(path)


def test_bad_message_is_reported_with_the_object_index():
    from touch4d.messages import MessageError
    msg = parse_scene(BASE).to_message()
    msg.objects[0]["shape"] = "nonsense"
    with pytest.raises(MessageError, match=r"objects\[0\]"):
        Scene.from_message(msg)
