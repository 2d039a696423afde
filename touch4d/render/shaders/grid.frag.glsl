// Per cell of the body grid over the screen (one texel each, data-texture order): how many bodies'
// bounds meet the cell, and the first 15 of them. Cells on the grid's border reach to infinity, so
// a point outside the grid, clamped into a border cell, still finds every body that can hold it.
#include "data.glsl"

uniform sampler2D t_lo;
uniform sampler2D t_hi;
uniform vec4 u_grid;            // (lowest corner, cell size, cells per axis, 0)
uniform int u_bodies;
layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;
layout(location = 2) out vec4 out2;
layout(location = 3) out vec4 out3;

void main() {
    int n = int(u_grid.z + 0.5);
    int cell = (int(gl_FragCoord.y) << 10) + int(gl_FragCoord.x);
    float slots[15] = float[15](0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    int count = 0;
    if (cell < n * n * n) {
        ivec3 c = ivec3(cell % n, (cell / n) % n, cell / (n * n));
        vec3 lo = u_grid.x + vec3(c) * u_grid.y;
        vec3 hi = lo + u_grid.y;
        lo = mix(lo, vec3(-3.0e38), equal(c, ivec3(0)));
        hi = mix(hi, vec3(3.0e38), equal(c, ivec3(n - 1)));
        for (int b = 0; b < u_bodies; ++b) {
            vec3 blo = fetch(t_lo, b).xyz;
            vec3 bhi = fetch(t_hi, b).xyz;
            if (all(lessThanEqual(blo, hi)) && all(greaterThanEqual(bhi, lo))) {
                if (count < 15) slots[count] = float(b);
                count += 1;
            }
        }
    }
    out0 = vec4(float(count), slots[0], slots[1], slots[2]);
    out1 = vec4(slots[3], slots[4], slots[5], slots[6]);
    out2 = vec4(slots[7], slots[8], slots[9], slots[10]);
    out3 = vec4(slots[11], slots[12], slots[13], slots[14]);
}
