"""`touch4d render --scene FILE [--hand X Y Z] [--camera ...] [--view slice --slice-w C] [--size WxH]
[--backend gpu|clip] -o out.png`:
one frame, offline."""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace

import numpy as np

from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError

from touch4d.render.camera import OrbitCamera, parse_camera
from touch4d.render.frame import Style


def register(subparsers) -> None:
    p = subparsers.add_parser("render", help="render one frame of a scene to a PNG (headless, EGL)",
                              formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    p.add_argument("--scene", required=True, help="scene file (YAML), e.g. config/scenes/hypercube.yaml")
    p.add_argument("--hand", nargs=3, type=float, metavar=("X", "Y", "Z"),
                   help="put the glove hand here (screen units) and show its tactile field")
    p.add_argument("--hand-rotation", nargs=4, type=float, metavar=("QX", "QY", "QZ", "QW"),
                   default=[0.0, 0.0, 0.0, 1.0], help="the hand's orientation quaternion")
    p.add_argument("--glove", default=None, help="glove file (default config/glove.yaml)")
    p.add_argument("--camera", default="",
                   help="orbit camera: yaw=DEG,pitch=DEG,distance=D,fov=DEG,target=X:Y:Z,ortho")
    p.add_argument("--projection", choices=("orthographic", "perspective"),
                   help="override the scene's 4D -> 3D projection")
    p.add_argument("--view", choices=("projection", "slice", "both"),
                   help="override the scene's view: the projection, the cross-section at w = --slice-w, or both")
    p.add_argument("--slice-w", type=float, metavar="C", help="where the slice cuts (default the scene's slice_w)")
    p.add_argument("--size", default="1280x800", help="image size WIDTHxHEIGHT in pixels")
    p.add_argument("--samples", type=int, default=4, help="multisampling (0 for exact pixel colours)")
    p.add_argument("--no-frame", action="store_true", help="leave out the screen's frame")
    p.add_argument("--no-tactile", action="store_true", help="leave out the tactile cube (always out without --hand)")
    p.add_argument("--no-status", action="store_true", help="leave out the status line")
    p.add_argument("--no-centres", action="store_true", help="leave out the cells' centre copies")
    p.add_argument("--no-clip", action="store_true", help="draw what other objects hide too")
    p.add_argument("--backend", choices=("gpu", "clip", "auto"), default="auto",
                   help="gpu: per-pixel ray test in shaders; clip: the paper's clip units on the CPU; "
                        "auto: gpu, or clip on a software rasteriser (llvmpipe)")
    p.add_argument("-o", "--output", required=True, help="PNG file to write")
    p.set_defaults(func=_render)


def parse_size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError("--size", "size", "WIDTHxHEIGHT, e.g. 1280x800", got=text) from None
    if not (16 <= w <= 8192 and 16 <= h <= 8192):
        raise ConfigError("--size", "size", "16..8192 pixels each way", got=text)
    return w, h


def slice_warning(scene, where: str, given: bool) -> str | None:
    """Why a slice cut `where` (a flag or a scene key) shows nothing: it was `given` to a view without
    a slice (it is then ignored), or it cuts outside every object's range of w (an empty slice)."""
    from touch4d.geometry.section import w_extent

    if scene.view == "projection":
        return (f"{where} {scene.slice_w:g} is ignored: the view is the projection (--view slice or both cuts "
                "the scene)") if given else None
    ranges = [(obj.name, *w_extent(np.vstack([p.vertices for p in obj.world_parts()]))) for obj in scene.objects]
    if not ranges or any(low <= scene.slice_w <= high for _, low, high in ranges):
        return None
    spans = ", ".join(f"{name} {low:g}..{high:g}" for name, low, high in ranges)
    return f"{where} {scene.slice_w:g} cuts no object: the slice is empty (the objects span w {spans})"


def _render(args) -> int:
    from touch4d.geometry.scene import load_scene
    from touch4d.messages import HandPose
    from touch4d.tactile.engine import TactileEngine
    from touch4d.tactile.glove import load_glove

    from touch4d.render.context import save_png
    from touch4d.render.offscreen import OffscreenRenderer
    from touch4d.render.view import SceneView, Show

    size = parse_size(args.size)
    camera = parse_camera(args.camera, OrbitCamera())
    if args.samples < 0:
        raise ConfigError("--samples", "samples", "0 or more", got=args.samples)
    scene_file = resolve_path(args.scene, COMMAND_LINE, key="--scene", what="scene file")
    scene = load_scene(scene_file)
    if args.projection:
        scene = replace(scene, projection=args.projection)
    if args.view:
        scene = replace(scene, view=args.view)
    if args.slice_w is not None:
        if not np.isfinite(args.slice_w):
            raise ConfigError("(command line)", "--slice-w", "a finite number", got=args.slice_w)
        scene = replace(scene, slice_w=args.slice_w)
    warning = slice_warning(scene, "--slice-w" if args.slice_w is not None else f"{args.scene}: slice_w",
                            given=args.slice_w is not None)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    glove = load_glove(resolve_path(args.glove, COMMAND_LINE, key="--glove", what="glove file") if args.glove else None)
    show = Show(frame=not args.no_frame, tactile=bool(args.hand) and not args.no_tactile, status=not args.no_status)
    view = SceneView(glove, Style(centres=not args.no_centres, clip=not args.no_clip), show)
    view.set_scene(scene)
    if args.hand:
        pose = HandPose(position=np.array(args.hand, dtype=float),
                        orientation=np.array(args.hand_rotation, dtype=float), valid=True)
        try:
            pose.check()
        except ValueError as exc:
            raise ConfigError("--hand-rotation", "orientation", "a unit quaternion", got=str(exc)) from None
        engine = TactileEngine(glove)
        engine.set_scene(scene.to_message())
        field, motors = engine.messages(pose)
        view.set_hand(pose)
        if field is not None:
            view.set_field(field)
        view.set_motors(motors)
    renderer = OffscreenRenderer(size, samples=args.samples, backend=args.backend)
    try:
        image = renderer.render(view, camera, [f"scene file {args.scene}"])
    finally:
        renderer.release()
    path = save_png(image, args.output)
    print(f"wrote {path} ({size[0]}x{size[1]}) of {scene_file}")
    return 0
