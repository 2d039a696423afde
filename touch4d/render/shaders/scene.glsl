// The 4D scene: bodies, their objects' poses, and the projection to the 3D screen (paper §4.2).
#include "data.glsl"

uniform sampler2D t_objects;   // per frame, 6 texels per object: orientation columns 0-3, position, (size)
uniform sampler2D t_bodies;    // 3 texels per body: (half-spaces start, count, object, 0), centre m,
                               // (vertices start, count, 0, 0)
uniform sampler2D t_view;      // per frame, per half-space: the cell in view space (view.frag)
uniform float u_eye;           // perspective: the eye at w = -u_eye; orthographic: 0

// float32: a cell whose view normal is within this (cosine) of orthogonal to the sight lines is
// edge-on (touch4d.geometry.halfspace.FACING, float64: 1e-9).
const float FACING = 1e-5;

struct Pose {
    mat4 r;
    vec4 p;
    float s;
};

Pose object_pose(int o) {
    int i = 6 * o;
    Pose q;
    q.r = mat4(fetch(t_objects, i), fetch(t_objects, i + 1), fetch(t_objects, i + 2), fetch(t_objects, i + 3));
    q.p = fetch(t_objects, i + 4);
    q.s = fetch(t_objects, i + 5).x;
    return q;
}

int body_object(int b) {
    return int(fetch(t_bodies, 3 * b).z + 0.5);
}

vec4 to_world(Pose q, vec4 local) {
    return q.r * (q.s * local) + q.p;
}

// View space (touch4d.geometry.projection.perspective_points): (u, v) with u the point on the 3D
// screen and v a depth that grows along the sight line and is affine across a flat face, so the
// rasteriser interpolates it exactly; every sight line runs along v. Orthographic: v = w.
vec4 to_view(vec4 x) {
    if (u_eye > 0.0) return vec4(x.xyz * u_eye, x.w) / (x.w + u_eye);
    return x;
}

// The cell `cell` of body b in view space: h with h.(x - c) <= 1 inside, c the body's view centre.
vec4 view_cell(int b, int cell) {
    return fetch(t_view, int(fetch(t_bodies, 3 * b).x + 0.5) + cell);
}

// Whether a cell faces the viewer: sight lines enter the body through it (h_v < 0), by a margin;
// edge-on cells do not (touch4d.geometry.halfspace.facing). Back-cell culling, in the vertex
// shaders: a face on no facing cell, or the centre copy of a cell that does not face, is dropped
// before rasterising. For a convex body that is what the ray test would decide at every fragment,
// so the fragments of the faces that remain skip their own body's test (halfspace.glsl).
bool facing(int b, int cell) {
    vec4 h = view_cell(b, cell);
    return h.w < -FACING * length(h);
}

// Where a vertex goes to be culled: outside the clip volume, so its triangle is dropped.
const vec4 CULLED = vec4(2.0, 2.0, 2.0, 1.0);
