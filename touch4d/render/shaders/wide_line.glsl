// One corner of a wide line's quad: corners 0, 1 at end a, 2, 3 at end b, on either side, each
// pushed half the width sideways and half the width beyond its end (square caps), in pixels.
uniform vec2 u_viewport;
uniform float u_width;

vec4 wide_line_corner(vec4 a, vec4 b, float corner) {
    if (a.w <= 0.0 || b.w <= 0.0) return vec4(2.0, 2.0, 2.0, 1.0);     // behind the camera: clipped
    vec2 half_vp = 0.5 * u_viewport;
    vec2 d = b.xy / b.w * half_vp - a.xy / a.w * half_vp;
    float len = length(d);
    vec2 dir = len > 1e-6 ? d / len : vec2(1.0, 0.0);
    vec2 side = vec2(-dir.y, dir.x) * (0.5 * u_width) / half_vp;
    vec2 along = dir * (0.5 * u_width) / half_vp;
    bool at_b = corner > 1.5;
    float s = mod(corner, 2.0) < 0.5 ? 1.0 : -1.0;
    vec4 p = at_b ? b : a;
    vec2 offset = s * side + (at_b ? along : -along);
    return vec4(p.xy + offset * p.w, p.zw);
}
