"""The 4D scene: objects (a shape, size, pose, colour), the projection; YAML files and `scene/state` messages.

Scene file (YAML)::

    projection: orthographic          # or perspective, with eye_distance (screen units, default 3)
    view: projection                  # or slice (each object's cross-section at w = slice_w, solid), or both
    slice_w: 1.5                      # where the slice cuts (default: the middle of the objects' w extent)
    slice_touch: section              # in a slice view the glove renders the section, or the projection
    objects:
      - name: cube                    # optional
        shape: tesseract              # a catalog name (params: {...} for its parameters), or a custom
                                      # shape, here or beside `shape`: {vertices: [[x,y,z,w], ...]}
                                      # | {halfspaces: [[n1,n2,n3,n4,d], ...]}
                                      # | {parts: [{vertices: ...} | {halfspaces: ...}, ...]} (a union)
        size: 1.0                     # scale of local coordinates; halfspaces become n.x <= d * size
        position: [0, 0, 0, 1.5]
        rotation: [[xw, 30], [yz, 10]]  # world = R_yz(10) R_xw(30) local + position
        color: "#3399ff"              # [r, g, b] or [r, g, b, a] in 0..1, #rrggbb, #rrggbbaa or a CSS name
        physics: {mass: 1.0}          # optional: rigid-body physics of the object (touch4d.physics.config)
    physics: {gravity: [0, -9.81, 0, 0]}   # optional: the scene's (docs/physics.md)

Every mistake is a ConfigError naming the file and the key (`objects[0].color`), never a traceback.
"""
from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from typing import Annotated, Literal

import msgspec
import numpy as np
from PIL import ImageColor

from touch4d import errors, schema
from touch4d.configfile import resolve_path
from touch4d.schema import Finite, Positive

from .physics_keys import ObjectPhysics, ScenePhysics
from .polytope import GeometryError, Polytope, not_corners
from .raycast import RayCaster
from .rotation import plane_axes, rotation_from_list
from .section import SectionCaster
from .shapes import get_shape, list_shapes

CUSTOM_KINDS = ("vertices", "halfspaces", "parts")
COLOR_FORMS = "a colour: [r, g, b] or [r, g, b, a] in 0..1, '#rrggbb', '#rrggbbaa' or a CSS name such as 'orange'"

DEFAULT_EYE_DISTANCE = 3.0
PALETTE = np.array([
    [0.30, 0.65, 1.00, 1.0], [1.00, 0.55, 0.20, 1.0], [0.40, 0.85, 0.40, 1.0],
    [0.90, 0.35, 0.60, 1.0], [0.95, 0.85, 0.30, 1.0], [0.60, 0.50, 0.95, 1.0],
])

_custom_cache: dict[bytes, list[Polytope]] = {}
_part_cache: dict[tuple[str, bytes], np.ndarray] = {}   # (kind, rows) of a custom part -> its half-spaces


@dataclass
class SceneObject:
    """One object: a catalog shape (or custom convex parts), its size, pose and colour."""

    name: str
    shape: str                         # catalog name, or "custom"
    params: dict = field(default_factory=dict)
    size: float = 1.0
    position: np.ndarray = field(default_factory=lambda: np.zeros(4))
    orientation: np.ndarray = field(default_factory=lambda: np.eye(4))
    color: np.ndarray = field(default_factory=lambda: PALETTE[0].copy())
    custom_parts: list | None = None   # "custom" only: local (K,5) half-space arrays [n1,n2,n3,n4,d]

    def local_parts(self) -> list[Polytope]:
        """Convex parts in local, unscaled coordinates (hulls are cached, so rotating costs no Qhull)."""
        if self.shape == "custom":
            return _custom_polytopes(self.custom_parts)
        return get_shape(self.shape, **self.params).parts

    def world_parts(self) -> list[Polytope]:
        """Convex parts placed in the world: orientation @ (size * local) + position."""
        return [p.transformed(self.orientation, self.position, self.size) for p in self.local_parts()]

    def to_map(self) -> dict:
        """The `SceneObject` map of a `scene/state` message."""
        out = {
            "name": self.name, "shape": self.shape, "params": dict(self.params), "size": float(self.size),
            "position": np.asarray(self.position, dtype=np.float64),
            "orientation": np.asarray(self.orientation, dtype=np.float64),
            "color": np.asarray(self.color, dtype=np.float64),
        }
        if self.shape == "custom":
            out["parts"] = [np.asarray(h, dtype=np.float64) for h in self.custom_parts]
        return out


