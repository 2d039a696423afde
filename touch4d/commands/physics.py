"""`touch4d physics simulate SCENE`: run a scene's physics offline and print where everything ends up."""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError

from touch4d.physics.bivector import to_planes


def register(subparsers) -> None:
    physics = subparsers.add_parser("physics", help="4D rigid-body physics of a scene")
    sub = physics.add_subparsers(dest="physics_command", metavar="SUBCOMMAND")
    physics.set_defaults(func=lambda args: (physics.print_help(), 2)[1])
    sim = sub.add_parser(
        "simulate", help="run a scene's physics for a while and print the final state",
        description="Step the scene's physics (the physics node's fixed step) for --duration seconds and print "
                    "the scene's total energy and angular momentum and, per moving object, its position, velocity "
                    "and turning (angular velocity, degrees per second by plane). --json also gives every object's "
                    "orientation (world = orientation @ (size * local) + position), static ones included.")
    sim.add_argument("scene", metavar="SCENE", help="scene file (YAML) with physics keys")
    sim.add_argument("--duration", type=_seconds, default=1.0, metavar="S", help="simulated seconds (default 1)")
    sim.add_argument("--rate", type=_positive, metavar="HZ", help="internal steps per second (default: the scene's)")
    sim.add_argument("--json", action="store_true", help="print JSON (a stable interface for scripts)")
    sim.add_argument("--frames", metavar="PNG", help="also draw the scene at --frame-count moments from start to end "
                                                     "(the renderer, headless) side by side into this PNG")
    sim.add_argument("--frame-count", type=int, default=6, metavar="N", help="frames in --frames (default 6)")
    sim.add_argument("--frame-size", default="480x400", metavar="WxH", help="size of each frame (default 480x400)")
    sim.add_argument("--camera", default="yaw=25,pitch=15,distance=5.2,target=0:-0.2:0",
                     help="orbit camera of the frames: yaw=DEG,pitch=DEG,distance=D,target=X:Y:Z")
    sim.add_argument("--backend", choices=("gpu", "clip", "auto"), default="auto",
                     help="the renderer's backend for --frames, as for touch4d render (default auto)")
    sim.set_defaults(func=run_simulate)
    rep = sub.add_parser(
        "replay", help="replay a recorded physics session from its journal and compare with its recorded states",
        description="Read the physics node's journal (topic physics/journal) from a recorded log, feed it to a fresh "
                    "world of the same scene, and compare the result with the log's last scene/state of the same "
                    "revision: a deterministic run gives the same bytes. The node's set-up (scene file, calibration, "
                    "glove, controller settings) comes from the journal too; --scene and the others override it.")
    rep.add_argument("log", metavar="LOG", help="MCAP log with physics/journal and scene/state")
    rep.add_argument("--scene", metavar="FILE", help="the scene file the node ran (default: as the log says)")
    rep.add_argument("--calibration", metavar="FILE", help="default: as the log says")
    rep.add_argument("--glove", metavar="FILE", help="default: as the log says")
    rep.add_argument("--json", action="store_true", help="print JSON")
    rep.set_defaults(func=run_replay)
    for name, text in (("pause", "pause the running physics node (again: go on)"), ("play", "go on after a pause"),
                       ("step", "run N steps of the paused physics node"), ("reset", "put every body back where "
                                                                                   "the scene file has it")):
        cmd = sub.add_parser(name, help=text, description=f"{text[0].upper()}{text[1:]}: a scene/command on the bus; "
                                                          "waits for the physics node's journal to show it taken.")
        if name == "step":
            cmd.add_argument("count", nargs="?", type=int, default=1, metavar="N", help="how many steps (default 1)")
        cmd.add_argument("--bus", help="bus config file (default: $TOUCH4D_BUS, else config/bus.yaml)")
        cmd.add_argument("--wait", type=_positive, default=3.0, metavar="S",
                         help="seconds to wait for the physics node's journal to show the command (default 3)")
        cmd.set_defaults(func=run_command, command=name)


def _positive(text: str) -> float:
    value = float(text)
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def _seconds(text: str) -> float:
    value = float(text)
    if not np.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"expected seconds >= 0, got {text!r}")
    return value


def run_simulate(args) -> int:
    from touch4d.geometry.scene import load_scene

    from touch4d.physics.config import load_physics
    from touch4d.physics.world import build_world, run

    path = resolve_path(args.scene, COMMAND_LINE, key="SCENE", what="scene file")
    scene = load_scene(path)
    world, state = build_world(scene, load_physics(path), rate=args.rate)
    steps = int(round(args.duration / world.dt))
    if args.frames:
        if not 1 <= args.frame_count <= 64:
            raise ConfigError("--frame-count", "frame-count", "1..64 frames", got=args.frame_count)
        marks = sorted(set(np.linspace(0, steps, args.frame_count).round().astype(int).tolist()))
        shots = []
        for mark in marks:
            state = run(world, state, mark - state.steps)
            shots.append((state.time, state))
        state = run(world, state, steps - state.steps)
        draw_frames(scene, world, shots, args)
    else:
        state = run(world, state, steps)
    report = simulation_report(world, state)
    if args.json:
        print(json.dumps(report))
    else:
        print(report_text(report))
    return 0


