// Per body (one texel each, data-texture order): its bounding box in view space this frame (screen
// point u and depth v), from its vertices, a little enlarged so that rounding never leaves a point of
// the body outside, and its centre in view space.
#include "scene.glsl"

uniform sampler2D t_vertices;   // every body's local vertices
uniform int u_bodies;
layout(location = 0) out vec4 out_lo;
layout(location = 1) out vec4 out_hi;
layout(location = 2) out vec4 out_centre;

void main() {
    int b = (int(gl_FragCoord.y) << 10) + int(gl_FragCoord.x);
    out_lo = vec4(0.0);
    out_hi = vec4(0.0);
    out_centre = vec4(0.0);
    if (b >= u_bodies) return;
    vec4 span = fetch(t_bodies, 3 * b + 2);
    Pose q = object_pose(body_object(b));
    vec4 lo = vec4(3.0e38);
    vec4 hi = vec4(-3.0e38);
    int start = int(span.x + 0.5);
    int count = int(span.y + 0.5);
    for (int k = 0; k < count; ++k) {
        vec4 x = to_view(to_world(q, fetch(t_vertices, start + k)));
        lo = min(lo, x);
        hi = max(hi, x);
    }
    vec4 pad = 1e-4 * (1.0 + max(abs(lo), abs(hi)));
    out_lo = lo - pad;
    out_hi = hi + pad;
    out_centre = to_view(to_world(q, fetch(t_bodies, 3 * b + 1)));
}
