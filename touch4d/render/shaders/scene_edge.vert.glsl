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
in vec4 in_cells0;              // the cells around the edge (-1: none; -2: too many to list)
in vec4 in_cells1;
out vec3 v_screen;
out float v_depth;
out vec4 v_color;
flat out float v_object;
flat out float v_body;
flat out float v_own;

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
    // Culled unless a cell around it faces the viewer; with too many cells to list, its fragments
    // ask their own body instead.
    float cells[8] = float[8](in_cells0.x, in_cells0.y, in_cells0.z, in_cells0.w,
                              in_cells1.x, in_cells1.y, in_cells1.z, in_cells1.w);
    bool listed = cells[0] > -1.5;
    bool shown = !listed;
    for (int k = 0; k < 8; ++k) {
        if (cells[k] > -0.5 && facing(int(in_body + 0.5), int(cells[k] + 0.5), q)) shown = true;
    }
    v_own = listed ? 0.0 : 1.0;
    gl_Position = shown ? wide_line_corner(u_mvp * vec4(a.xyz, 1.0), u_mvp * vec4(b.xyz, 1.0), in_corner) : CULLED;
}
