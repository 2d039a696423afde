"""`touch4d render`: one frame of a scene file to a PNG, with the hand and its tactile field."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from touch4d.cli import main
from touch4d.render.camera import OrbitCamera, parse_camera
from touch4d.render.hud import amplitude_colors

SCENE = "config/scenes/hypercube.yaml"     # a tesseract coloured (0.30, 0.65, 1.00)
ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.timeout(120)
def test_renders_a_scene_with_the_hand_and_tactile_cube(tmp_path, capsys):
    out = tmp_path / "frame.png"
    code = main(["render", "--scene", SCENE, "--hand", "0", "0", "0.2", "--size", "400x300", "--samples", "0",
                 "--camera", "yaw=0,pitch=0,distance=7,ortho", "-o", str(out)])
    assert code == 0 and "wrote" in capsys.readouterr().out
    image = np.asarray(Image.open(out))[..., :3].astype(int)
    assert image.shape == (300, 400, 3)
    # The tesseract's edges in the scene's colour.
    blue = np.all(np.abs(image - np.round(np.array([0.30, 0.65, 1.00]) * 255)) <= 2, axis=-1)
    assert blue.sum() > 100
    # The hand touches the flat front cell: every touched sample feels the same h = 1 - beta = 0.5
    # (Fig. 17), drawn in the tactile cube in the middle colour of the amplitude map.
    mid = np.all(np.abs(image - np.round(amplitude_colors(0.5) * 255)) <= 3, axis=-1)
    assert mid[:, :150].sum() > 50          # the cube sits left of the screen


def test_bad_arguments_exit_2_naming_them(tmp_path, capsys):
    assert main(["render", "--scene", SCENE, "--size", "big", "-o", str(tmp_path / "x.png")]) == 2
    assert "--size" in capsys.readouterr().err
    assert main(["render", "--scene", str(tmp_path / "missing.yaml"), "-o", str(tmp_path / "x.png")]) == 2
    assert "missing.yaml" in capsys.readouterr().err
    assert main(["render", "--scene", SCENE, "--camera", "yaw=left", "-o", str(tmp_path / "x.png")]) == 2
    assert "yaw" in capsys.readouterr().err
    assert not (tmp_path / "x.png").exists()


def test_camera_spec_sets_only_what_it_names():
    cam = parse_camera("yaw=10, pitch=-5,target=1:2:3,ortho")
    assert (cam.yaw, cam.pitch, cam.ortho) == (10.0, -5.0, True)
    assert cam.target.tolist() == [1, 2, 3] and cam.distance == OrbitCamera().distance
    # A point at the target lands in the middle of the frame.
    assert np.allclose(cam.to_pixels(np.array([[1.0, 2, 3]]), (200, 100)), [[100, 50]])


def render(tmp_path, scene, *extra, name="frame.png"):
    out = tmp_path / name
    assert main(["render", "--scene", str(scene), "--size", "240x150", "--samples", "0", *extra, "-o", str(out)]) == 0
    return np.asarray(Image.open(out))


def test_without_a_hand_there_is_no_tactile_cube(tmp_path):
    plain = render(tmp_path, SCENE)
    assert np.array_equal(plain, render(tmp_path, SCENE, "--no-tactile", name="no-cube.png"))


def test_the_status_line_names_the_scene_file(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("a.yaml", "a-much-longer-scene-file-name.yaml"):      # the same scene in both
        (tmp_path / name).write_bytes((ROOT / SCENE).read_bytes())
    short = render(tmp_path, "a.yaml", "--no-frame", name="short.png")
    long = render(tmp_path, "a-much-longer-scene-file-name.yaml", "--no-frame", name="long.png")
    rows = np.nonzero(np.any(short != long, axis=(1, 2)))[0]
    assert len(rows) > 0 and rows.max() < 60       # the status box at the top differs, nothing else
    assert "a-much-longer-scene-file-name.yaml" in capsys.readouterr().out
