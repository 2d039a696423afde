// Every fragment of the scene (fills, centre copies, edges) passes the ray test of halfspace.glsl,
// then is written as a colour (u_mode 0, alpha-blended), into the order-independent transparency
// targets (1: weighted blended, see oit.frag), or as its screen point and object (2, identities: the screen point and object, and the 4D depth w).
#include "halfspace.glsl"

uniform int u_mode;
uniform int u_clip;             // 0: draw what other bodies hide too (back cells stay culled)
in vec3 v_screen;
in float v_depth;
in vec4 v_color;
flat in float v_object;
flat in float v_body;
layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;

void main() {
    if (u_clip != 0 ? hidden(v_screen, v_depth) : hides(int(v_body + 0.5), v_screen, world_depth(v_depth))) discard;
    if (u_mode == 2) {
        out0 = vec4(v_screen, v_object + 1.0);
        out1 = vec4(world_depth(v_depth), 0.0, 0.0, 1.0);
    } else if (u_mode == 1) {
        // Weighted blended OIT (McGuire and Bavoil 2013): nearer fragments weigh more. out0: rgb
        // summed, alpha multiplied (revealage); out1: weights summed.
        float a = v_color.a;
        float z = 1.0 / gl_FragCoord.w;
        float weight = a * clamp(10.0 / (1e-5 + pow(z / 5.0, 2.0) + pow(z / 200.0, 6.0)), 1e-2, 3e3);
        out0 = vec4(v_color.rgb * weight, a);
        out1 = vec4(weight, 0.0, 0.0, 0.0);
    } else {
        out0 = v_color;
        out1 = vec4(0.0);
    }
}
