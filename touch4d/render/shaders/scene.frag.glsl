// Every fragment of the scene (fills, centre copies, edges) passes the ray test of halfspace.glsl,
// then is written as a colour (u_mode 0, alpha-blended), into the order-independent transparency
// targets (1: weighted blended, see oit.frag), as its screen point, object and 4D depth w (2,
// identities), or as one layer of its object in channel (object mod 4) (3, layer counts).
#include "halfspace.glsl"
#include "oit_weight.glsl"

uniform int u_mode;
uniform int u_clip;             // 0: draw what other bodies hide too (back cells stay culled)
uniform vec4 u_section;         // identities and layers: only screen points with u_section.xyz . u <= u_section.w
in vec3 v_screen;
in float v_depth;
in vec4 v_color;
flat in float v_object;
flat in float v_body;
flat in float v_own;
layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;

void main() {
    int own = int(v_body + 0.5);
    bool ask_own = v_own > 0.5;
    if (u_clip != 0 ? hidden(v_screen, v_depth, ask_own ? -1 : own)
                    : ask_own && hides(own, v_screen, v_depth, 1e-4)) discard;
    if (u_mode >= 2 && dot(u_section.xyz, v_screen) > u_section.w) discard;
    if (u_mode == 3) {
        out0 = vec4(equal(ivec4(int(v_object + 0.5) % 4), ivec4(0, 1, 2, 3)));
        out1 = vec4(0.0);
    } else if (u_mode == 2) {
        out0 = vec4(v_screen, v_object + 1.0);
        float w = u_eye > 0.0 ? v_depth * u_eye / (1.0 - v_depth) : v_depth;
        out1 = vec4(w, 0.0, 0.0, 1.0);
    } else if (u_mode == 1) {
        // Weighted blended OIT (oit_weight.glsl). out0: rgb summed, alpha multiplied (revealage);
        // out1: weights summed.
        float a = v_color.a;
        float weight = oit_weight(a);
        out0 = vec4(v_color.rgb * weight, a);
        out1 = vec4(weight, 0.0, 0.0, 0.0);
    } else {
        out0 = v_color;
        out1 = vec4(0.0);
    }
}