@dataclass
class Scene:
    """Objects, projection mode and eye distance, the view (projection, slice, both) and where the slice
    cuts, the selected object and a revision counter."""

    objects: list[SceneObject] = field(default_factory=list)
    projection: str = "orthographic"
    eye_distance: float = DEFAULT_EYE_DISTANCE
    selected: int = 0
    revision: int = 0
    view: str = "projection"
    slice_w: float = 0.0
    slice_touch: str = "section"

    @property
    def touches_section(self) -> bool:
        """Whether the glove renders the cross-section at slice_w (a slice view that says so) rather
        than the projection."""
        return self.view == "slice" and self.slice_touch == "section"

    @property
    def perspective_eye(self) -> float | None:
        """The eye distance when projecting in perspective, else None (the form RayCaster takes)."""
        return self.eye_distance if self.projection == "perspective" else None

    def world_parts(self) -> list[tuple[int, Polytope]]:
        """(object index, world Polytope) for every convex part of every object."""
        return [(i, p) for i, obj in enumerate(self.objects) for p in obj.world_parts()]

    def ray_caster(self) -> RayCaster | SectionCaster:
        """What the glove touches: a RayCaster for this scene and its projection (the paper), or in a
        slice view that touches the section, a SectionCaster of the cross-sections at slice_w."""
        if self.touches_section:
            return SectionCaster(self.world_parts(), self.slice_w, self.perspective_eye)
        return RayCaster(self.world_parts(), self.perspective_eye)

    def to_message(self):
        """This scene as a `scene/state` message."""
        from touch4d.messages import SceneState

        return SceneState(objects=[o.to_map() for o in self.objects], projection=self.projection,
                          eye_distance=float(self.eye_distance), selected=int(self.selected),
                          revision=int(self.revision), view=self.view, slice_w=float(self.slice_w),
                          slice_touch=self.slice_touch)

    @classmethod
    def from_message(cls, msg) -> "Scene":
        """A Scene from a `scene/state` message (objects rebuilt from cached hulls)."""
        from touch4d.messages import MessageError

        objects = []
        for i, m in enumerate(msg.objects):
            try:   # the map's fields, as the message codec left them (plain values and arrays)
                shape = str(m["shape"])
                params = msgspec.convert(m.get("params") or {}, ShapeParams, strict=True)
                obj = SceneObject(
                    name=str(m["name"]), shape=shape, params=params,
                    size=float(m["size"]), position=np.asarray(m["position"], dtype=np.float64).reshape(4),
                    orientation=np.asarray(m["orientation"], dtype=np.float64).reshape(4, 4),
                    color=np.asarray(m["color"], dtype=np.float64).reshape(4),
                    custom_parts=[np.asarray(h, dtype=np.float64).reshape(-1, 5) for h in m["parts"]]
                    if shape == "custom" else None,
                )
            except (KeyError, ValueError, TypeError) as exc:
                raise MessageError(f"SceneState.objects[{i}]: {exc}") from exc
            try:
                obj.local_parts()
            except GeometryError as exc:
                raise MessageError(f"SceneState.objects[{i}]: {exc}") from exc
            objects.append(obj)
        return cls(objects=objects, projection=msg.projection, eye_distance=float(msg.eye_distance),
                   selected=int(msg.selected), revision=int(msg.revision), view=msg.view,
                   slice_w=float(msg.slice_w), slice_touch=msg.slice_touch)

    def copy(self) -> "Scene":
        return replace(self, objects=[replace(o, position=o.position.copy(), orientation=o.orientation.copy())
                                      for o in self.objects])


def scene_digest(msg, touch_only: bool = False) -> bytes:
    """The one digest of a `scene/state` message: everything in its objects, the projection, the eye
    distance and the view with its slice (all but `selected` and `revision`; with `touch_only`, names
    and colours too, which the hand cannot feel). Equal digests draw (or touch) the same scene, so a
    repeated message (the scene node repeats it for late joiners) or a new selection rebuilds nothing."""
    skipped = ("name", "color") if touch_only else ()
    digest = hashlib.blake2b(digest_size=16)
    digest.update(f"{msg.projection}|{float(msg.eye_distance)!r}|{msg.view}|{float(msg.slice_w)!r}|"
                  f"{msg.slice_touch}".encode())

    def add(value) -> None:
        if isinstance(value, dict):
            for k in sorted(value, key=str):
                if k in skipped:
                    continue
                digest.update(f"<{k}>".encode())
                add(value[k])
        elif isinstance(value, (list, tuple)):
            digest.update(f"[{len(value)}".encode())
            for item in value:
                add(item)
        elif isinstance(value, np.ndarray):
            digest.update(f"{value.dtype}{value.shape}".encode() + np.ascontiguousarray(value).tobytes())
        else:
            digest.update(repr(value).encode())

    add(msg.objects)
    return digest.digest()


def _custom_polytopes(parts) -> list[Polytope]:
    key = b"".join(np.ascontiguousarray(h, dtype=np.float64).tobytes() + b"|" for h in parts)
    if key not in _custom_cache:
        _custom_cache[key] = [Polytope.from_halfspaces(h) for h in parts]
    return _custom_cache[key]


