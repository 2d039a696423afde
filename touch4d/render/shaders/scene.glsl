// The 4D scene: bodies, their objects' poses, and the projection to the 3D screen (paper §4.2).
#include "data.glsl"

uniform sampler2D t_objects;   // per frame, 6 texels per object: orientation columns 0-3, position, (size)
uniform sampler2D t_bodies;    // 3 texels per body: (half-spaces start, count, vertices start, count),
                               // centre m, (object, 0, 0, 0)
uniform float u_eye;           // perspective: the eye at w = -u_eye; orthographic: 0

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
    return int(fetch(t_bodies, 3 * b + 2).x + 0.5);
}

vec4 to_world(Pose q, vec4 local) {
    return q.r * (q.s * local) + q.p;
}

// View space (touch4d.geometry.projection.perspective_points): (u, v) with u the point on the 3D
// screen and v a depth that grows along the sight line and is affine across a flat face, so the
// rasteriser interpolates it exactly; orthographic: v = w.
vec4 to_view(vec4 x) {
    if (u_eye > 0.0) return vec4(x.xyz * u_eye, x.w) / (x.w + u_eye);
    return x;
}

// The world depth w of view depth v (inverse of to_view along a sight line).
float world_depth(float v) {
    return u_eye > 0.0 ? v * u_eye / (1.0 - v) : v;
}
