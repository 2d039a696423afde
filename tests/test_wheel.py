"""touch4d as a new user installs it: the wheel built from the sources (without a setuptools
warning), installed into a fresh venv, and run from an empty directory — launch, render, tactile
probe, record, replay and study find their defaults in the installed package, not in this checkout.

The venv borrows this environment's third-party packages (a .pth line) instead of downloading them
again; touch4d itself comes only from the wheel, which the first test proves."""
import json
import os
import shutil
import signal
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from touch4d.bus.testing import ProcessOutput, free_port
from touch4d.log.reader import LogReader

REPO = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "README.md", "touch4d", "messages", "nodes", "config", "launch")

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def wheel_env(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("wheel")
    # A copy of what the build reads, so that no stale build/ of the checkout leaks into the wheel.
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        if (REPO / name).is_dir():
            shutil.copytree(REPO / name, src / name, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "keys"))
        else:
            shutil.copy(REPO / name, src / name)
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "-v", "--no-deps", "--no-build-isolation",
                            "--no-index", "-w", str(tmp / "dist"), str(src)], capture_output=True, text=True,
                           timeout=240)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr[-3000:]
    wheel = next((tmp / "dist").glob("touch4d-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    site = Path(subprocess.run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    deps = {sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]}
    (site / "borrowed-dependencies.pth").write_text("".join(f"{d}\n" for d in sorted(deps)))
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "-q", "--no-deps",
                    "--no-index", str(wheel)], check=True, capture_output=True, timeout=240)
    work = tmp / "empty"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "TOUCH4D_"))}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    bus = tmp / "bus.yaml"       # free ports, so that a machine shared with other runs is no problem
    bus.write_text(f"broker: {{bind: 127.0.0.1, pub_port: {free_port()}, sub_port: {free_port()}}}\n")
    env["TOUCH4D_BUS"] = str(bus)
    return {"log": build.stdout + build.stderr, "site": site, "work": work, "env": env, "tmp": tmp}


