"""`touch4d tactile probe`: the stimulus for one hand pose (or joint set) against a scene file, as text
or JSON; `touch4d hand joints`: the joint set of the glove's hand at a pose, fingers straight or bent."""
from __future__ import annotations

import argparse
import json
import math
from typing import Annotated, Literal

import msgspec

import numpy as np

from touch4d import schema
from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError
from touch4d.geometry.scene import load_scene
from touch4d.hands import FINGER_NAMES, HandShape

from touch4d.tactile.glove import load_glove
from touch4d.tactile.skeleton import JointsError
from touch4d.tactile.stimulus import Stimulus, compute_joint_stimulus, compute_stimulus


class JointsFile(msgspec.Struct, forbid_unknown_fields=True):
    """A joint set as `touch4d hand joints` prints it (WebXR's joints, screen units)."""

    names: list[str]
    positions: list[Annotated[list[float], msgspec.Meta(min_length=3, max_length=3)]]
    orientations: list[Annotated[list[float], msgspec.Meta(min_length=4, max_length=4)]]
    radii: list[float] | None = None
    handedness: Literal["left", "right"] | None = None


def register(subparsers) -> None:
    tactile = subparsers.add_parser("tactile", help="the tactile stimulus model (paper §5)")
    sub = tactile.add_subparsers(dest="tactile_command", metavar="SUBCOMMAND")
    tactile.set_defaults(func=lambda args: (tactile.print_help(), 2)[1])
    probe = sub.add_parser(
        "probe", help="the stimulus for one hand pose against a scene",
        description="Place the glove's hand at a pose in the screen and print l, s, h per sample "
                    "and the intensity per motor (paper eq. 1-7).")
    probe.add_argument("--scene", required=True, metavar="FILE", help="scene file (YAML)")
    probe.add_argument("--glove", metavar="FILE", help="glove file (default: config/glove.yaml)")
    probe.add_argument("--position", nargs=3, type=float, metavar=("X", "Y", "Z"),
                       help="the hand's origin (palm centre) in screen coordinates")
    probe.add_argument("--joints", metavar="FILE",
                       help="a joint set (JSON, as `touch4d hand joints` prints) in place of a rigid pose: "
                            "every sample on its bone")
    probe.add_argument("--orientation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                       default=[0.0, 0.0, 0.0, 1.0], help="unit quaternion, hand frame -> screen (default identity)")
    probe.add_argument("--alpha", type=_positive, metavar="A", help="gradient constant of eq. 1 (per screen unit)")
    probe.add_argument("--beta", type=_unit, metavar="B", help="reducing constant of eq. 2 (0..1)")
    probe.add_argument("--projection", choices=("scene", "orthographic", "perspective"), default="scene",
                       help="rays along +w (orthographic) or from the eye (perspective); default: the scene's")
    probe.add_argument("--json", action="store_true", help="print JSON (a stable interface for scripts)")
    probe.set_defaults(func=run_probe)

    hand = subparsers.add_parser("hand", help="the glove's articulated hand (WebXR joints)")
    hsub = hand.add_subparsers(dest="hand_command", metavar="SUBCOMMAND")
    hand.set_defaults(func=lambda args: (hand.print_help(), 2)[1])
    joints = hsub.add_parser(
        "joints", help="the joint set of the glove's hand at a pose",
        description="Print the WebXR joint set (25 joints: names, positions, orientations, radii, in screen "
                    "units) of the glove's hand at a pose, its fingers straight (--flat) or bent (--curl).")
    joints.add_argument("--glove", metavar="FILE", help="glove file (default: config/glove.yaml)")
    joints.add_argument("--flat", action="store_true", help="straight fingers (the default; the rigid hand)")
    joints.add_argument("--curl", action="append", default=[], metavar="FINGER=C",
                        help=f"bend a finger, 0 (straight) .. 1 (fist): {', '.join(FINGER_NAMES)} or all; repeatable")
    joints.add_argument("--spread", type=_unit, default=0.0, metavar="S", help="spread the fingers, 0 .. 1")
    joints.add_argument("--handedness", choices=("left", "right"),
                        help="the hand (default: the glove's, left for config/glove.yaml); the other one is the "
                             "glove mirrored")
    joints.add_argument("--position", nargs=3, type=float, metavar=("X", "Y", "Z"), default=[0.0, 0.0, 0.0],
                        help="the hand's origin (palm centre) in screen coordinates (default 0 0 0)")
    joints.add_argument("--orientation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                        default=[0.0, 0.0, 0.0, 1.0], help="unit quaternion, hand frame -> screen (default identity)")
    joints.set_defaults(func=run_joints)


def run_joints(args) -> int:
    from touch4d.tactile.pose import check_pose
    glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None)
    if args.flat and (args.curl or args.spread):
        raise ConfigError(COMMAND_LINE, "--flat", "straight fingers, without --curl or --spread")
    position, orientation = check_pose(args.position, args.orientation)
    joints = glove.skeleton.joint_set(position, orientation, glove.units_per_metre, _shape(args.curl, args.spread),
                                      args.handedness)
    print(json.dumps(joints.to_json()))
    return 0


def _shape(curls: list[str], spread: float) -> HandShape:
    curl = {}
    for item in curls:
        finger, _, value = item.partition("=")
        try:
            amount = float(value)
        except ValueError:
            amount = math.nan
        if finger not in (*FINGER_NAMES, "all") or not 0.0 <= amount <= 1.0:
            hint = schema.did_you_mean(finger, (*FINGER_NAMES, "all")) if finger not in (*FINGER_NAMES, "all") else None
            raise ConfigError(COMMAND_LINE, "--curl", f"FINGER=C with FINGER one of {', '.join(FINGER_NAMES)}, "
                              "all, and C in 0..1", got=item, hint=hint)
        curl.update({f: amount for f in FINGER_NAMES} if finger == "all" else {finger: amount})
    return HandShape(curl=curl, spread=spread)


def read_joints(path, glove):
    """(names, positions, orientations, handedness) from a joint-set file (JSON or YAML)."""
    data = schema.load(path, JointsFile, "joint set")
    n = len(data.names)
    for key in ("positions", "orientations"):
        if len(getattr(data, key)) != n:
            schema.fail(path, key, f"one entry per name ({n})", got=f"{len(getattr(data, key))} entries")
    return (data.names, np.array(data.positions, float), np.array(data.orientations, float),
            data.handedness or glove.skeleton.handedness)


def run_probe(args) -> int:
    scene = load_scene(resolve_path(args.scene, COMMAND_LINE, key="--scene", what="scene file"))
    if args.projection != "scene":
        scene.projection = args.projection
    glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None)
    if (args.joints is None) == (args.position is None):
        raise ConfigError(COMMAND_LINE, "--position", "either --position (a rigid pose) or --joints FILE")
    if args.joints is not None:
        path = resolve_path(args.joints, COMMAND_LINE, key="--joints", what="joint set file")
        names, positions, orientations, handedness = read_joints(path, glove)
        try:
            st = compute_joint_stimulus(glove, scene.ray_caster(), names, positions, orientations, handedness,
                                        args.alpha, args.beta)
        except JointsError as exc:
            raise ConfigError(path, "(file)", "a joint set that places the hand", got=str(exc)) from None
    else:
        st = compute_stimulus(glove, scene.ray_caster(), args.position, args.orientation, args.alpha, args.beta)
    if args.json:
        print(json.dumps(probe_report(glove.motor_names, glove.motor_sample, st)))
    else:
        print(probe_text(glove, scene, st))
    return 0


