// The cells' centre copies (paper §4.3): each cell's faces scaled about the cell's centroid, in the
// cell's colour (by local cell index, so a cell keeps its colour as it turns) or the object's; copies
// of cells that face away from the viewer are culled here.
#include "scene_vertex.glsl"

uniform float u_centre_scale;
uniform int u_cell_colors;
uniform vec3 u_palette[12];
in vec4 in_local;
in vec4 in_centroid;
in float in_body;
in float in_cell;

void main() {
    int b = int(in_body + 0.5);
    int o = body_object(b);
    vec4 view = to_view(to_world(object_pose(o), mix(in_centroid, in_local, u_centre_scale)));
    emit(view, b, o, u_cell_colors != 0 ? u_palette[int(in_cell + 0.5) % 12] : fetch(t_colors, o).rgb, false);
    gl_Position = u_mvp * vec4(view.xyz, 1.0);
    if (!facing(b, int(in_cell + 0.5))) gl_Position = CULLED;     // a back cell's copy
}
