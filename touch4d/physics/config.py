"""The physics keys of scene files, declared once (msgspec Structs read with `touch4d.schema`).

Top level::

    physics:
      gravity: [0, -9.81, 0, 0]     # screen units / s^2 (the screen spans [-1, 1]^3); default none
      rate: 1000                    # internal steps per second (fixed)
      iterations: 10                # velocity passes of the contact solver per step
      position_iterations: 4        # pseudo-velocity passes that remove penetration
      margin: 0.02                  # contacts are made this far apart (speculative), screen units

Per object (every key optional; an object without `physics:` is a dynamic body of density 1)::

    physics:
      mass: 2.0                     # or density: 1.0 (mass per unit 4-volume); not both
      velocity: [0, 0, 0, 0]        # of the centre of mass, screen units / s
      angular_velocity: [[xw, 90], [yz, 30]]   # degrees per second in world planes, named as in rotation
      friction: 0.5                 # or {static: 0.6, kinetic: 0.4}; a pair uses the geometric mean
      restitution: 0.0              # 0 plastic .. 1 elastic; a pair uses the larger
      static: true                  # fixed (a floor is a large static object)
"""
from __future__ import annotations

from typing import Annotated, Union

import msgspec

from touch4d import schema
from touch4d.errors import ConfigError
from touch4d.geometry.rotation import plane_axes

Positive = Annotated[float, msgspec.Meta(gt=0)]
NonNegative = Annotated[float, msgspec.Meta(ge=0)]
Vector4 = tuple[float, float, float, float]


class Friction(msgspec.Struct, forbid_unknown_fields=True):
    """Coulomb friction: `static` while a contact sticks, `kinetic` while it slides."""

    static: NonNegative = 0.5
    kinetic: NonNegative = 0.5


class ObjectPhysics(msgspec.Struct, forbid_unknown_fields=True):
    """An object's `physics:` section."""

    mass: Union[Positive, None] = None
    density: Union[Positive, None] = None
    velocity: Vector4 = (0.0, 0.0, 0.0, 0.0)
    angular_velocity: list[tuple[str, float]] = []
    friction: Union[NonNegative, Friction] = 0.5
    restitution: Annotated[float, msgspec.Meta(ge=0, le=1)] = 0.0
    static: bool = False

    @property
    def friction_pair(self) -> tuple[float, float]:
        """(static, kinetic) coefficients."""
        if isinstance(self.friction, Friction):
            return self.friction.static, self.friction.kinetic
        return float(self.friction), float(self.friction)


class ScenePhysics(msgspec.Struct, forbid_unknown_fields=True):
    """The scene's top-level `physics:` section."""

    gravity: Vector4 = (0.0, 0.0, 0.0, 0.0)
    rate: Annotated[float, msgspec.Meta(gt=0, le=100000)] = 1000.0
    iterations: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 10
    position_iterations: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 4
    margin: Annotated[float, msgspec.Meta(ge=0)] = 0.02
    slop: Annotated[float, msgspec.Meta(ge=0)] = 0.00005


class PhysicsConfig(msgspec.Struct):
    """A scene file's physics: the scene's, and each object's (index as in the file)."""

    scene: ScenePhysics
    objects: list[ObjectPhysics]


def parse_physics(data, file=None) -> PhysicsConfig:
    """The physics of a parsed scene file (`data`); errors name the file and key (`objects[1].physics.mass`)."""
    if not isinstance(data, dict):
        raise ConfigError(file, "(top level)", "a mapping with 'objects'", got=type(data).__name__)
    scene = schema.convert(data.get("physics", {}), ScenePhysics, file, "physics")
    objects = []
    items = data.get("objects")
    for i, item in enumerate(items if isinstance(items, list) else []):
        key = f"objects[{i}].physics"
        raw = item.get("physics", {}) if isinstance(item, dict) else {}
        obj = schema.convert(raw, ObjectPhysics, file, key)
        if obj.mass is not None and obj.density is not None:
            schema.fail(file, f"{key}.mass", "mass or density, not both", got=obj.mass)
        for j, (plane, _) in enumerate(obj.angular_velocity):
            try:
                plane_axes(plane)
            except ValueError:
                schema.fail(file, f"{key}.angular_velocity[{j}]", "a plane of two axes among x, y, z, w (e.g. xw)",
                            got=plane, choices=("xy", "xz", "xw", "yz", "yw", "zw"))
        objects.append(obj)
    return PhysicsConfig(scene, objects)


def load_physics(path) -> PhysicsConfig:
    """The physics of the scene file `path` (found as every path is)."""
    from touch4d.configfile import resolve_path

    path = resolve_path(path, what="scene file")
    return parse_physics(schema.read_yaml(path, "scene file"), path)
