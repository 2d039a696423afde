// The tactile pass (paper eq. 4-7), one texel per glove sample (data-texture order): the sample
// placed by the hand's pose, and the distance l along its ray to the nearest body it enters, asked
// of halfspace.glsl's ray_span, the test every drawn fragment passes. Orthographic: l is that
// depth in w; perspective: the distance along the sight line (touch4d.geometry.projection.
// perspective_distance). A slice view that touches its cross-section (u_section) asks instead
// whether the sample's point of the cut at w = u_cut lies in a body (inside_at): l = 0 there, the
// strongest touch, as touch4d.geometry.section.SectionCaster answers. The desktop
// (touch4d.render.tactile) and the WebXR page (static/touch.js) both run it after the frame's bounds
// and view passes.
#include "halfspace.glsl"

uniform sampler2D t_samples;   // per sample: its point in the hand frame, screen units (x, y, z, 0)
uniform mat3 u_hand;           // the hand's orientation: hand frame -> screen
uniform vec3 u_hand_at;        // the hand's position on the screen, screen units
uniform int u_samples;
uniform bool u_section;        // the slice view's touch: the cross-section at w = u_cut, solid
uniform float u_cut;           // where the slice cuts, in w
out vec4 out_touch;            // (l, object hit, inside the screen, 0); l = -1 where nothing is touched

void main() {
    int i = (int(gl_FragCoord.y) << 10) + int(gl_FragCoord.x);
    out_touch = vec4(-1.0, -1.0, 0.0, 0.0);
    if (i >= u_samples) return;
    vec3 u = u_hand * fetch(t_samples, i).xyz + u_hand_at;
    if (any(greaterThan(abs(u), vec3(1.0)))) return;       // outside the screen cube: not in L
    out_touch.z = 1.0;
    float best = 3.0e38;
    int hit = -1;
    if (u_section) {
        // the cut's view depth: w itself, or w / (w + d) in perspective (a cut at or behind the eye
        // is seen nowhere: nothing to touch)
        if (u_eye > 0.0 && u_cut + u_eye <= 0.0) return;
        float v = u_eye > 0.0 ? u_cut / (u_cut + u_eye) : u_cut;
        for (int b = 0; b < u_bodies; ++b) {
            vec4 lo = fetch(t_lo, b);
            if (any(lessThan(u, lo.xyz)) || any(greaterThan(u, fetch(t_hi, b).xyz))) continue;
            if (inside_at(b, u, v)) {
                out_touch.xy = vec2(0.0, float(body_object(b)));
                return;
            }
        }
        return;
    }
    for (int b = 0; b < u_bodies; ++b) {
        vec4 lo = fetch(t_lo, b);
        if (any(lessThan(u, lo.xyz)) || any(greaterThan(u, fetch(t_hi, b).xyz))) continue;
        vec2 span = ray_span(b, u);
        if (span.x <= span.y && span.x < best && (u_eye <= 0.0 || span.x < 1.0)) {
            best = span.x;
            hit = body_object(b);
        }
    }
    if (hit < 0) return;
    float l = best;
    if (u_eye > 0.0) {   // v = w / (w + d) on the mapped ray: back to w, then along the sight line
        float w = best * u_eye / (1.0 - best);
        l = w / u_eye * sqrt(dot(u, u) + u_eye * u_eye);
    }
    out_touch.xy = vec2(l, float(hit));
}