def run(env, *args, timeout=120):
    done = subprocess.run(args, cwd=env["work"], env=env["env"], capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, f"{args}: {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
    return done.stdout


def start(env, *args) -> ProcessOutput:
    """A touch4d process in its own process group, its output collected line by line."""
    return ProcessOutput(subprocess.Popen(args, cwd=env["work"], env=env["env"], stdout=subprocess.PIPE,
                                          stderr=subprocess.STDOUT, start_new_session=True))


def stop(out: ProcessOutput, sig=None, timeout=60) -> int:
    """Send `sig` (if any), wait for the process, then kill whatever is left of its process group."""
    try:
        if sig is not None and out.proc.poll() is None:
            out.proc.send_signal(sig)
        return out.proc.wait(timeout)
    finally:
        try:
            os.killpg(out.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        out.join()


def test_the_build_is_quiet_and_the_installed_package_is_the_wheel(wheel_env):
    assert "absent from the `packages` configuration" not in wheel_env["log"]
    assert "Warning" not in wheel_env["log"], [ln for ln in wheel_env["log"].splitlines() if "Warning" in ln]
    where = json.loads(run(wheel_env, "python", "-c", "import json, touch4d, touch4d.nodes, touch4d.defaults; "
                           "print(json.dumps([touch4d.__file__, touch4d.nodes.__file__, str(touch4d.defaults.ROOT)]))"))
    for path in where:
        assert Path(path).is_relative_to(wheel_env["site"]) and not Path(path).is_relative_to(REPO), path
    assert run(wheel_env, "touch4d", "config", "where", "launch/demo.yaml").strip() == \
        str(wheel_env["site"] / "touch4d/defaults/launch/demo.yaml")
    assert sorted(p.name for p in (wheel_env["site"] / "touch4d/defaults/config").iterdir()) == \
        sorted(p.name for p in (REPO / "config").iterdir() if p.name != "keys")


def test_tactile_probe_and_render_from_an_empty_directory(wheel_env):
    out = json.loads(run(wheel_env, "touch4d", "tactile", "probe", "--scene", "config/scenes/hypercube.yaml",
                         "--position", "0", "0", "0", "--json"))
    # The hand in the middle of the hypercube's flat front cell: every touched sample at the same
    # depth, so s = 1 and h = 1 - beta = 0.5 (paper eq. 1-2); V = gamma h = 0.5 on every motor.
    assert len(out["motors"]) == 30 and {m["V"] for m in out["motors"]} == {0.5}
    run(wheel_env, "touch4d", "render", "--scene", "config/scenes/hypercube.yaml", "--size", "320x200",
        "--samples", "0", "-o", "frame.png")
    image = np.asarray(Image.open(wheel_env["work"] / "frame.png"))[..., :3].astype(int)
    blue = np.all(np.abs(image - np.round(np.array([0.30, 0.65, 1.00]) * 255)) <= 2, axis=-1)  # the scene's colour
    assert blue.sum() > 50


def test_the_papers_study_is_packaged_and_planned_from_an_empty_directory(wheel_env):
    out = run(wheel_env, "touch4d", "study", "check", "config/studies/paper.yaml")
    assert str(wheel_env["site"] / "touch4d/defaults/config/studies/paper.yaml") in out and "213 trials" in out
    plan = json.loads(run(wheel_env, "touch4d", "study", "plan", "config/studies/paper.yaml", "--participant", "P01",
                          "--json"))
    assert plan["condition_order"] == ["visual", "touch", "visual+touch"] and len(plan["trials"]) == 213


def test_launch_record_and_replay_from_an_empty_directory(wheel_env):
    work, frames = wheel_env["work"], wheel_env["tmp"] / "frames"
    launch = start(wheel_env, "touch4d", "launch", "--duration", "120", "renderer.rate:=5",
                   f"renderer.output:={frames}/", "renderer.width:=160", "renderer.height:=100")
    try:
        launch.wait_for_line(r"^\[tracker\].*path demo", timeout=100)      # the hand moves from here on
        launch.wait_for_line(r"^\[tactile\].*samples", timeout=100)
        launch.wait_for_line(r"^\[renderer\].*headless", timeout=100)
        run(wheel_env, "touch4d", "record", "-o", "session.mcap", "--duration", "3", "hand/pose", "tactile/motors")
    finally:
        code = stop(launch, signal.SIGINT, timeout=30)                     # Ctrl+C: a clean stop
    assert code == 0, launch.text
    assert f"launch file {wheel_env['site'] / 'touch4d/defaults/launch/demo.yaml'}" in launch.text
    assert "failed" not in launch.text and sorted(frames.glob("frame-*.png"))   # the headless renderer's frames
    poses = count(work / "session.mcap", "hand/pose")
    assert poses > 100 and count(work / "session.mcap", "tactile/motors") > 100     # 3 s at 90 Hz

    broker = start(wheel_env, "touch4d", "bus", "broker")
    try:
        recorder = start(wheel_env, "touch4d", "record", "-o", "replayed.mcap", "--duration", "30", "hand/pose")
        try:
            recorder.wait_for_line("^recording", timeout=60)
            run(wheel_env, "touch4d", "replay", "session.mcap", "--rate", "4")
        finally:
            assert stop(recorder, signal.SIGINT, timeout=30) == 0, recorder.text
    finally:
        stop(broker, signal.SIGINT, timeout=10)
    assert count(work / "replayed.mcap", "hand/pose") == poses


def count(path: Path, topic: str) -> int:
    return sum(1 for _ in LogReader(path).messages({topic}))


def test_the_firmware_core_from_a_wheel_says_what_to_do_and_builds_from_a_named_checkout(wheel_env):
    args = ["touch4d", "glove", "emulate", "--firmware", "--duration", "0.3", "--channel", f"wheel-fw-{os.getpid()}"]
    done = subprocess.run(args, cwd=wheel_env["work"], env=wheel_env["env"], capture_output=True, text=True,
                          timeout=60)
    assert done.returncode != 0 and "Traceback" not in done.stderr
    for words in ("wheel ships no firmware sources", "source checkout", "TOUCH4D_FIRMWARE_DIR=", "board_emulator: python"):
        assert words in done.stderr, done.stderr
    # The installed package, with a checkout's sources named: the core is built there and runs.
    env = {**wheel_env["env"], "TOUCH4D_FIRMWARE_DIR": str(REPO / "firmware")}
    done = subprocess.run(args, cwd=wheel_env["work"], env=env, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "emulating boards [1, 2, 3, 4] (firmware)" in done.stdout
