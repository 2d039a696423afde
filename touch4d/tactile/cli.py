"""`touch4d tactile probe`: the stimulus for one hand pose against a scene file, as text or JSON."""
from __future__ import annotations

import argparse
import json
import math

import numpy as np

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.geometry.scene import load_scene

from .glove import load_glove
from .stimulus import Stimulus, compute_stimulus


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
    probe.add_argument("--position", required=True, nargs=3, type=float, metavar=("X", "Y", "Z"),
                       help="the hand's origin (palm centre) in screen coordinates")
    probe.add_argument("--orientation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                       default=[0.0, 0.0, 0.0, 1.0], help="unit quaternion, hand frame -> screen (default identity)")
    probe.add_argument("--alpha", type=_positive, metavar="A", help="gradient constant of eq. 1 (per screen unit)")
    probe.add_argument("--beta", type=_unit, metavar="B", help="reducing constant of eq. 2 (0..1)")
    probe.add_argument("--projection", choices=("scene", "orthographic", "perspective"), default="scene",
                       help="rays along +w (orthographic) or from the eye (perspective); default: the scene's")
    probe.add_argument("--json", action="store_true", help="print JSON (a stable interface for scripts)")
    probe.set_defaults(func=run_probe)


def run_probe(args) -> int:
    scene = load_scene(resolve_path(args.scene, COMMAND_LINE, key="--scene", what="scene file"))
    if args.projection != "scene":
        scene.projection = args.projection
    glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None)
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
