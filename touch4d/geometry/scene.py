"""The 4D scene: objects (a shape, size, pose, colour), the projection; YAML files and `scene/state` messages.

Scene file (YAML)::

    projection: orthographic          # or perspective, with eye_distance (screen units, default 3)
    objects:
      - name: cube                    # optional
        shape: tesseract              # a catalog name (params: {...} for its parameters), or instead
                                      # vertices: [[x,y,z,w], ...] | halfspaces: [[n1,n2,n3,n4,d], ...]
                                      # | parts: [{vertices: ...} | {halfspaces: ...}, ...] (a union)
        size: 1.0                     # scale of local coordinates; halfspaces become n.x <= d * size
        position: [0, 0, 0, 1.5]
        rotation: [[xw, 30], [yz, 10]]  # world = R_yz(10) R_xw(30) local + position
        color: [0.2, 0.6, 1.0, 1.0]   # RGB or RGBA, 0..1
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from touch4d.configfile import read_yaml, resolve_path
from touch4d.errors import ConfigError

from .polytope import GeometryError, Polytope
from .raycast import RayCaster
from .rotation import plane_axes, rotation_from_list
from .shapes import get_shape, list_shapes

DEFAULT_EYE_DISTANCE = 3.0
PALETTE = np.array([
    [0.30, 0.65, 1.00, 1.0], [1.00, 0.55, 0.20, 1.0], [0.40, 0.85, 0.40, 1.0],
    [0.90, 0.35, 0.60, 1.0], [0.95, 0.85, 0.30, 1.0], [0.60, 0.50, 0.95, 1.0],
])
OBJECT_KEYS = {"name", "shape", "params", "vertices", "halfspaces", "parts", "size", "position", "rotation", "color"}
TOP_KEYS = {"objects", "projection", "eye_distance", "description", "selected"}

_custom_cache: dict[bytes, list[Polytope]] = {}


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
    unknown = set(data) - TOP_KEYS
    if unknown:
        raise ConfigError(file, sorted(unknown)[0], f"one of the keys {', '.join(sorted(TOP_KEYS))}")
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
    unknown = set(item) - OBJECT_KEYS
    if unknown:
        raise ConfigError(file, f"{key}.{sorted(unknown)[0]}", f"one of the keys {', '.join(sorted(OBJECT_KEYS))}")
    given = [k for k in ("shape", "vertices", "halfspaces", "parts") if k in item]
    if len(given) != 1:
        raise ConfigError(file, key, "exactly one of shape, vertices, halfspaces, parts", got=given or None)
    size = _number(file, f"{key}.size", item.get("size", 1.0), positive=True)
    position = _vector(file, f"{key}.position", item.get("position", [0, 0, 0, 0]), (4,))
    color = _vector(file, f"{key}.color", item.get("color", list(PALETTE[index % len(PALETTE)])), (3, 4))
    if np.any((color < 0) | (color > 1)):
        raise ConfigError(file, f"{key}.color", "components between 0 and 1", got=color.tolist())
    if len(color) == 3:
        color = np.r_[color, 1.0]
    orientation = _rotation(file, f"{key}.rotation", item.get("rotation", []))
    params = item.get("params", {})
    if not isinstance(params, dict):
        raise ConfigError(file, f"{key}.params", "a mapping of shape parameters", got=params)
    kind = given[0]
    custom = None
    if kind == "shape":
        shape = item["shape"]
        if shape not in list_shapes():
            raise ConfigError(file, f"{key}.shape", f"a catalog shape ({', '.join(list_shapes())})", got=shape)
        try:
            get_shape(shape, **params)
        except GeometryError as exc:
            raise ConfigError(file, f"{key}.params", f"valid parameters for {shape}", got=str(exc)) from None
    else:
        if params:
            raise ConfigError(file, f"{key}.params", "no params for a shape given by vertices/half-spaces", got=params)
        shape = "custom"
        specs = item["parts"] if kind == "parts" else [{kind: item[kind]}]
        if kind == "parts" and (not isinstance(specs, list) or not specs):
            raise ConfigError(file, f"{key}.parts", "a non-empty list of {vertices: ...} or {halfspaces: ...}", got=specs)
        custom = [_part(file, f"{key}.parts[{j}]" if kind == "parts" else key, spec) for j, spec in enumerate(specs)]
    name = item.get("name", f"{shape}{index}")
    if not isinstance(name, str):
        raise ConfigError(file, f"{key}.name", "a string", got=name)
    return SceneObject(name=name, shape=shape, params=dict(params), size=size, position=position,
                       orientation=orientation, color=color, custom_parts=custom)


def _part(file, key, spec) -> np.ndarray:
    """One convex part given by vertices or half-spaces -> its local (K,5) half-spaces."""
    if not isinstance(spec, dict) or len(spec) != 1 or next(iter(spec)) not in ("vertices", "halfspaces"):
        raise ConfigError(file, key, "a mapping with one key, vertices or halfspaces", got=spec)
    kind, value = next(iter(spec.items()))
    rows = _matrix(file, f"{key}.{kind}", value, 4 if kind == "vertices" else 5)
    try:
        poly = Polytope.from_vertices(rows) if kind == "vertices" else Polytope.from_halfspaces(rows)
    except GeometryError as exc:
        raise ConfigError(file, f"{key}.{kind}", "a bounded convex 4-polytope", got=str(exc)) from None
    return poly.halfspaces


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
