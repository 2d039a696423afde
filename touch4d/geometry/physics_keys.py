"""The physics keys of scene files, declared once as msgspec Structs (the scene file's `physics:` sections;
`touch4d.geometry.scene.SceneFile` holds them, `touch4d.physics` reads them; docs/physics.md).
"""
from __future__ import annotations

from typing import Annotated, Union

import msgspec

from touch4d import schema
from touch4d.schema import Finite, NonNegative, Positive

from .rotation import PLANES, plane_axes

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


def static_indices(physics: list) -> list[int]:
    """The indices of the objects whose `physics:` section (None: none) makes them static: they never
    move (a floor), and are never the controller's either."""
    return [i for i, p in enumerate(physics) if p is not None and p.static]
