"""Orbit camera around the 3D screen: yaw/pitch/distance about a target, perspective or orthographic."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from touch4d.errors import ConfigError


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray) -> np.ndarray:
    """World -> camera 4x4 matrix (right-handed, camera looks along -z)."""
    f = target - eye
    f = f / np.linalg.norm(f)
    s = np.cross(f, up)
    if np.linalg.norm(s) < 1e-9:  # looking straight up or down: any perpendicular will do
        s = np.cross(f, [0.0, 0.0, 1.0])
    s = s / np.linalg.norm(s)
    u = np.cross(s, f)
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = s, u, -f
    m[:3, 3] = -m[:3, :3] @ eye
    return m


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    t = 1.0 / math.tan(math.radians(fov_y_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = t / aspect, t
    m[2, 2] = (far + near) / (near - far)
    m[2, 3] = 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def orthographic(half_height: float, aspect: float, near: float, far: float) -> np.ndarray:
    m = np.eye(4)
    m[0, 0] = 1.0 / (half_height * aspect)
    m[1, 1] = 1.0 / half_height
    m[2, 2] = -2.0 / (far - near)
    m[2, 3] = -(far + near) / (far - near)
    return m


@dataclass
class OrbitCamera:
    """Orbits `target`: yaw about +y (0 = looking from +z), pitch up from the xz plane, degrees.

    `ortho` uses a parallel projection whose view height matches what the perspective camera sees
    at the target, so switching keeps the framing.
    """

    yaw: float = 28.0
    pitch: float = 18.0
    distance: float = 6.4
    target: np.ndarray = field(default_factory=lambda: np.array([-0.55, 0.0, 0.0]))
    fov: float = 40.0
    ortho: bool = False

    PITCH_LIMIT = 89.0

    @property
    def eye(self) -> np.ndarray:
        yaw, pitch = math.radians(self.yaw), math.radians(self.pitch)
        offset = np.array([math.sin(yaw) * math.cos(pitch), math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        return np.asarray(self.target, dtype=float) + self.distance * offset

    def view(self) -> np.ndarray:
        return look_at(self.eye, np.asarray(self.target, dtype=float), np.array([0.0, 1.0, 0.0]))

    def projection(self, aspect: float) -> np.ndarray:
        near, far = 0.05, self.distance + 20.0
        if self.ortho:
            half = self.distance * math.tan(math.radians(self.fov) / 2)
            return orthographic(half, aspect, near, far)
        return perspective(self.fov, aspect, near, far)

    def matrix(self, size: tuple[int, int]) -> np.ndarray:
        """World -> clip space for a frame of `size` (width, height) pixels."""
        return self.projection(size[0] / size[1]) @ self.view()

    def to_pixels(self, points: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(N,3) world points -> (N,2) pixel coordinates (x right, y down, row 0 at the top)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        clip = np.c_[pts, np.ones(len(pts))] @ self.matrix(size).T
        ndc = clip[:, :2] / clip[:, 3:4]
        return np.c_[(ndc[:, 0] + 1) * 0.5 * size[0], (1 - ndc[:, 1]) * 0.5 * size[1]]

    def orbit(self, dx_pixels: float, dy_pixels: float, degrees_per_pixel: float = 0.3) -> None:
        """Mouse drag: turn around the target."""
        self.yaw -= dx_pixels * degrees_per_pixel
        self.pitch = float(np.clip(self.pitch + dy_pixels * degrees_per_pixel, -self.PITCH_LIMIT, self.PITCH_LIMIT))

    def zoom(self, steps: float, factor: float = 0.9) -> None:
        """Scroll: move closer (positive steps) or farther."""
        self.distance = float(np.clip(self.distance * factor ** steps, 1.0, 100.0))


CAMERA_KEYS = ("yaw", "pitch", "distance", "fov", "target", "ortho")


def parse_camera(text: str, base: OrbitCamera | None = None, source: str = "--camera") -> OrbitCamera:
    """Camera from 'yaw=30,pitch=20,distance=6,fov=40,target=-0.5:0:0,ortho' (any subset); errors
    name `source` (the option or parameter the text came from)."""
    camera = replace(base) if base is not None else OrbitCamera()
    for item in filter(None, (part.strip() for part in text.split(","))):
        key, _, value = item.partition("=")
        key = key.strip()
        try:
            if key == "ortho" and not value:
                camera.ortho = True
            elif key == "ortho":
                camera.ortho = value.strip().lower() in ("1", "true", "yes", "on")
            elif key == "target":
                target = np.array([float(v) for v in value.split(":")])
                if target.shape != (3,):
                    raise ValueError
                camera.target = target
            elif key in ("yaw", "pitch", "distance", "fov"):
                setattr(camera, key, float(value))
            else:
                raise ConfigError(source, key, f"one of {', '.join(CAMERA_KEYS)}", got=item)
        except ValueError:
            raise ConfigError(source, key, "a number (target: x:y:z)", got=value) from None
    if camera.distance <= 0 or not 1 <= camera.fov <= 170:
        raise ConfigError(source, "distance/fov", "distance > 0 and 1 <= fov <= 170",
                          got=(camera.distance, camera.fov))
    return camera
