// Per body (one texel each, data-texture order): its bounding box on the 3D screen this frame, from
// its vertices, a little enlarged so that rounding never leaves a point of the body outside.
#include "scene.glsl"

uniform sampler2D t_vertices;   // every body's local vertices
uniform int u_bodies;
uniform int u_target_width;
layout(location = 0) out vec4 out_lo;
layout(location = 1) out vec4 out_hi;

void main() {
    int b = int(gl_FragCoord.y) * u_target_width + int(gl_FragCoord.x);
    out_lo = vec4(0.0);
    out_hi = vec4(0.0);
    if (b >= u_bodies) return;
    vec4 span = fetch(t_bodies, 3 * b + 2);
    Pose q = object_pose(body_object(b));
    vec3 lo = vec3(3.0e38);
    vec3 hi = vec3(-3.0e38);
    int start = int(span.x + 0.5);
    int count = int(span.y + 0.5);
    for (int k = 0; k < count; ++k) {
        vec3 u = to_view(to_world(q, fetch(t_vertices, start + k))).xyz;
        lo = min(lo, u);
        hi = max(hi, u);
    }
    vec3 pad = 1e-4 * (1.0 + max(abs(lo), abs(hi)));
    out_lo = vec4(lo - pad, 1.0);
    out_hi = vec4(hi + pad, 1.0);
}
