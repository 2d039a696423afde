// The bodies' 2-faces (fills): local 4D vertex -> world -> 3D screen, in the object's colour; a face
// on no cell that faces the viewer is culled here.
#include "scene.glsl"

uniform mat4 u_mvp;
uniform sampler2D t_colors;     // per object RGBA
uniform float u_alpha;          // the style's fill alpha
in vec4 in_local;
in float in_body;
in vec2 in_cells;               // the two cells the face lies on (local indices)
out vec3 v_screen;
out float v_depth;
out vec4 v_color;
flat out float v_object;
flat out float v_body;
flat out float v_own;           // 1: the fragment asks its own body too (edges)

void main() {
    int b = int(in_body + 0.5);
    int o = body_object(b);
    Pose q = object_pose(o);
    vec4 view = to_view(to_world(q, in_local));
    vec4 c = fetch(t_colors, o);
    v_screen = view.xyz;
    v_depth = view.w;
    v_color = vec4(c.rgb, c.a * u_alpha);
    v_object = float(o);
    v_body = in_body;
    v_own = 0.0;
    gl_Position = u_mvp * vec4(view.xyz, 1.0);
    if (!facing(b, int(in_cells.x + 0.5), q) && !facing(b, int(in_cells.y + 0.5), q)) gl_Position = CULLED;
}