# ---- scene files ---------------------------------------------------------------------------------

ShapeParams = dict[str, str | int | float]   # a catalog shape's parameters (their ranges: shapes.py)
Row4 = Annotated[tuple[Finite, Finite, Finite, Finite], msgspec.Meta(description="a list of 4 numbers")]
Row5 = Annotated[tuple[Finite, Finite, Finite, Finite, Finite], msgspec.Meta(description="a list of 5 numbers")]
Rows4 = Annotated[list[Row4], msgspec.Meta(min_length=1)]
Rows5 = Annotated[list[Row5], msgspec.Meta(min_length=1)]
Step = Annotated[tuple[str, Finite], msgspec.Meta(description="a pair [plane, degrees] such as [xw, 30]")]


class PartSpec(msgspec.Struct, forbid_unknown_fields=True):
    """One convex part of a custom shape: its vertices or its half-spaces [n1, n2, n3, n4, d]."""

    vertices: Rows4 | None = None
    halfspaces: Rows5 | None = None

    def __post_init__(self):
        if (self.vertices is None) == (self.halfspaces is None):
            raise schema.Invalid("a mapping with one key, vertices or halfspaces",
                                 got=[k for k in ("vertices", "halfspaces") if getattr(self, k) is not None] or None)


class CustomShape(PartSpec, forbid_unknown_fields=True):
    """A custom shape: one convex part (vertices or half-spaces) or a union of `parts`."""

    parts: Annotated[list[PartSpec], msgspec.Meta(min_length=1)] | None = None

    def __post_init__(self):
        given = [k for k in CUSTOM_KINDS if getattr(self, k) is not None]
        if len(given) != 1:
            raise schema.Invalid("a catalog name, or a mapping with one of vertices, halfspaces, parts",
                                 got=given or None)


class ObjectSpec(msgspec.Struct, forbid_unknown_fields=True):
    """One object of a scene file, as written (see the module doc)."""

    name: str | None = None
    shape: str | CustomShape | None = None
    params: ShapeParams = {}
    vertices: Rows4 | None = None
    halfspaces: Rows5 | None = None
    parts: Annotated[list[PartSpec], msgspec.Meta(min_length=1)] | None = None
    size: Positive = 1.0
    position: Row4 = (0.0, 0.0, 0.0, 0.0)
    rotation: list[Step] = []
    color: str | list[Finite] | None = None
    physics: ObjectPhysics | None = None          # read by touch4d.physics (docs/physics.md)


class SceneFile(msgspec.Struct, forbid_unknown_fields=True):
    """A scene file, as written (see the module doc)."""

    objects: Annotated[list[ObjectSpec], msgspec.Meta(min_length=1, description="a non-empty list of objects")]
    projection: Literal["orthographic", "perspective"] = "orthographic"
    eye_distance: Positive = DEFAULT_EYE_DISTANCE
    view: Literal["projection", "slice", "both"] = "projection"
    slice_w: Finite | None = None
    slice_touch: Literal["section", "projection"] = "section"
    description: str = ""
    selected: int = 0
    physics: ScenePhysics | None = None           # read by touch4d.physics (docs/physics.md)


def load_scene(path) -> Scene:
    """Read and check a YAML scene file (found by `resolve_path`); a bad file raises ConfigError naming
    the file, key and reason."""
    path = resolve_path(path, what="scene file")
    return parse_scene(schema.read_yaml(path, "scene file"), path)


def parse_scene(data, file=None) -> Scene:
    """A Scene from the parsed YAML mapping `data` (errors name `file`)."""
    spec = schema.convert(data, SceneFile, file)
    objects = [_object(file, f"objects[{i}]", item, i) for i, item in enumerate(spec.objects)]
    if not -1 <= spec.selected < len(objects):
        schema.fail(file, "selected", f"an object index -1..{len(objects) - 1}", got=spec.selected)
    slice_w = spec.slice_w
    if slice_w is None:                              # the middle of what there is to cut
        w = np.concatenate([p.vertices[:, 3] for o in objects for p in o.world_parts()])
        slice_w = float(0.5 * (w.min() + w.max()))
    return Scene(objects=objects, projection=spec.projection, eye_distance=spec.eye_distance, selected=spec.selected,
                 view=spec.view, slice_w=slice_w, slice_touch=spec.slice_touch)


