// The bodies' edges as wide lines: one instance per edge, its quad's corners pushed out in screen
// space; every fragment carries the 4D point of the edge under it for the visibility test.
#include "scene_vertex.glsl"
#include "wide_line.glsl"

in float in_corner;
in vec4 in_a;
in vec4 in_b;
in float in_body;
in vec4 in_cells0;              // the cells around the edge (-1: none; -2: too many to list)
in vec4 in_cells1;

void main() {
    int body = int(in_body + 0.5);
    int o = body_object(body);
    Pose q = object_pose(o);
    vec4 a = to_view(to_world(q, in_a));
    vec4 b = to_view(to_world(q, in_b));
    // Culled unless a cell around it faces the viewer; with too many cells to list, its fragments
    // ask their own body instead.
    float cells[8] = float[8](in_cells0.x, in_cells0.y, in_cells0.z, in_cells0.w,
                              in_cells1.x, in_cells1.y, in_cells1.z, in_cells1.w);
    bool listed = cells[0] > -1.5;
    bool shown = !listed;
    for (int k = 0; k < 8; ++k) {
        if (cells[k] > -0.5 && facing(body, int(cells[k] + 0.5))) shown = true;
    }
    emit(in_corner > 1.5 ? b : a, body, o, fetch(t_colors, o).rgb, !listed);
    gl_Position = shown ? wide_line_corner(u_mvp * vec4(a.xyz, 1.0), u_mvp * vec4(b.xyz, 1.0), in_corner) : CULLED;
}
