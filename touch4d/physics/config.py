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

import msgspec

from touch4d import schema
from touch4d.geometry.physics_keys import Friction, ObjectPhysics, ScenePhysics, static_indices

__all__ = ["Friction", "ObjectPhysics", "ScenePhysics", "PhysicsConfig", "parse_physics", "load_physics"]


class PhysicsConfig(msgspec.Struct):
    """A scene file's physics: the scene's, and each object's (index as in the file)."""

    scene: ScenePhysics
    objects: list[ObjectPhysics]

    @property
    def static(self) -> list[int]:
        """The indices of the objects that never move (a floor): never the controller's either."""
        return static_indices(self.objects)


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
