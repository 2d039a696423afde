// Identity render of the clip-unit backend: the 3D screen point and the object index + 1 (carried in
// the red channel of the vertex colour), into a float target.
in vec4 v_color;
in vec3 v_position;
out vec4 f_color;
void main() {
    f_color = vec4(v_position, v_color.r);
}