def _object(file, key, item: ObjectSpec, index) -> SceneObject:
    given = [k for k in ("shape", *CUSTOM_KINDS) if getattr(item, k) is not None]
    if len(given) != 1:
        schema.fail(file, key, "exactly one of shape, vertices, halfspaces, parts", got=given or None)
    color = _color(file, f"{key}.color", item.color if item.color is not None else PALETTE[index % len(PALETTE)].tolist())
    orientation = _rotation(file, f"{key}.rotation", item.rotation)
    shape, params = item.shape, item.params
    if params and not isinstance(shape, str):
        schema.fail(file, f"{key}.params", "no params for a shape given by vertices/half-spaces", got=params)
    if isinstance(shape, CustomShape):                 # a custom shape written under `shape:`
        custom = _custom(file, f"{key}.shape", shape)
    elif isinstance(shape, str):
        if shape not in list_shapes():
            schema.fail(file, f"{key}.shape", f"a catalog shape ({', '.join(list_shapes())}) or a mapping with one "
                        "of vertices, halfspaces, parts", got=shape, choices=list_shapes())
        try:
            get_shape(shape, **params)
        except GeometryError as exc:
            schema.fail(file, f"{key}.params", f"valid parameters for {shape}", got=str(exc))
        custom = None
    else:
        custom = _custom(file, key, item)
    name = item.name if item.name is not None else f"{'custom' if custom is not None else shape}{index}"
    return SceneObject(name=name, shape="custom" if custom is not None else shape, params=dict(params),
                       size=item.size, position=np.array(item.position, dtype=np.float64),
                       orientation=orientation, color=color, custom_parts=custom)


def _color(file, key, value) -> np.ndarray:
    """RGBA in 0..1 from [r, g, b], [r, g, b, a], or a string Pillow's ImageColor reads (#rrggbb, #rrggbbaa,
    CSS names such as 'orange', rgb(...), hsl(...))."""
    if isinstance(value, str):
        try:
            rgba = ImageColor.getrgb(value.strip())
        except ValueError:
            schema.fail(file, key, COLOR_FORMS, got=value, choices=ImageColor.colormap)
        color = np.array(rgba, dtype=np.float64) / 255.0
    elif len(value) in (3, 4):
        color = np.array(value, dtype=np.float64)
        if np.any((color < 0) | (color > 1)):
            schema.fail(file, key, f"{COLOR_FORMS} (list components between 0 and 1)", got=value)
    else:
        schema.fail(file, key, COLOR_FORMS, got=value)
    return np.r_[color, 1.0] if len(color) == 3 else color


def _custom(file, key, spec: PartSpec) -> list[np.ndarray]:
    """A custom shape (vertices, halfspaces or parts, at `key`) -> the local half-spaces of its parts."""
    if spec.parts is not None:
        return [_part(file, f"{key}.parts[{j}]", part) for j, part in enumerate(spec.parts)]
    return [_part(file, key, spec)]


def _part(file, key, spec: PartSpec) -> np.ndarray:
    """One convex part given by vertices or half-spaces -> its local (K,5) half-spaces."""
    kind = "vertices" if spec.vertices is not None else "halfspaces"
    rows = np.array(getattr(spec, kind), dtype=np.float64)
    cache_key = (kind, rows.tobytes())
    if cache_key not in _part_cache:                 # a hull takes tens of ms: build each part once
        try:
            poly = Polytope.from_vertices(rows) if kind == "vertices" else Polytope.from_halfspaces(rows)
        except GeometryError as exc:
            schema.fail(file, f"{key}.{kind}", "a bounded convex 4-polytope", got=str(exc))
        if kind == "vertices":
            _all_corners(file, f"{key}.vertices", rows, poly)
        halfspaces = np.array(poly.halfspaces)
        halfspaces.setflags(write=False)             # shared by every scene that has this part
        _part_cache[cache_key] = halfspaces
    return _part_cache[cache_key]


def _all_corners(file, key, rows, poly) -> None:
    """Refuse a vertex list whose hull drops some of its points (a dent, an inner point): the shape
    touched would not be the one written. A concave shape is a union of convex `parts:`."""
    dropped = not_corners(rows, poly)
    if dropped:
        where = "; ".join(f"[{i}] {[float(f'{v:.6g}') for v in rows[i]]} lies {how}" for i, how in dropped[:5])
        more = f" (and {len(dropped) - 5} more)" if len(dropped) > 5 else ""
        raise errors.ConfigError(file, key, "the corners of one convex shape (each point a vertex of their convex hull)",
                          detail=f"{len(dropped)} of {len(rows)} points would be dropped: {where}{more}",
                          hint="a concave shape is a union of convex pieces: give them under `parts:` "
                               "as [{vertices: ...}, {vertices: ...}]")


def _rotation(file, key, steps) -> np.ndarray:
    for i, (plane, _degrees) in enumerate(steps):
        try:
            plane_axes(plane)
        except ValueError:
            schema.fail(file, f"{key}[{i}]", "a plane of two axes among x, y, z, w (e.g. xw)", got=plane,
                        choices=[a + b for a in "xyzw" for b in "xyzw" if a < b])
    return rotation_from_list([list(step) for step in steps])
