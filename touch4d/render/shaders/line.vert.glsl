// Wide lines without a geometry shader: each segment is one instance, a quad u_width pixels wide
// whose four corners (in_corner 0..3, a triangle strip) are pushed out in screen space.
#include "wide_line.glsl"
uniform mat4 u_mvp;
in float in_corner;
in vec3 in_a;
in vec4 in_color_a;
in vec3 in_b;
in vec4 in_color_b;
out vec4 v_color;
out vec3 v_position;
void main() {
    bool at_b = in_corner > 1.5;
    gl_Position = wide_line_corner(u_mvp * vec4(in_a, 1.0), u_mvp * vec4(in_b, 1.0), in_corner);
    v_color = at_b ? in_color_b : in_color_a;
    v_position = at_b ? in_b : in_a;
}