def probe_report(motor_names, motor_sample, st: Stimulus) -> dict:
    """The JSON form: constants, every sample (screen position, l or null, s, h), every motor."""
    return {
        "alpha": st.alpha, "beta": st.beta, "gamma": st.gamma,
        "samples": [
            {"position": p.tolist(), "l": None if math.isnan(l) else float(l), "s": float(s), "h": float(h)}
            for p, l, s, h in zip(st.positions, st.l, st.s, st.h)
        ],
        "motors": [
            {"name": name, "sample": int(i), "h": float(h), "V": float(v)}
            for name, i, h, v in zip(motor_names, motor_sample, st.motor_h, st.V)
        ],
    }


def probe_text(glove, scene, st: Stimulus) -> str:
    """A short human summary: what was touched and a table of the motors."""
    touched = st.touched
    lines = [
        f"glove {glove.path}: {len(st.l)} samples, {len(st.V)} motors; alpha {st.alpha:g}, "
        f"beta {st.beta:g}, gamma {st.gamma:g}; projection {scene.projection}",
        f"samples inside the screen: {int(st.inside.sum())}, touching: {int(touched.sum())}, "
        f"active (s > 0): {int(np.count_nonzero(st.s))}",
    ]
    if touched.any():
        names = sorted({scene.objects[i].name for i in np.unique(st.hit[touched])})
        lines.append(f"l from {np.nanmin(st.l):.4f} to {np.nanmax(st.l):.4f} screen units; "
                     f"h up to {st.h.max():.3f}; objects touched: {', '.join(names)}")
    width = max(len(n) for n in glove.motor_names)
    lines.append(f"{'motor':<{width}}  sample  {'h':>6}  {'V':>6}")
    for name, i, h, v in zip(glove.motor_names, glove.motor_sample, st.motor_h, st.V):
        lines.append(f"{name:<{width}}  {int(i):>6}  {h:6.3f}  {v:6.3f}  {'#' * int(round(20 * min(v, 1.0)))}")
    return "\n".join(lines)


def _positive(text: str) -> float:
    value = _finite(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text}")
    return value


def _unit(text: str) -> float:
    value = _finite(text)
    if not 0.0 <= value <= 1.0:
        raise argparse.ArgumentTypeError(f"expected a number in 0..1, got {text}")
    return value


def _finite(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text}")
    return value
