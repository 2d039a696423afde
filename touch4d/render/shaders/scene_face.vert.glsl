// The bodies' 2-faces (fills): local 4D vertex -> world -> 3D screen, in the object's colour; a face
// on no cell that faces the viewer is culled here.
#include "scene_vertex.glsl"

in vec4 in_local;
in float in_body;
in vec2 in_cells;               // the two cells the face lies on (local indices)

void main() {
    int b = int(in_body + 0.5);
    int o = body_object(b);
    vec4 view = to_view(to_world(object_pose(o), in_local));
    emit(view, b, o, fetch(t_colors, o).rgb, false);
    gl_Position = u_mvp * vec4(view.xyz, 1.0);
    if (!facing(b, int(in_cells.x + 0.5)) && !facing(b, int(in_cells.y + 0.5))) gl_Position = CULLED;
}
