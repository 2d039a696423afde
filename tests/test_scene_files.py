"""Scenes people write: colours by name or hex, custom shapes under `shape:`, any wrong type a clear
error naming its key (never a traceback), and `touch4d scene check`."""
import copy
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from touch4d.cli import main
from touch4d.errors import ConfigError
from touch4d.geometry.scene import load_scene, parse_scene

REPO = Path(__file__).resolve().parents[1]
TESSERACT = [[x, y, z, w] for x in (-.5, .5) for y in (-.5, .5) for z in (-.5, .5) for w in (-.5, .5)]
SIMPLEX_VERTICES = [[0, 0, 0, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
SIMPLEX_HALFSPACES = [[-1, 0, 0, 0, 0], [0, -1, 0, 0, 0], [0, 0, -1, 0, 0], [0, 0, 0, -1, 0], [1, 1, 1, 1, 1]]


def one(**obj):
    return parse_scene({"objects": [{"position": [0, 0, 0, 1.5], **obj}]}, "s.yaml").objects[0]


@pytest.mark.parametrize("text, rgba", [
    ("#3366ff", [0x33 / 255, 0x66 / 255, 1.0, 1.0]),
    ("#3366FF80", [0x33 / 255, 0x66 / 255, 1.0, 0x80 / 255]),
    ("orange", [1.0, 165 / 255, 0.0, 1.0]),                    # CSS: rgb(255, 165, 0)
    ("RebeccaPurple", [0x66 / 255, 0x33 / 255, 0x99 / 255, 1.0]),
    ("#f00", [1.0, 0.0, 0.0, 1.0]),
    ([0.2, 0.4, 0.6], [0.2, 0.4, 0.6, 1.0]),
    ([0.2, 0.4, 0.6, 0.5], [0.2, 0.4, 0.6, 0.5]),
])
def test_colours_by_name_hex_or_list(text, rgba):
    np.testing.assert_allclose(one(shape="tesseract", color=text).color, rgba)


@pytest.mark.parametrize("value", ["blurple", "#12345", "#gg0000", "", [1, 0], [0, 0, 2]])
def test_a_bad_colour_names_the_key_and_the_forms(value):
    with pytest.raises(ConfigError) as err:
        one(shape="tesseract", color=value)
    assert err.value.key == "objects[0].color" and "#rrggbb" in str(err.value) and "s.yaml" in str(err.value)


@pytest.mark.parametrize("kind, value", [("vertices", TESSERACT), ("halfspaces", SIMPLEX_HALFSPACES),
                                         ("parts", [{"vertices": TESSERACT}, {"halfspaces": SIMPLEX_HALFSPACES}])])
def test_custom_shapes_also_go_under_shape(kind, value):
    beside, under = one(**{kind: value}), one(shape={kind: value})
    assert under.shape == beside.shape == "custom"
    assert len(under.custom_parts) == len(beside.custom_parts)
    for a, b in zip(under.custom_parts, beside.custom_parts):
        np.testing.assert_allclose(a, b)


@pytest.mark.parametrize("shape, key", [
    ({"vertices": TESSERACT, "halfspaces": SIMPLEX_HALFSPACES}, "objects[0].shape"),
    ({"vertex": TESSERACT}, "objects[0].shape.vertex"),
    ({}, "objects[0].shape"),
    ({"vertices": "cube"}, "objects[0].shape.vertices"),
])
def test_a_bad_custom_shape_under_shape_names_its_key(shape, key):
    with pytest.raises(ConfigError) as err:
        one(shape=shape)
    assert err.value.key == key


VALID = {
    "description": "every key, each value right",
    "projection": "perspective", "eye_distance": 3.0, "selected": 1,
    "objects": [
        {"name": "a", "shape": "duoprism", "params": {"p": 3, "q": 4}, "size": 0.8,
         "position": [0, 0, 0, 1.5], "rotation": [["xw", 10], ["yz", 5]], "color": "#3366ff"},
        {"name": "b", "shape": "prism", "params": {"base": "cube", "subdivisions": 1}, "color": [1, 0, 0]},
        {"name": "c", "vertices": SIMPLEX_VERTICES},
        {"name": "d", "shape": {"parts": [{"halfspaces": SIMPLEX_HALFSPACES}]}},
    ],
}
JUNK = [None, True, -1, 1.5, math.nan, math.inf, "text", "", [], [1, 2], [[1]], {}, {"a": 1}, {1: 2}, [None]]


def key_paths(value, path=""):
    """Every key path in a parsed YAML value, e.g. objects[0].rotation[1][0]."""
    yield path
    if isinstance(value, dict):
        for k, v in value.items():
            yield from key_paths(v, f"{path}.{k}" if path else k)
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from key_paths(v, f"{path}[{i}]")


def replaced(data, path, junk):
    """A deep copy of `data` with the value at key path `path` replaced by `junk`."""
    import re
    out = copy.deepcopy(data)
    steps = [int(s) if s.isdigit() else s for s in re.findall(r"[^.\[\]]+", path)]
    target = out
    for step in steps[:-1]:
        target = target[step]
    target[steps[-1]] = junk
    return out


def test_any_wrong_value_anywhere_is_a_config_error_naming_its_key():
    parse_scene(VALID, "s.yaml")                     # the base is valid
    paths = [p for p in key_paths(VALID) if p]
    crashes, unnamed = [], []
    warnings.simplefilter("ignore", RuntimeWarning)   # numpy's note on junk half-spaces; the error is what counts
    for path in paths:
        for junk in JUNK:
            try:
                parse_scene(replaced(VALID, path, junk), "s.yaml")
            except ConfigError as err:
                if not (path.startswith(err.key) or err.key.startswith(path)):
                    unnamed.append((path, junk, err.key))
            except Exception as exc:                 # a traceback for the user
                crashes.append((path, junk, repr(exc)))
    assert not crashes, crashes[:10]
    assert not unnamed, unnamed[:10]


def test_keys_that_are_not_names_are_reported(tmp_path):
    for data, key in (({1: "x", "y": 2, "objects": []}, "1"), ({"objects": [{"shape": "tesseract", 3: 1}]}, "objects[0].3")):
        with pytest.raises(ConfigError) as err:
            parse_scene(data, "s.yaml")
        assert err.value.key == key


# ---- touch4d scene check ------------------------------------------------------------------------------


def test_scene_check_describes_a_good_scene(capsys):
    assert main(["scene", "check", "config/scenes/multi-object.yaml"]) == 0
    out = capsys.readouterr().out
    assert str(REPO / "config/scenes/multi-object.yaml") in out and "3 object(s)" in out
    for name in ("front-cube", "back-24-cell", "side-5-cell"):
        assert name in out
    assert "ok" in out.splitlines()[-1]


def test_scene_check_names_the_key_of_a_bad_scene(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"objects": [{"shape": "tesseract", "size": [1, 2]}]}))
    assert main(["scene", "check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and "objects[0].size" in err and "Traceback" not in err
    assert main(["scene", "check", str(tmp_path / "nope.yaml")]) == 2
    assert "looked in" in capsys.readouterr().err


def test_scene_check_warns_about_an_object_outside_the_screen(tmp_path, capsys):
    far = tmp_path / "far.yaml"
    far.write_text(yaml.safe_dump({"objects": [{"name": "lost", "shape": "tesseract", "position": [3, 0, 0, 1.5]},
                                               {"name": "here", "shape": "tesseract", "position": [0, 0, 0, 1.5]}]}))
    assert main(["scene", "check", str(far)]) == 0
    out = capsys.readouterr().out
    assert "lost" in out and "outside the screen" in out and out.count("outside the screen") == 1


def test_every_packaged_scene_checks():
    for path in sorted((REPO / "config" / "scenes").glob("*.yaml")):
        assert load_scene(path).objects, path
        assert main(["scene", "check", str(path)]) == 0, path
