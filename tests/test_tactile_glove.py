"""The glove files: the default glove's layout, its variants, and every mistake named by key."""
from pathlib import Path

import numpy as np
import pytest
import yaml

from touch4d.errors import ConfigError
from touch4d.tactile.glove import DEFAULT_GLOVE, glove_from_dict, load_glove

ROOT = Path(__file__).resolve().parents[1]
FINGERS = ("thumb", "index", "middle", "ring", "little")


@pytest.fixture(scope="module")
def glove():
    return load_glove()


@pytest.fixture
def data():
    return yaml.safe_load(DEFAULT_GLOVE.read_text())


def test_default_glove_is_the_config_file(glove):
    assert Path(glove.path) == ROOT / "config" / "glove.yaml"
    assert glove.screen_edge_m == 0.5 and glove.units_per_metre == 4.0
    assert (glove.alpha, glove.beta, glove.gamma) == (3.0, 0.5, 1.0)


def test_default_samples_are_a_9_grid_inside_the_hand_about_the_papers_242(glove):
    samples = glove.samples
    assert 230 <= len(samples) <= 260
    assert glove.hand.contains(samples).all()
    low, high = glove.hand.bounds()
    for axis in range(3):
        levels = np.unique(np.round(samples[:, axis], 9))
        assert len(levels) <= 9
        np.testing.assert_allclose(np.diff(np.linspace(low[axis], high[axis], 9))[0],
                                   (high[axis] - low[axis]) / 8)
    # Every finger has samples beyond the palm, along its length.
    for name in FINGERS:
        f = glove.hand.finger(name)
        on_finger = np.linalg.norm(np.cross(samples - f.base, f.tip - f.base), axis=1) / np.linalg.norm(f.tip - f.base)
        beyond = ~glove.hand.in_palm(samples) & (on_finger <= f.radius + 1e-9)
        assert beyond.sum() >= 3, name


