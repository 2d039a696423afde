// Identity render of the clip-unit backend, into float targets; the object index + 1 comes in the red
// channel of the vertex colour. u_mode 2: the 3D screen point and the object; 3: one layer of the
// object, counted in channel (object mod 4) under additive blending.
uniform int u_mode;
uniform vec4 u_section;         // only screen points with u_section.xyz . u <= u_section.w
in vec4 v_color;
in vec3 v_position;
layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;
void main() {
    if (dot(u_section.xyz, v_position) > u_section.w) discard;
    int o = int(v_color.r + 0.5) - 1;
    out0 = u_mode == 3 ? vec4(equal(ivec4(o % 4), ivec4(0, 1, 2, 3))) : vec4(v_position, v_color.r);
    out1 = vec4(0.0);
}
