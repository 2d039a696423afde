// Flat translucent triangles (the clip-unit backend's fills and centre copies) into the
// order-independent transparency targets, as scene.frag writes them (u_mode 1): rgb summed by weight,
// alpha multiplied (revealage); the weights summed.
#include "oit_weight.glsl"

in vec4 v_color;
in vec3 v_position;
layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;

void main() {
    float weight = oit_weight(v_color.a);
    out0 = vec4(v_color.rgb * weight, v_color.a);
    out1 = vec4(weight, 0.0, 0.0, 0.0);
}