def test_default_motors_at_the_papers_places_with_fixed_boards(glove):
    names = glove.motor_names
    assert len(names) == 30
    assert names[:5] == ["palm-center", "palm-index", "palm-little", "palm-thenar", "palm-hypothenar"]
    assert names[5:10] == [n.replace("palm", "back") for n in names[:5]]
    expected = [f"{f}-{side}-{part}" for f in FINGERS for side in ("front", "back") for part in ("proximal", "distal")]
    assert names[10:] == expected
    k = np.arange(30)
    np.testing.assert_array_equal(glove.motor_board, 1 + k // 8)
    np.testing.assert_array_equal(glove.motor_channel, k % 8)
    # Palm motors on the palm side (-z), back motors on the back (+z), finger fronts -z, backs +z.
    z = glove.motor_positions[:, 2]
    assert (z[:5] < 0).all() and (z[5:10] > 0).all()
    assert all((z[i] < 0) == ("front" in names[i]) for i in range(10, 30))
    assert [b.id for b in glove.can.boards] == [1, 2, 3, 4]
    assert glove.can.interface == "virtual" and glove.can.refresh_hz == 200


def test_each_motor_is_bound_to_its_nearest_sample(glove):
    d = np.linalg.norm(glove.motor_positions[:, None] - glove.samples[None], axis=2)
    np.testing.assert_array_equal(glove.motor_sample, d.argmin(axis=1))
    assert (d.min(axis=1) < 0.02).all()
    # The palm-centre motor binds to a sample on the palm's surface (z = -thickness / 2) near its centre.
    np.testing.assert_allclose(glove.samples[glove.motor_sample[0]], [0.0, 0.0, -0.0125], atol=0.0051)


@pytest.mark.parametrize("file, samples, motors, boards", [
    ("config/gloves/dense.yaml", (700, 900), 30, 4),
    ("config/gloves/two-motor.yaml", (230, 260), 2, 1),
    ("config/gloves/64-motor.yaml", (230, 260), 64, 8),
])
def test_variant_gloves_are_config_changes(file, samples, motors, boards):
    g = load_glove(ROOT / file)
    assert samples[0] <= len(g.samples) <= samples[1]
    assert len(g.motor_names) == motors == len(set(g.motor_names))
    assert len(g.can.boards) == boards
    assert len(set(zip(g.motor_board.tolist(), g.motor_channel.tolist()))) == motors


def test_with_constants_overrides_and_checks(glove):
    g = glove.with_constants(alpha=1.5, beta=0.0)
    assert (g.alpha, g.beta, g.gamma) == (1.5, 0.0, glove.gamma)
    assert glove.alpha == 3.0
    with pytest.raises(ConfigError, match="beta"):
        glove.with_constants(beta=1.5)
    with pytest.raises(ConfigError, match="alpha"):
        glove.with_constants(alpha=0.0)


def _set(d, path, value):
    keys = path.split(".")
    for k in keys[:-1]:
        d = d[int(k)] if k.isdigit() else d[k]
    last = keys[-1]
    if value is _DELETE:
        del d[int(last) if last.isdigit() else last]
    else:
        d[int(last) if last.isdigit() else last] = value


_DELETE = object()


@pytest.mark.parametrize("path, value, key, words", [
    ("alpha", _DELETE, "alpha", "the tactile model needs"),
    ("alpha", -1.0, "alpha", "> 0"),
    ("beta", 1.5, "beta", "0..1"),
    ("gamma", "loud", "gamma", "finite number > 0, got 'loud'"),
    ("screen_edge_m", 0, "screen_edge_m", "> 0"),
    ("grid.n", 1, "grid.n", "integer >= 2"),
    ("grid.n", [9, 9], "grid.n", "list of 3"),
    ("hand.palm.width", _DELETE, "hand.palm.width", "required"),
    ("hand.palm.thickness", 0.5, "hand.palm.thickness", "<= hand.palm.width"),
    ("hand.fingers.2.radius", -0.01, "hand.fingers[2].radius", "> 0"),
    ("hand.fingers.0.name", "pinky", "hand.fingers[0].name", "thumb"),
    ("hand.fingers.0.name", "thum", "hand.fingers[0].name", "did you mean 'thumb'?"),
    ("touch_threshold", 1.5, "touch_threshold", "an intensity in 0..1, got 1.5"),
    ("can.duty", {"start": 0.9}, "can.duty.start", "<= can.duty.max (0.8)"),
    ("can.refresh_hz", float("nan"), "can.refresh_hz", "a finite number"),
    ("hand.fingers.1.base", [0.0], "hand.fingers[1].base", "list of 2"),
    ("motors", [], "motors", "list"),
    ("motors.3.position", [0, 0], "motors[3].position", "list of 3"),
    ("motors.3.position", [0.5, 0.5, 0.5], "motors[3].position", "on the hand"),
    ("motors.4.board", 9, "motors[4].board", "can.boards"),
    ("motors.4.channel", 8, "motors[4].channel", "0..7"),
    ("motors.4.channel", 0, "motors[4].channel", "palm-center"),
    ("motors.5.name", "palm-center", "motors[5].name", "used once"),
    ("can.boards.1.id", 1, "can.boards[1].id", "used once"),
    ("can", 5, "can", "a mapping"),
    # the motor node's rules, so a glove the tactile node accepts also drives the boards
    ("can.boards.0.id", 200, "can.boards[0].id", "1..127"),
    ("can.boards.0.channels", 9, "can.boards[0].channels", "1..8"),
    # typos are named, not silently ignored
    ("gama", 2.0, "gama", "did you mean 'gamma'?"),
    ("grid.m", 9, "grid.m", "one of the keys n"),
    ("hand.palm.widht", 0.09, "hand.palm.widht", "did you mean 'width'?"),
    ("hand.fingers.3.lenght", 0.07, "hand.fingers[3].lenght", "did you mean 'length'?"),
    ("motors.2.chanel", 3, "motors[2].chanel", "did you mean 'channel'?"),
    ("can.bitrat", 250000, "can.bitrat", "one of"),
])
def test_mistakes_name_file_key_and_expectation(data, path, value, key, words):
    _set(data, path, value)
    with pytest.raises(ConfigError) as info:
        glove_from_dict(data, "my-glove.yaml")
    assert info.value.key == key
    assert words in str(info.value)
    assert str(info.value).startswith("my-glove.yaml: key")


def test_unreadable_and_invalid_files(tmp_path):
    with pytest.raises(ConfigError, match="readable"):
        load_glove(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("alpha: [1, 2\n")
    with pytest.raises(ConfigError, match="valid YAML") as info:
        load_glove(bad)
    assert "bad.yaml" in str(info.value)
    bad.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="a mapping"):
        load_glove(bad)


def test_relative_glove_paths_work_from_any_directory(tmp_path, monkeypatch):
    from touch4d.boards.config import load_glove_can

    monkeypatch.chdir(tmp_path)
    glove = load_glove("config/gloves/two-motor.yaml")
    assert Path(glove.path) == ROOT / "config" / "gloves" / "two-motor.yaml" and len(glove.motor_names) == 2
    assert load_glove_can("config/gloves/two-motor.yaml").motor_names == tuple(glove.motor_names)
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "glove.yaml").write_text(DEFAULT_GLOVE.read_text().replace("alpha: 3.0", "alpha: 2.0"))
    assert load_glove("config/glove.yaml").alpha == 2.0        # the working directory's file comes first
    with pytest.raises(ConfigError) as info:
        load_glove("config/no-such-glove.yaml")
    assert info.value.file == "config/no-such-glove.yaml" and info.value.key == "(file)"
