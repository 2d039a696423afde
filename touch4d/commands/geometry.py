"""`touch4d shape list`, `touch4d shape info NAME [-p KEY=VALUE ...]`: what the catalog holds;
`touch4d scene check FILE`: whether a scene file is right, and what it holds; `touch4d scene slice FILE
--w C [--json]`: every object's cross-section at w = C."""
from __future__ import annotations

import json

import numpy as np

from touch4d import schema
from touch4d.configfile import COMMAND_LINE, resolve_path
from touch4d.errors import ConfigError

from touch4d.geometry.polytope import GeometryError
from touch4d.geometry.projection import project
from touch4d.geometry.scene import load_scene
from touch4d.geometry.section import cross_section, w_extent
from touch4d.geometry.shapes import get_shape, list_shapes, shape_params


def register(subparsers) -> None:
    shape = subparsers.add_parser("shape", help="the 4D shape catalog")
    sub = shape.add_subparsers(dest="shape_command", metavar="ACTION")
    lst = sub.add_parser("list", help="every catalog shape with its vertex/edge/face/cell counts")
    lst.set_defaults(func=_list)
    info = sub.add_parser("info", help="one shape: its size convention, parameters and boundary")
    info.add_argument("name", help="a catalog name (see `touch4d shape list`)")
    info.add_argument("-p", "--param", action="append", default=[], metavar="KEY=VALUE",
                      help="a shape parameter, e.g. -p base=dodecahedron (repeatable)")
    info.set_defaults(func=_info)
    shape.set_defaults(func=lambda args: shape.print_help() or 2)

    scene = subparsers.add_parser("scene", help="scene files")
    sub = scene.add_subparsers(dest="scene_command", metavar="ACTION")
    check = sub.add_parser("check", help="check a scene file: every mistake named by its key; what it holds",
                           description="Load a scene file as the scene node would; print its objects and where "
                                       "they fall on the screen, or the first mistake with its key (exit 2).")
    check.add_argument("file", metavar="FILE", help="scene file, e.g. config/scenes/hypercube.yaml")
    check.set_defaults(func=_check)
    cut = sub.add_parser("slice", help="every object's cross-section at w = C: vertices, faces and their cells, volume",
                         description="Cut each object of a scene file by the hyperplane w = C and print the convex "
                                     "polyhedron of each convex part: its vertices (x, y, z), its faces (vertex "
                                     "indices, each with the cell of the part it cuts) and its volume.")
    cut.add_argument("file", metavar="FILE", help="scene file, e.g. config/scenes/hypercube.yaml")
    cut.add_argument("--w", type=float, default=None, metavar="C",
                     help="where to cut (screen units; default the scene's slice_w)")
    cut.add_argument("--json", action="store_true", help="print the sections as JSON")
    cut.set_defaults(func=_slice)
    scene.set_defaults(func=lambda args: scene.print_help() or 2)


def _counts(shape) -> tuple[int, int, int, int]:
    return tuple(int(x) for x in np.sum([p.counts for p in shape.parts], axis=0))


def _list(args) -> int:
    print(f"{'name':<14}{'parts':>6}{'V':>6}{'E':>6}{'F':>6}{'C':>6}  size / description")
    for name in list_shapes():
        shape = get_shape(name)
        v, e, f, c = _counts(shape)
        print(f"{name:<14}{len(shape.parts):>6}{v:>6}{e:>6}{f:>6}{c:>6}  {shape.doc}")
    return 0


def _info(args) -> int:
    if args.name not in list_shapes():
        schema.fail("(command line)", "NAME", f"a catalog shape ({', '.join(list_shapes())})", got=args.name,
                    choices=list_shapes())
    params = {}
    for item in args.param:
        key, sep, value = item.partition("=")
        if not sep:
            raise ConfigError("(command line)", "--param", "KEY=VALUE", got=item)
        try:
            params[key] = schema.parse_yaml(value)
        except ConfigError as exc:   # the YAML problem whole, on one line
            raise ConfigError("(command line)", "--param", "KEY=VALUE with a YAML value", got=item,
                              detail=exc.detail) from None
    try:
        shape = get_shape(args.name, **params)
    except GeometryError as exc:
        raise ConfigError("(command line)", "--param", f"parameters of {args.name}: {shape_params(args.name)}",
                          got=str(exc)) from None
    print(f"{shape.name}: {shape.doc}")
    print(f"parameters: {shape.params or 'none'}")
    for i, part in enumerate(shape.parts):
        v, e, f, c = part.counts
        lo, hi = part.vertices.min(axis=0), part.vertices.max(axis=0)
        cells = ", ".join(f"{n}x{k}" for k, n in sorted(_cell_kinds(part).items()))
        print(f"part {i}: {v} vertices, {e} edges, {f} faces, {c} cells ({cells}); "
              f"V-E+F-C = {v - e + f - c}; box {np.round(lo, 4).tolist()} .. {np.round(hi, 4).tolist()}")
    return 0


