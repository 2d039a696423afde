"""The clip-unit backend's CPU frame build (paper §4.3): back-cell culling, McIntosh's clip units
between bodies, convex pieces and vertex arrays. The paper's reference drawing, and the fallback
for GL contexts the GPU backend cannot use."""
from .builder import MeshBuilder, SceneMesh
from .place import Body

__all__ = ["Body", "MeshBuilder", "SceneMesh"]
