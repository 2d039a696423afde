"""The scene as plain arrays for a GPU: geometry built once per scene revision, transforms per frame.

`SceneGeometry.build(scene)` makes, for every body (a convex part of an object), its local vertices,
its 2-faces triangulated, its edges, its cells' faces with the cell centroid and index (for the
centre copies) and its local half-spaces, plus the tables that tie bodies to objects and colours.
`object_transforms(scene)` makes the only thing that changes when the scene turns: per object its
4x4 orientation, position and size. Nothing here imports a GL library: the desktop backend uploads
these arrays with moderngl, the WebXR page sends the same bytes to WebGL2. Layouts (dtype, shape,
meaning) are fixed in docs/contracts.md; `data_texture` packs records into RGBA32F texels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from touch4d.geometry.polytope import Polytope

DATA_WIDTH = 1024           # texels per row of a data texture (the shaders mask and shift by it)
OBJECT_TEXELS = 6           # per object: orientation columns 0-3, position, (size, 0, 0, 0)
BODY_TEXELS = 3             # per body: (half-space start, count, object, 0), centre, (vertex start, count, 0, 0)
GRID_SLOTS = 15             # bodies listed per grid cell; a fuller cell falls back to all bodies
GRID_MAX = 24               # grid cells per axis at most
EDGE_CELLS = 8              # cells listed around an edge (a 600-cell has 5)


@dataclass(frozen=True, eq=False)
class SceneGeometry:
    """Everything about a scene that does not change when its objects move. All float32 arrays are
    C-contiguous; `key` identifies what it was built from (parts by identity, colours by value)."""

    parts: tuple                 # per body: its local Polytope (for the clip-unit backend)
    body_object: np.ndarray      # (B,) int32: the object each body belongs to
    object_color: np.ndarray     # (O, 4) float32 RGBA 0..1
    vertices: np.ndarray         # (V, 4) float32: every body's local vertices, body after body
    halfspaces: np.ndarray       # (H, 4) float32: h with h.(x - m) <= 1 inside, m the body's centre
    halfspace_body: np.ndarray   # (H,) int32: the body of each half-space
    bodies: np.ndarray           # (B, 3, 4) float32: the body table (BODY_TEXELS texels per body)
    fills: np.ndarray            # (3T, 7) float32: triangles of the 2-faces, rows [x, y, z, w, body, a, b],
                                 #   a and b the two cells the face lies on (local indices)
    edges: np.ndarray            # (E, 17) float32: [ax, ay, az, aw, bx, by, bz, bw, body, c0 .. c7], c the
                                 #   cells around the edge (-1 pads; all -2: more than EDGE_CELLS)
    centres: np.ndarray          # (3C, 10) float32: triangles of each cell's faces,
                                 #   [x, y, z, w, cx, cy, cz, cw, body, cell] with c the cell's centroid
    grid_size: int               # cells per axis of the per-frame body grid over the screen
    key: tuple

    @property
    def n_bodies(self) -> int:
        return len(self.body_object)

    @property
    def n_halfspaces(self) -> int:
        return len(self.halfspaces)

    @property
    def n_objects(self) -> int:
        return len(self.object_color)

    @classmethod
    def build(cls, scene) -> "SceneGeometry":
        """The geometry of a `touch4d.geometry.scene.Scene` (its objects' local parts and colours)."""
        parts, owner = [], []
        for index, obj in enumerate(scene.objects):
            for part in obj.local_parts():
                parts.append(part)
                owner.append(index)
        colors = np.array([np.asarray(o.color, dtype=np.float64).reshape(4) for o in scene.objects],
                          dtype=np.float32).reshape(-1, 4)
        return cls.from_parts(parts, owner, colors, key=scene_key(scene))

    @classmethod
    def from_parts(cls, parts: list[Polytope], body_object, object_color, key=None) -> "SceneGeometry":
        """The geometry of bodies given as local polytopes, their objects and the objects' colours."""
        body_object = np.asarray(body_object, dtype=np.int32).reshape(-1)
        verts, hs, hs_body, table, fills, edges, centres = [], [], [], [], [], [], []
        v_start = h_start = 0
        for b, (part, obj) in enumerate(zip(parts, body_object)):
            t = _template(part)
            table.append([[h_start, len(t.halfspaces), obj, 0], [*t.centre], [v_start, len(t.vertices), 0, 0]])
            verts.append(t.vertices)
            hs.append(t.halfspaces)
            hs_body.append(np.full(len(t.halfspaces), b, np.int32))
            fills.append(np.insert(t.fills, 4, b, axis=1))
            edges.append(np.insert(t.edges, 8, b, axis=1))
            centres.append(np.insert(t.centres, 8, b, axis=1))
            v_start += len(t.vertices)
            h_start += len(t.halfspaces)

        def stack(items, width):
            return np.ascontiguousarray(np.concatenate(items) if items else np.zeros((0, width)), dtype=np.float32)

        n = len(parts)
        return cls(parts=tuple(parts), body_object=body_object,
                   object_color=np.ascontiguousarray(object_color, dtype=np.float32).reshape(-1, 4),
                   vertices=stack(verts, 4), halfspaces=stack(hs, 4),
                   halfspace_body=np.concatenate(hs_body) if hs_body else np.zeros(0, np.int32),
                   bodies=np.array(table, dtype=np.float32).reshape(n, BODY_TEXELS, 4),
                   fills=stack(fills, 7), edges=stack(edges, 8 + 1 + EDGE_CELLS), centres=stack(centres, 10),
                   grid_size=grid_size(n), key=key if key is not None else ("parts", tuple(map(id, parts))))

    def fits(self, scene) -> bool:
        """Whether this geometry draws `scene` (same parts and colours; poses may differ)."""
        return scene_key(scene) == self.key

    def textures(self) -> dict[str, np.ndarray]:
        """The per-revision data textures, (rows, width, 4) float32 each, by the names the shaders use."""
        body = np.zeros((len(self.halfspace_body), 4), np.float32)
        body[:, 0] = self.halfspace_body
        return {"t_vertices": data_texture(self.vertices), "t_halfspaces": data_texture(self.halfspaces),
                "t_halfspace_body": data_texture(body), "t_bodies": data_texture(self.bodies),
                "t_colors": data_texture(self.object_color)}


def scene_key(scene) -> tuple:
    """What a SceneGeometry depends on: every object's local parts (by identity: catalog and custom
    hulls are cached, so an unchanged shape is the same object) and its colour."""
    return tuple((tuple(map(id, o.local_parts())), np.asarray(o.color, dtype=np.float64).tobytes())
                 for o in scene.objects)


def object_transforms(scene) -> np.ndarray:
    """(O, OBJECT_TEXELS, 4) float32 per object: orientation R's four columns, position p, (size, 0, 0, 0);
    world = R @ (size * local) + p."""
    objects = scene.objects
    out = np.zeros((len(objects), OBJECT_TEXELS, 4), np.float32)
    if objects:
        out[:, :4] = np.stack([o.orientation for o in objects]).transpose(0, 2, 1)
        out[:, 4] = np.stack([o.position for o in objects])
        out[:, 5, 0] = [o.size for o in objects]
    return out


def data_texture(records: np.ndarray) -> np.ndarray:
    """Records of whole texels (N, k, 4) or (N, 4) as an RGBA32F data texture (rows, DATA_WIDTH, 4):
    texel i lies at column i % DATA_WIDTH, row i // DATA_WIDTH; zero padded."""
    texels = np.ascontiguousarray(records, dtype=np.float32).reshape(-1, 4)
    rows = max(1, -(-len(texels) // DATA_WIDTH))
    out = np.zeros((rows * DATA_WIDTH, 4), np.float32)
    out[:len(texels)] = texels
    return out.reshape(rows, DATA_WIDTH, 4)


def data_rows(records: np.ndarray) -> tuple[np.ndarray, int]:
    """The texels of `records` that a data texture's update must write: the whole rows they fill and
    the part of the last one (as (rows, width, 4) with width < DATA_WIDTH for a single row)."""
    texels = np.ascontiguousarray(records, dtype=np.float32).reshape(-1, 4)
    if len(texels) <= DATA_WIDTH:
        return texels.reshape(1, -1, 4), len(texels)
    return data_texture(texels), DATA_WIDTH


def grid_size(n_bodies: int) -> int:
    """Cells per axis of the body grid: about two per body across, so a fragment over one body
    tests a few bodies, not all of them."""
    return int(min(GRID_MAX, max(1, math.ceil(2 * n_bodies ** (1 / 3)))))


_TEMPLATES: dict[int, "_Template"] = {}


def _template(part: Polytope) -> "_Template":
    """The arrays of a local polytope, kept across scene revisions (shapes are cached, so a scene that
    changes its colours or adds an object reuses them)."""
    t = _TEMPLATES.get(id(part))
    if t is None or t.polytope is not part:
        if len(_TEMPLATES) > 256:
            _TEMPLATES.clear()
        t = _TEMPLATES[id(part)] = _Template(part)
    return t


class _Template:
    """One local polytope's arrays, without the body column (shared by the bodies of one shape)."""

    def __init__(self, poly: Polytope):
        self.polytope = poly            # keeps the id in the cache from being reused
        topo = poly.topology
        v = poly.vertices
        self.vertices = v
        self.centre = v.mean(axis=0)
        slack = poly.offsets - poly.normals @ self.centre          # > 0: the centre is interior
        self.halfspaces = poly.normals / slack[:, None]
        tris = [(k, f[0], f[i], f[i + 1]) for k, f in enumerate(topo.faces) for i in range(1, len(f) - 1)]
        tris = np.array(tris, dtype=np.int64).reshape(-1, 4)
        corners = tris[:, 1:].reshape(-1)
        cells = np.repeat(np.asarray(topo.face_cells)[tris[:, 0]], 3, axis=0)
        self.fills = np.concatenate([v[corners], cells], axis=1)
        cells = np.full((len(topo.edges), EDGE_CELLS), -1.0)
        face_cells = np.asarray(topo.face_cells)
        for e, faces in enumerate(topo.edge_faces):
            around = np.unique(face_cells[faces])
            if len(around) > EDGE_CELLS:
                cells[e] = -2.0                       # too many to list: the shader asks the body
            else:
                cells[e, :len(around)] = around
        self.edges = np.concatenate([v[topo.edges].reshape(-1, 8), cells], axis=1)
        rows = []
        for cell, faces in enumerate(topo.cell_faces):
            centroid = v[topo.cell_vertices[cell]].mean(axis=0)
            for f in faces:
                face = topo.faces[f]
                for i in range(1, len(face) - 1):
                    for k in (face[0], face[i], face[i + 1]):
                        rows.append([*v[k], *centroid, cell])
        self.centres = np.array(rows, dtype=np.float64).reshape(-1, 9)
