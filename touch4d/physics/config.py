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
from touch4d.geometry.rotation import PLANES, plane_axes
from touch4d.schema import Finite, NonNegative, Positive

Vector4 = Annotated[tuple[Finite, Finite, Finite, Finite], msgspec.Meta(description="a list of 4 numbers")]
PlaneRate = Annotated[tuple[str, Finite], msgspec.Meta(description="a pair [plane, degrees per second] such as [xw, 90]")]


class Friction(msgspec.Struct, forbid_unknown_fields=True):
    """Coulomb friction: `static` while a contact sticks, `kinetic` while it slides."""

    static: NonNegative = 0.5
    kinetic: NonNegative = 0.5


class ObjectPhysics(msgspec.Struct, forbid_unknown_fields=True):
    """An object's `physics:` section."""

    mass: Union[Positive, None] = None
    density: Union[Positive, None] = None
    velocity: Vector4 = (0.0, 0.0, 0.0, 0.0)
    angular_velocity: list[PlaneRate] = []
    friction: Union[NonNegative, Friction] = 0.5
    restitution: Annotated[float, msgspec.Meta(ge=0, le=1, description="a number in 0..1")] = 0.0
    static: bool = False

    def __post_init__(self):
        if self.mass is not None and self.density is not None:
            raise schema.Invalid("mass or density, not both", got=self.mass, key="mass")
        for j, (plane, _) in enumerate(self.angular_velocity):
            try:
                plane_axes(plane)
            except ValueError:
                raise schema.Invalid("a plane of two axes among x, y, z, w (e.g. xw)", got=plane,
                                     key=f"angular_velocity[{j}]", choices=PLANES) from None

    @property
    def friction_pair(self) -> tuple[float, float]:
        """(static, kinetic) coefficients."""
        if isinstance(self.friction, Friction):
            return self.friction.static, self.friction.kinetic
        return float(self.friction), float(self.friction)


class ScenePhysics(msgspec.Struct, forbid_unknown_fields=True):
    """The scene's top-level `physics:` section."""

    gravity: Vector4 = (0.0, 0.0, 0.0, 0.0)
    rate: Annotated[float, msgspec.Meta(gt=0, le=100000, description="steps per second, 0..100000")] = 1000.0
    iterations: Annotated[int, msgspec.Meta(ge=1, le=1000)] = 10
    position_iterations: Annotated[int, msgspec.Meta(ge=0, le=1000)] = 4
    margin: NonNegative = 0.02
    slop: NonNegative = 0.00005


class PhysicsConfig(msgspec.Struct):
    """A scene file's physics: the scene's, and each object's (index as in the file)."""

    scene: ScenePhysics
    objects: list[ObjectPhysics]


def parse_physics(data, file=None) -> PhysicsConfig:
    """The physics of a parsed scene file (`data`, checked whole as the scene module declares it); errors name
    the file and key (`objects[1].physics.mass`)."""
    from touch4d.geometry.scene import SceneFile

    spec = schema.convert(data, SceneFile, file)
    return PhysicsConfig(spec.physics or ScenePhysics(), [o.physics or ObjectPhysics() for o in spec.objects])


def load_physics(path) -> PhysicsConfig:
    """The physics of the scene file `path` (found as every path is)."""
    from touch4d.configfile import resolve_path

    path = resolve_path(path, what="scene file")
    return parse_physics(schema.read_yaml(path, "scene file"), path)