def _check(args) -> int:
    path = resolve_path(args.file, COMMAND_LINE, key="FILE", what="scene file")
    scene = load_scene(path)
    eye = f", eye at w = -{scene.eye_distance:g}" if scene.projection == "perspective" else ""
    view = "" if scene.view == "projection" else \
        f"; {scene.view} view at w = {scene.slice_w:g} (touch: {scene.slice_touch})"
    print(f"{path}: {len(scene.objects)} object(s), {scene.projection} projection{eye}{view}")
    outside = 0
    for i, obj in enumerate(scene.objects):
        parts = obj.world_parts()
        vertices = np.vstack([p.vertices for p in parts])
        rgba = "#" + "".join(f"{round(c * 255):02x}" for c in obj.color)
        what = obj.shape if obj.shape != "custom" else f"custom, {len(parts)} convex part(s)"
        line = (f"  [{i}] {obj.name}: {what}, size {obj.size:g}, at {np.round(obj.position, 3).tolist()}, "
                f"colour {rgba}, {len(vertices)} vertices")
        where = _on_screen(vertices, scene)
        outside += where is not None
        print(line + ("" if where is None else f"; {where}"))
    from touch4d.physics.config import load_physics
    from touch4d.tracking.scene_control import controller_object

    static = load_physics(path).static
    index = controller_object(scene.selected, static, len(scene.objects))
    selected = ("the whole scene" if index < 0 else f"object {index} ({scene.objects[index].name})") + (
        f"; never the static {', '.join(repr(scene.objects[i].name) for i in static)}" if static else "")
    print(f"ok{f', but {outside} object(s) cannot be seen or touched' if outside else ''}; the controller turns "
          f"{selected}")
    return 0


def _slice(args) -> int:
    path = resolve_path(args.file, COMMAND_LINE, key="FILE", what="scene file")
    scene = load_scene(path)
    c = scene.slice_w if args.w is None else args.w
    if not np.isfinite(c):
        raise ConfigError("(command line)", "--w", "a finite number", got=args.w)
    objects = []
    for obj in scene.objects:
        parts = obj.world_parts()
        sections = [cross_section(p, c) for p in parts]
        objects.append({"name": obj.name, "w_extent": list(w_extent(np.vstack([p.vertices for p in parts]))),
                        "parts": [{"vertices": s.vertices.tolist(),
                                   "faces": [{"vertices": f, "cell": int(k)} for f, k in zip(s.faces, s.face_cell)],
                                   "volume": s.volume} for s in sections]})
    if args.json:
        print(json.dumps({"file": str(path), "w": c, "objects": objects}, indent=1))
        return 0
    print(f"{path}: cross-sections at w = {c:g}")
    for i, obj in enumerate(objects):
        lo, hi = obj["w_extent"]
        print(f"  [{i}] {obj['name']}: w {lo:.4g} .. {hi:.4g}")
        for j, part in enumerate(obj["parts"]):
            if not part["faces"]:
                print(f"    part {j}: empty (w = {c:g} misses it)")
                continue
            print(f"    part {j}: {len(part['vertices'])} vertices, {len(part['faces'])} faces, "
                  f"volume {part['volume']:.6g}")
            for k, v in enumerate(part["vertices"]):
                print(f"      v{k}: {np.round(v, 6).tolist()}")
            for face in part["faces"]:
                print(f"      cell {face['cell']}: {face['vertices']}")
    return 0


def _on_screen(vertices: np.ndarray, scene) -> str | None:
    """None when the object's projection meets the screen cube [-1, 1]^3, else why not."""
    if scene.projection == "perspective" and np.any(vertices[:, 3] <= -scene.eye_distance):
        return "WARNING: partly behind the eye"
    points = project(vertices, scene.projection, scene.eye_distance)
    lo, hi = points.min(axis=0), points.max(axis=0)
    if np.any(hi < -1) or np.any(lo > 1):
        return f"WARNING: outside the screen [-1, 1]^3 (projected box {np.round(lo, 2).tolist()} .. " \
               f"{np.round(hi, 2).tolist()}): it can be neither seen nor touched"
    return None


def _cell_kinds(part) -> dict[int, int]:
    """How many cells have each number of faces."""
    sizes = [len(f) for f in part.cell_faces]
    return {k: sizes.count(k) for k in set(sizes)}
