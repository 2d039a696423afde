"""The 4D scene as the page draws it: geometry once per change of what the scene is made of, then
per frame only each object's transform (orientation, position, size), colour and the projection.
"""
from __future__ import annotations

import hashlib

import numpy as np

from touch4d.geometry.scene import Scene
from touch4d.messages import SceneState


def geometry_key(msg: SceneState) -> str:
    """A digest of what the objects are made of (shape, parameters, custom parts), not where they are."""
    digest = hashlib.blake2b(digest_size=8)
    for obj in msg.objects:
        digest.update(repr((obj.get("shape"), sorted((obj.get("params") or {}).items()))).encode())
        for part in obj.get("parts") or []:
            digest.update(np.ascontiguousarray(part, dtype=np.float64).tobytes())
        digest.update(b"|")
    return digest.hexdigest()


def geometry_arrays(scene: Scene) -> dict[str, np.ndarray]:
    """Every convex part of every object in its local, unscaled coordinates: 4D vertices, edges
    (vertex index pairs, into the concatenated vertices) and each vertex's object index."""
    vertices, edges, owner = [], [], []
    base = 0
    for index, obj in enumerate(scene.objects):
        for part in obj.local_parts():
            vertices.append(part.vertices)
            edges.append(np.asarray(part.edges) + base)
            owner.append(np.full(len(part.vertices), index))
            base += len(part.vertices)
    if not vertices:
        return {"vertices": np.zeros((0, 4), np.float32), "edges": np.zeros((0, 2), np.uint32),
                "object": np.zeros(0, np.uint32)}
    return {"vertices": np.concatenate(vertices).astype(np.float32),
            "edges": np.concatenate(edges).astype(np.uint32),
            "object": np.concatenate(owner).astype(np.uint32)}


def transform_arrays(msg: SceneState) -> dict[str, np.ndarray]:
    """Per object: orientation (4x4, row-major), position (4), size and colour: a few hundred bytes."""
    objs = msg.objects
    return {
        "orientation": np.array([o["orientation"] for o in objs], np.float32).reshape(len(objs), 4, 4),
        "position": np.array([o["position"] for o in objs], np.float32).reshape(len(objs), 4),
        "size": np.array([o["size"] for o in objs], np.float32).reshape(len(objs)),
        "color": np.array([o["color"] for o in objs], np.float32).reshape(len(objs), 4),
    }


def scene_fields(msg: SceneState) -> dict:
    """The per-frame scene values that are not arrays."""
    return {"projection": msg.projection, "eye_distance": float(msg.eye_distance),
            "selected": int(msg.selected), "revision": int(msg.revision)}
