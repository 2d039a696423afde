// Flat layers: positions in the 3D screen's coordinates, one RGBA colour per vertex.
uniform mat4 u_mvp;
in vec3 in_position;
in vec4 in_color;
out vec4 v_color;
out vec3 v_position;
void main() {
    gl_Position = u_mvp * vec4(in_position, 1.0);
    v_color = in_color;
    v_position = in_position;
}