def simulation_report(world, state) -> dict:
    """The final state by object name, and the scene's energy and angular momentum (degrees for rates)."""
    from touch4d.physics.world import angular_momentum, angular_velocity, energy, object_positions

    positions = object_positions(world, state)
    rates = np.degrees(angular_velocity(world, state))
    objects = {
        name: {
            "position": positions[i].tolist(), "orientation": state.r[i].tolist(), "velocity": state.v[i].tolist(),
            "angular_velocity": to_planes(rates[i]), "static": bool(world.static[i]),
        }
        for i, name in enumerate(world.names)
    }
    return {"time": state.time, "steps": state.steps, "dt": world.dt, "objects": objects,
            "energy": energy(world, state), "angular_momentum": to_planes(angular_momentum(world, state))}


def report_text(report: dict) -> str:
    lines = [f"after {report['time']:.4f} s ({report['steps']} steps of {report['dt'] * 1000:g} ms): "
             f"energy {report['energy']:.6g}"]
    lines.append("angular momentum " + ", ".join(f"{p} {v:.4g}" for p, v in report["angular_momentum"].items()))
    for name, obj in report["objects"].items():
        if obj["static"]:
            continue
        pos = " ".join(f"{c:8.4f}" for c in obj["position"])
        vel = " ".join(f"{c:8.4f}" for c in obj["velocity"])
        spin = ", ".join(f"{p} {v:.1f}" for p, v in obj["angular_velocity"].items() if abs(v) >= 0.05) or "none"
        lines.append(f"{name}: position {pos}; velocity {vel}; turning (deg/s) {spin}")
    return "\n".join(lines)


def draw_frames(scene, world, shots, args) -> None:
    """The scene at each (time, state) drawn by the renderer, side by side, with the time under each."""
    from PIL import Image, ImageDraw

    from touch4d.render.camera import OrbitCamera, parse_camera
    from touch4d.commands.render import parse_size
    from touch4d.render.frame import Style
    from touch4d.render.offscreen import OffscreenRenderer
    from touch4d.render.view import SceneView, Show
    from touch4d.tactile.glove import load_glove

    from touch4d.physics.world import object_positions

    size = parse_size(args.frame_size)
    camera = parse_camera(args.camera, OrbitCamera())
    view = SceneView(load_glove(None), Style(), Show(frame=True, tactile=False, status=False))
    renderer = OffscreenRenderer(size, samples=4, backend=args.backend)
    images = []
    try:
        for t, state in shots:
            shown = scene.copy()
            positions = object_positions(world, state)
            for i, obj in enumerate(shown.objects):
                obj.position, obj.orientation = positions[i].copy(), state.r[i].copy()
            shown.revision = state.steps + 1
            view.set_scene(shown)
            image = Image.fromarray(renderer.render(view, camera)[..., :3])
            ImageDraw.Draw(image).text((10, size[1] - 22), f"t = {t:.2f} s", fill=(230, 230, 230))
            images.append(image)
    finally:
        renderer.release()
    strip = Image.new("RGB", (size[0] * len(images), size[1]))
    for k, image in enumerate(images):
        strip.paste(image, (k * size[0], 0))
    strip.save(args.frames)
    print(f"wrote {args.frames}: {len(images)} frames of {size[0]}x{size[1]}", file=sys.stderr)


