"""The 4D scene: objects (a shape, size, pose, colour), the projection; YAML files and `scene/state` messages.

Scene file (YAML)::

    projection: orthographic          # or perspective, with eye_distance (screen units, default 3)
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

Every mistake is a ConfigError naming the file and the key (`objects[0].color`), never a traceback.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from PIL import ImageColor

from touch4d.configfile import read_yaml, resolve_path
from touch4d.errors import ConfigError

from .polytope import GeometryError, Polytope
from .raycast import RayCaster
from .rotation import plane_axes, rotation_from_list
from .shapes import get_shape, list_shapes

CUSTOM_KINDS = ("vertices", "halfspaces", "parts")
COLOR_FORMS = "a colour: [r, g, b] or [r, g, b, a] in 0..1, '#rrggbb', '#rrggbbaa' or a CSS name such as 'orange'"

DEFAULT_EYE_DISTANCE = 3.0
PALETTE = np.array([
    [0.30, 0.65, 1.00, 1.0], [1.00, 0.55, 0.20, 1.0], [0.40, 0.85, 0.40, 1.0],
    [0.90, 0.35, 0.60, 1.0], [0.95, 0.85, 0.30, 1.0], [0.60, 0.50, 0.95, 1.0],
])
# `physics` (scene and object) is read by touch4d.physics.config; the geometry ignores it.
OBJECT_KEYS = {"name", "shape", "params", "vertices", "halfspaces", "parts", "size", "position", "rotation", "color",
               "physics"}
TOP_KEYS = {"objects", "projection", "eye_distance", "description", "selected", "physics"}

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
    """Objects, projection mode and eye distance, the selected object and a revision counter."""

    objects: list[SceneObject] = field(default_factory=list)
    projection: str = "orthographic"
    eye_distance: float = DEFAULT_EYE_DISTANCE
    selected: int = 0
    revision: int = 0

    @property
    def perspective_eye(self) -> float | None:
        """The eye distance when projecting in perspective, else None (the form RayCaster takes)."""
        return self.eye_distance if self.projection == "perspective" else None

    def world_parts(self) -> list[tuple[int, Polytope]]:
        """(object index, world Polytope) for every convex part of every object."""
        return [(i, p) for i, obj in enumerate(self.objects) for p in obj.world_parts()]

    def ray_caster(self) -> RayCaster:
        """A RayCaster for this scene and its projection."""
        return RayCaster(self.world_parts(), self.perspective_eye)

    def to_message(self):
        """This scene as a `scene/state` message."""
        from touch4d.messages import SceneState

        return SceneState(objects=[o.to_map() for o in self.objects], projection=self.projection,
                          eye_distance=float(self.eye_distance), selected=int(self.selected),
                          revision=int(self.revision))

    @classmethod
    def from_message(cls, msg) -> "Scene":
        """A Scene from a `scene/state` message (objects rebuilt from cached hulls)."""
        from touch4d.messages import MessageError

        objects = []
        for i, m in enumerate(msg.objects):
            try:
                obj = SceneObject(
                    name=str(m["name"]), shape=str(m["shape"]), params=dict(m.get("params") or {}),
                    size=float(m["size"]), position=np.asarray(m["position"], dtype=np.float64).reshape(4),
                    orientation=np.asarray(m["orientation"], dtype=np.float64).reshape(4, 4),
                    color=np.asarray(m["color"], dtype=np.float64).reshape(4),
                    custom_parts=[np.asarray(h, dtype=np.float64) for h in m["parts"]] if m["shape"] == "custom" else None,
                )
                obj.local_parts()
            except (KeyError, ValueError, TypeError) as exc:
                raise MessageError(f"SceneState.objects[{i}]: {exc}") from exc
            objects.append(obj)
        return cls(objects=objects, projection=msg.projection, eye_distance=float(msg.eye_distance),
                   selected=int(msg.selected), revision=int(msg.revision))

    def copy(self) -> "Scene":
        return replace(self, objects=[replace(o, position=o.position.copy(), orientation=o.orientation.copy())
                                      for o in self.objects])


def _custom_polytopes(parts) -> list[Polytope]:
    key = b"".join(np.ascontiguousarray(h, dtype=np.float64).tobytes() + b"|" for h in parts)
    if key not in _custom_cache:
        _custom_cache[key] = [Polytope.from_halfspaces(h) for h in parts]
    return _custom_cache[key]


# ---- scene files ---------------------------------------------------------------------------------


def load_scene(path) -> Scene:
    """Read and check a YAML scene file (found by `resolve_path`); a bad file raises ConfigError naming
    the file, key and reason."""
    path = resolve_path(path, what="scene file")
    return parse_scene(read_yaml(path, "scene file"), path)


def parse_scene(data, file=None) -> Scene:
    """A Scene from the parsed YAML mapping `data` (errors name `file`)."""
    if not isinstance(data, dict):
        raise ConfigError(file, "(top level)", "a mapping with 'objects'", got=type(data).__name__)
    _known_keys(file, "", data, TOP_KEYS)
    if not isinstance(data.get("description", ""), str):
        raise ConfigError(file, "description", "a line of text", got=data["description"])
    projection = data.get("projection", "orthographic")
    if projection not in ("orthographic", "perspective"):
        raise ConfigError(file, "projection", "orthographic or perspective", got=projection)
    eye = _number(file, "eye_distance", data.get("eye_distance", DEFAULT_EYE_DISTANCE), positive=True)
    items = data.get("objects")
    if not isinstance(items, list) or not items:
        raise ConfigError(file, "objects", "a non-empty list of objects", got=items)
    objects = [_object(file, f"objects[{i}]", item, i) for i, item in enumerate(items)]
    selected = data.get("selected", 0)
    if isinstance(selected, bool) or not isinstance(selected, int) or not -1 <= selected < len(objects):
        raise ConfigError(file, "selected", f"an object index -1..{len(objects) - 1}", got=selected)
    return Scene(objects=objects, projection=projection, eye_distance=eye, selected=selected)


def _number(file, key, value, positive=False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(file, key, "a number", got=value)
    if positive and value <= 0:
        raise ConfigError(file, key, "a positive number", got=value)
    return float(value)


def _vector(file, key, value, sizes) -> np.ndarray:
    if not isinstance(value, list) or len(value) not in sizes:
        raise ConfigError(file, key, f"a list of {' or '.join(map(str, sizes))} numbers", got=value)
    return np.array([_number(file, f"{key}[{i}]", v) for i, v in enumerate(value)])


def _matrix(file, key, value, width) -> np.ndarray:
    if not isinstance(value, list) or not value:
        raise ConfigError(file, key, f"a list of rows of {width} numbers", got=value)
    return np.array([_vector(file, f"{key}[{i}]", row, (width,)) for i, row in enumerate(value)])


def _object(file, key, item, index) -> SceneObject:
    if not isinstance(item, dict):
        raise ConfigError(file, key, "a mapping with shape, size, position, rotation, color", got=item)
    _known_keys(file, f"{key}.", item, OBJECT_KEYS)
    given = [k for k in ("shape", *CUSTOM_KINDS) if k in item]
    if len(given) != 1:
        raise ConfigError(file, key, "exactly one of shape, vertices, halfspaces, parts", got=given or None)
    size = _number(file, f"{key}.size", item.get("size", 1.0), positive=True)
    position = _vector(file, f"{key}.position", item.get("position", [0, 0, 0, 0]), (4,))
    color = _color(file, f"{key}.color", item.get("color", PALETTE[index % len(PALETTE)].tolist()))
    orientation = _rotation(file, f"{key}.rotation", item.get("rotation", []))
    params = item.get("params", {})
    if not isinstance(params, dict) or not all(isinstance(k, str) for k in params):
        raise ConfigError(file, f"{key}.params", "a mapping of shape parameter names to values", got=params)
    custom = None
    shape = item.get("shape")
    if isinstance(shape, dict) and (len(shape) != 1 or next(iter(shape)) not in CUSTOM_KINDS):
        raise ConfigError(file, f"{key}.shape", "a catalog name, or a mapping with one of vertices, halfspaces, "
                          "parts", got=shape)
    if params and (isinstance(shape, dict) or "shape" not in item):
        raise ConfigError(file, f"{key}.params", "no params for a shape given by vertices/half-spaces", got=params)
    if isinstance(shape, dict):                        # a custom shape written under `shape:`
        kinds = list(shape)
        custom = _custom(file, f"{key}.shape", kinds[0], shape[kinds[0]])
    elif "shape" in item:
        if not isinstance(shape, str) or shape not in list_shapes():
            raise ConfigError(file, f"{key}.shape", f"a catalog shape ({', '.join(list_shapes())}) or a mapping "
                              "with one of vertices, halfspaces, parts", got=shape)
        if any(not isinstance(v, (str, int, float)) for v in params.values()):
            raise ConfigError(file, f"{key}.params", f"a name or a number for each parameter of {shape}", got=params)
        try:
            get_shape(shape, **params)
        except GeometryError as exc:
            raise ConfigError(file, f"{key}.params", f"valid parameters for {shape}", got=str(exc)) from None
    else:
        custom = _custom(file, key, given[0], item[given[0]])
    if custom is not None:
        shape = "custom"
    name = item.get("name", f"{shape}{index}")
    if not isinstance(name, str):
        raise ConfigError(file, f"{key}.name", "a string", got=name)
    return SceneObject(name=name, shape=shape, params=dict(params), size=size, position=position,
                       orientation=orientation, color=color, custom_parts=custom)


def _known_keys(file, prefix: str, mapping: dict, allowed: set[str]) -> None:
    """Refuse a key that is not in `allowed` (whatever its type), naming it."""
    unknown = sorted((k for k in mapping if k not in allowed), key=str)
    if unknown:
        raise ConfigError(file, f"{prefix}{unknown[0]}", f"one of the keys {', '.join(sorted(allowed))}")


def _color(file, key, value) -> np.ndarray:
    """RGBA in 0..1 from [r, g, b], [r, g, b, a], or a string Pillow's ImageColor reads (#rrggbb, #rrggbbaa,
    CSS names such as 'orange', rgb(...), hsl(...))."""
    if isinstance(value, str):
        try:
            rgba = ImageColor.getrgb(value.strip())
        except ValueError:
            raise ConfigError(file, key, COLOR_FORMS, got=value) from None
        color = np.array(rgba, dtype=np.float64) / 255.0
    elif isinstance(value, list) and len(value) in (3, 4):
        color = np.array([_number(file, f"{key}[{i}]", v) for i, v in enumerate(value)])
        if np.any((color < 0) | (color > 1)):
            raise ConfigError(file, key, f"{COLOR_FORMS} (list components between 0 and 1)", got=value)
    else:
        raise ConfigError(file, key, COLOR_FORMS, got=value)
    return np.r_[color, 1.0] if len(color) == 3 else color


def _custom(file, key, kind, value) -> list[np.ndarray]:
    """A custom shape (vertices, halfspaces or parts, at `key`) -> the local half-spaces of its parts."""
    if kind == "parts":
        if not isinstance(value, list) or not value:
            raise ConfigError(file, f"{key}.parts", "a non-empty list of {vertices: ...} or {halfspaces: ...}", got=value)
        return [_part(file, f"{key}.parts[{j}]", spec) for j, spec in enumerate(value)]
    return [_part(file, key, {kind: value})]


def _part(file, key, spec) -> np.ndarray:
    """One convex part given by vertices or half-spaces -> its local (K,5) half-spaces."""
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in ("vertices", "halfspaces"):
        raise ConfigError(file, key, "a mapping with one key, vertices or halfspaces", got=spec)
    kind, value = next(iter(spec.items()))
    rows = _matrix(file, f"{key}.{kind}", value, 4 if kind == "vertices" else 5)
    cache_key = (kind, rows.tobytes())
    if cache_key not in _part_cache:                 # a hull takes tens of ms: build each part once
        try:
            poly = Polytope.from_vertices(rows) if kind == "vertices" else Polytope.from_halfspaces(rows)
        except GeometryError as exc:
            raise ConfigError(file, f"{key}.{kind}", "a bounded convex 4-polytope", got=str(exc)) from None
        halfspaces = np.array(poly.halfspaces)
        halfspaces.setflags(write=False)             # shared by every scene that has this part
        _part_cache[cache_key] = halfspaces
    return _part_cache[cache_key]


def _rotation(file, key, steps) -> np.ndarray:
    if not isinstance(steps, list):
        raise ConfigError(file, key, "a list of [plane, degrees] such as [[xw, 30], [yz, 10]]", got=steps)
    for i, step in enumerate(steps):
        if not isinstance(step, list) or len(step) != 2:
            raise ConfigError(file, f"{key}[{i}]", "a pair [plane, degrees]", got=step)
        try:
            plane_axes(step[0])
        except ValueError:
            raise ConfigError(file, f"{key}[{i}]", "a plane of two axes among x, y, z, w (e.g. xw)", got=step[0]) from None
        _number(file, f"{key}[{i}]", step[1])
    return rotation_from_list(steps)
