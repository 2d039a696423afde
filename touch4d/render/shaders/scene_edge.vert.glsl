// The bodies' edges as wide lines: one instance per edge, its quad's corners pushed out in screen
// space; every fragment carries the 4D point of the edge under it for the visibility test.
#include "scene.glsl"
#include "wide_line.glsl"

uniform mat4 u_mvp;
uniform sampler2D t_colors;
uniform float u_alpha;          // the style's edge alpha
in float in_corner;
in vec4 in_a;
in vec4 in_b;
in float in_body;
out vec3 v_screen;
out float v_depth;
out vec4 v_color;
flat out float v_object;
flat out float v_body;

void main() {
    int o = body_object(int(in_body + 0.5));
    Pose q = object_pose(o);
    vec4 a = to_view(to_world(q, in_a));
    vec4 b = to_view(to_world(q, in_b));
    vec4 here = in_corner > 1.5 ? b : a;
    vec4 c = fetch(t_colors, o);
    v_screen = here.xyz;
    v_depth = here.w;
    v_color = vec4(c.rgb, c.a * u_alpha);
    v_object = float(o);
    v_body = in_body;
    gl_Position = wide_line_corner(u_mvp * vec4(a.xyz, 1.0), u_mvp * vec4(b.xyz, 1.0), in_corner);
}
