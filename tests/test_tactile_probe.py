"""`touch4d tactile probe`: the researcher's check of one pose, as text and as stable JSON."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import tilted_tesseract
from touch4d.cli import main
from touch4d.tactile.glove import load_glove

ROOT = Path(__file__).resolve().parents[1]

SCENE = tilted_tesseract.SCENE_YAML


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "tilted.yaml"
    path.write_text(SCENE)
    return path


def probe_json(capsys, *args):
    assert main(["tactile", "probe", *args, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_probe_json_gives_the_stimulus_worked_by_hand(capsys, scene_file):
    out = probe_json(capsys, "--scene", str(scene_file), "--position", "-0.34", "-0.18", "0")
    glove = load_glove()
    positions, l, s, h, v = tilted_tesseract.stimulus(glove.samples, [-0.34, -0.18, 0], 3.0, 0.5, 1.0,
                                                      glove.motor_sample)
    assert (out["alpha"], out["beta"], out["gamma"]) == (3.0, 0.5, 1.0)       # config/glove.yaml's
    assert len(out["samples"]) == len(glove.samples)
    np.testing.assert_allclose([x["position"] for x in out["samples"]], positions, atol=1e-12)
    np.testing.assert_allclose([x["l"] for x in out["samples"]], l, atol=1e-9)
    np.testing.assert_allclose([x["s"] for x in out["samples"]], s, atol=1e-9)
    np.testing.assert_allclose([x["h"] for x in out["samples"]], h, atol=1e-9)
    assert [m["name"] for m in out["motors"]] == glove.motor_names
    assert [m["sample"] for m in out["motors"]] == glove.motor_sample.tolist()
    np.testing.assert_allclose([m["V"] for m in out["motors"]], v, atol=1e-9)
    np.testing.assert_allclose([m["h"] for m in out["motors"]], h[glove.motor_sample], atol=1e-9)
    assert np.ptp(v) > 0.1


def test_probe_json_has_null_l_where_nothing_is_touched_and_takes_overrides(capsys, scene_file):
    out = probe_json(capsys, "--scene", str(scene_file), "--position", "0.9", "0", "0",
                     "--orientation", "0", "0", "0.7071068", "0.7071068", "--alpha", "1.5", "--beta", "0.25")
    assert (out["alpha"], out["beta"]) == (1.5, 0.25)
    ls = [s["l"] for s in out["samples"]]
    assert None in ls and any(v is not None for v in ls)
    for sample in out["samples"]:
        if sample["l"] is None:
            assert sample["s"] == 0 and sample["h"] == 0


def test_probe_glove_and_projection_options(capsys, scene_file):
    out = probe_json(capsys, "--scene", str(scene_file), "--glove", str(ROOT / "config/gloves/two-motor.yaml"),
                     "--position", "-0.34", "-0.18", "0")
    assert [m["name"] for m in out["motors"]] == ["palm-center", "back-center"]
    ortho = probe_json(capsys, "--scene", str(scene_file), "--position", "-0.34", "-0.18", "0")
    persp = probe_json(capsys, "--scene", str(scene_file), "--position", "-0.34", "-0.18", "0",
                       "--projection", "perspective")
    assert [s["l"] for s in ortho["samples"]] != [s["l"] for s in persp["samples"]]


def test_probe_text_lists_every_motor(capsys, scene_file):
    assert main(["tactile", "probe", "--scene", str(scene_file), "--position", "-0.34", "-0.18", "0"]) == 0
    text = capsys.readouterr().out
    assert "touching: 247" in text and "objects touched: cube" in text
    for name in load_glove().motor_names:
        assert name in text


@pytest.mark.parametrize("args, words", [
    (["--orientation", "0", "0", "0", "0"], "orientation: expected a unit quaternion"),
    (["--orientation", "nan", "0", "0", "1"], "orientation: expected finite numbers"),
    (["--glove", "/no/such.yaml"], "/no/such.yaml"),
])
def test_probe_bad_input_is_reported_without_a_traceback(capsys, scene_file, args, words):
    assert main(["tactile", "probe", "--scene", str(scene_file), "--position", "0", "0", "0", *args]) == 2
    err = capsys.readouterr().err
    assert words in err and "Traceback" not in err


def test_probe_rejects_out_of_range_constants(capsys, scene_file):
    for args in (["--alpha", "-1"], ["--beta", "1.5"], ["--alpha", "inf"]):
        with pytest.raises(SystemExit) as info:
            main(["tactile", "probe", "--scene", str(scene_file), "--position", "0", "0", "0", *args])
        assert info.value.code == 2
    assert "expected a number" in capsys.readouterr().err


@pytest.mark.timeout(60)
def test_probe_runs_as_a_command(scene_file):
    run = subprocess.run([sys.executable, "-m", "touch4d.cli", "tactile", "probe", "--scene", str(scene_file),
                          "--position", "-0.34", "-0.18", "0", "--json"], capture_output=True, text=True,
                         timeout=60, cwd=ROOT)
    assert run.returncode == 0, run.stderr
    assert len(json.loads(run.stdout)["motors"]) == 30
