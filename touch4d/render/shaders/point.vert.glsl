// Round points of a per-vertex size in pixels (tactile samples, hand samples).
uniform mat4 u_mvp;
in vec3 in_position;
in vec4 in_color;
in float in_size;
out vec4 v_color;
void main() {
    gl_Position = u_mvp * vec4(in_position, 1.0);
    gl_PointSize = in_size;
    v_color = in_color;
}