def run_replay(args) -> int:
    """Replay a log's physics journal; exit 0 when the replayed state equals the recorded one exactly."""
    from touch4d.geometry.scene import load_scene
    from touch4d.log.reader import LogReader
    from touch4d.tactile.glove import load_glove
    from touch4d.tracking.calibration import load_calibration
    from touch4d.tracking.scene_control import ControlConfig

    from touch4d.physics.config import load_physics
    from touch4d.physics.session import DEFAULT_BUTTONS, entry_from_map, replay, split_buttons

    log = resolve_path(args.log, COMMAND_LINE, key="LOG", what="log file")
    journal, states, start = [], [], None
    for msg in LogReader(log).messages({"physics/journal", "scene/state"}):
        data = msg.decode()
        if msg.topic == "scene/state":
            states.append(data)
        elif data.get("kind") == "start":
            start = start or data.get("args") or {}
        else:
            try:
                journal.append(entry_from_map(data["step"], data["kind"], data["args"]))
            except (KeyError, ValueError) as exc:
                raise ConfigError(log, "physics/journal", "journal entries of the physics node", got=str(exc)) from None
    if not journal:
        raise ConfigError(log, "physics/journal", "a log recorded from the physics node (no journal in it)")
    start = start or {}

    def setting(name, flag, what, default):
        """A path: the command line's, else the node's (from the log), else the default."""
        if flag is not None:
            return resolve_path(flag, COMMAND_LINE, key=f"--{name}", what=what)
        return resolve_path(start.get(name) or default, what=what)

    if args.scene is None and "scene" not in start:
        raise ConfigError(log, "physics/journal", "the node's set-up (a start entry), or --scene")
    scene_path = setting("scene", args.scene, "scene file", None)
    scene_buttons, physics_buttons = split_buttons(start.get("buttons", DEFAULT_BUTTONS), log)
    config = ControlConfig.from_params(gains=start.get("gains", {}), trigger_threshold=start.get("trigger_threshold", 0.5),
                                       buttons=scene_buttons, rotate=start.get("rotate", "object"), spin={},
                                       source=str(log))
    glove = load_glove(setting("glove", args.glove, "glove file", "config/glove.yaml"))
    calibration = load_calibration(setting("calibration", args.calibration, "calibration file",
                                           "config/calibration.yaml"))
    by_revision = {int(m["revision"]): m["objects"] for m in states}
    compared, differences = set(), []

    def check(session) -> None:
        """Compare with the recorded state of the revision the replay has reached, if one was recorded."""
        revision = session.control.scene.revision
        if revision in by_revision and revision not in compared:
            compared.add(revision)
            for got, want in zip(session.message().objects, by_revision[revision]):
                for key in ("position", "orientation"):
                    g, w = np.asarray(got[key]), np.asarray(want[key])
                    differences.append(0.0 if g.tobytes() == w.tobytes() else float(np.abs(g - w).max()))

    session = replay(load_scene(scene_path), load_physics(scene_path), calibration, config, physics_buttons, journal,
                     glove=glove, push_rate=float(start.get("push_rate", 40.0)), after=check)
    same = bool(compared) and max(differences) == 0.0
    report = {"entries": len(journal), "steps": session.state.steps, "states_compared": len(compared),
              "identical": same, "max_difference": max(differences) if differences else None}
    if args.json:
        print(json.dumps(report))
    elif not compared:
        print(f"{len(journal)} journal entries replayed; no recorded scene/state of the same revision to compare")
    else:
        print(f"{len(journal)} journal entries, {len(compared)} recorded states compared: "
              + ("the same bytes" if same else f"they differ by up to {report['max_difference']:.3g}"))
    return 0 if same else 1


def run_command(args) -> int:
    """Send one scene/command (pause, play, step N, reset) to the physics node on the bus and wait for the
    journal entries that show it taken; exit 1 when none came."""
    from touch4d.bus.config import resolve_bus_config
    from touch4d.bus.introspect import request
    from touch4d.messages import PhysicsInput, SceneCommand

    argument = str(args.count) if args.command == "step" else ""
    if args.command == "step" and args.count < 1:
        raise ConfigError(COMMAND_LINE, "N", "a number of steps >= 1", got=args.count)
    taken_at: list[float] = []

    def done(got) -> bool:
        """The journal shows the outcome, or the command was taken SETTLE_S ago and nothing more will show."""
        if command_outcome(args.command, argument, got, final=False) is not None:
            return True
        if command_outcome(args.command, argument, got, final=True) is not None:
            taken_at[:] = taken_at or [time.monotonic()]
            return time.monotonic() - taken_at[0] > SETTLE_S
        return False

    entries = request("scene/command", SceneCommand(command=args.command, argument=argument), "physics/journal",
                      PhysicsInput, done, resolve_bus_config(args.bus), timeout=args.wait)
    outcome = command_outcome(args.command, argument, entries, final=True)
    if outcome is None:
        print(f"touch4d physics: no physics node took {args.command} within {args.wait:g} s (none on this bus, or it "
              "refused the command: its log says why); the plain scene node runs no physics: "
              "touch4d launch demo scene:=physics", file=sys.stderr)
        return 1
    print(f"physics node: {outcome}")
    return 0


SETTLE_S = 1.0   # after a command is taken, how long no steps mean none will come (the node ticks at 50 Hz or more)


def command_outcome(command: str, argument: str, entries, *, final: bool) -> str | None:
    """What the physics node's journal entries (`physics/journal`, after the command was sent) show of the
    command: a sentence once they show it, else None. `final`: no more will come (the wait is over), so
    what has not happened will not (a pause that no steps followed holds)."""
    taken = next((i for i, e in enumerate(entries) if e.kind == "command" and e.args.get("command") == command
                  and str(e.args.get("argument", "")) == argument), None)
    if taken is None:
        return None
    at = entries[taken].step
    runs = [e for e in entries[taken + 1:] if e.kind == "run"]
    ran = sum(int(e.args.get("steps", 0)) for e in runs)
    if command == "reset":
        return f"reset at step {at}: every body back where the scene file has it (step 0)"
    if command == "step":
        wanted = int(argument or 1)
        if ran >= wanted:
            return f"ran {wanted} step(s) from step {runs[0].step}: paused at step {runs[0].step + wanted}"
        return f"took step {wanted} at step {at}; {ran} of them ran before the wait ended" if final else None
    if command == "play":
        if runs:
            return f"running from step {runs[0].step}"
        return f"took play at step {at}; no steps ran before the wait ended (still paused?)" if final else None
    if runs:                                       # pause toggles: steps after it mean it went on
        return f"pause toggles, and it was paused: running again from step {runs[0].step}"
    return f"paused at step {at} (pause again or play to go on)" if final else None
