// The cells' centre copies (paper §4.3): each cell's faces scaled about the cell's centroid, in the
// cell's colour (by local cell index, so a cell keeps its colour as it turns) or the object's; copies
// of cells that face away from the viewer are culled here.
#include "scene.glsl"

uniform mat4 u_mvp;
uniform sampler2D t_colors;
uniform float u_alpha;          // the style's centre alpha
uniform float u_centre_scale;
uniform int u_cell_colors;
uniform vec3 u_palette[12];
in vec4 in_local;
in vec4 in_centroid;
in float in_body;
in float in_cell;
out vec3 v_screen;
out float v_depth;
out vec4 v_color;
flat out float v_object;
flat out float v_body;
flat out float v_own;

void main() {
    int b = int(in_body + 0.5);
    int o = body_object(b);
    Pose q = object_pose(o);
    vec4 local = mix(in_centroid, in_local, u_centre_scale);
    vec4 view = to_view(to_world(q, local));
    vec4 c = fetch(t_colors, o);
    vec3 rgb = u_cell_colors != 0 ? u_palette[int(in_cell + 0.5) % 12] : c.rgb;
    v_screen = view.xyz;
    v_depth = view.w;
    v_color = vec4(rgb, c.a * u_alpha);
    v_object = float(o);
    v_body = in_body;
    v_own = 0.0;
    gl_Position = u_mvp * vec4(view.xyz, 1.0);
    if (!facing(b, int(in_cell + 0.5), q)) gl_Position = CULLED;     // a back cell's copy
}
