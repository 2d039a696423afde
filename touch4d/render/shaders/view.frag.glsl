// Per half-space of every body (one texel each, data-texture order): its cell in view space this
// frame, as h with h.(x - c) <= 1 inside, c the body's view centre (t_centres, from bounds.frag).
// The local cell h_l.(y - m) <= 1 of a body placed by x = R (s y) + p is the world half-space
// n.x <= k, n = R h_l / s, k = 1 + h_l.m + n.p; perspective maps it to (n_xyz, n_w d + k).x <= k
// (touch4d.geometry.projection.perspective_halfspaces).
#include "scene.glsl"

uniform sampler2D t_halfspaces;       // every body's local cells
uniform sampler2D t_halfspace_body;   // the body of each
uniform sampler2D t_centres;
uniform int u_halfspaces;
out vec4 out_h;

void main() {
    int i = (int(gl_FragCoord.y) << 10) + int(gl_FragCoord.x);
    out_h = vec4(0.0);
    if (i >= u_halfspaces) return;
    int b = int(fetch(t_halfspace_body, i).x + 0.5);
    Pose q = object_pose(body_object(b));
    vec4 h = fetch(t_halfspaces, i);
    vec4 n = q.r * h / q.s;
    float k = 1.0 + dot(h, fetch(t_bodies, 3 * b + 1)) + dot(n, q.p);
    if (u_eye > 0.0) n.w = n.w * u_eye + k;
    out_h = n / (k - dot(n, fetch(t_centres, b)));
}
