// What every scene vertex shader hands the scene fragment shader (scene.frag): the 3D screen point
// and view depth (interpolated), the colour, and flat: the object, the body, and whether the
// fragment must ask its own body too.
#include "scene.glsl"

uniform mat4 u_mvp;
uniform sampler2D t_colors;     // per object RGBA
uniform float u_alpha;          // the style's alpha for these primitives
out vec3 v_screen;
out float v_depth;
out vec4 v_color;
flat out float v_object;
flat out float v_body;
flat out float v_own;

// Sets the outputs for the view-space point `view` of body b (object o), in colour rgb with the
// object's alpha scaled by u_alpha.
void emit(vec4 view, int b, int o, vec3 rgb, bool own) {
    v_screen = view.xyz;
    v_depth = view.w;
    v_color = vec4(rgb, fetch(t_colors, o).a * u_alpha);
    v_object = float(o);
    v_body = float(b);
    v_own = own ? 1.0 : 0.0;
}
