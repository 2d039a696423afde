#version 330
// Wide lines: each segment becomes a screen-aligned quad u_width pixels wide (core GL only draws 1 px).
layout(lines) in;
layout(triangle_strip, max_vertices = 4) out;
uniform vec2 u_viewport;
uniform float u_width;
in vec4 v_color[];
out vec4 g_color;
void main() {
    vec4 a = gl_in[0].gl_Position;
    vec4 b = gl_in[1].gl_Position;
    if (a.w <= 0.0 || b.w <= 0.0) return;
    vec2 half_vp = 0.5 * u_viewport;
    vec2 sa = a.xy / a.w * half_vp;
    vec2 sb = b.xy / b.w * half_vp;
    vec2 d = sb - sa;
    float len = length(d);
    vec2 dir = len > 1e-6 ? d / len : vec2(1.0, 0.0);
    vec2 side = vec2(-dir.y, dir.x) * (0.5 * u_width) / half_vp;
    vec2 along = dir * (0.5 * u_width) / half_vp;
    g_color = v_color[0];
    gl_Position = vec4(a.xy + (side - along) * a.w, a.zw); EmitVertex();
    gl_Position = vec4(a.xy + (-side - along) * a.w, a.zw); EmitVertex();
    g_color = v_color[1];
    gl_Position = vec4(b.xy + (side + along) * b.w, b.zw); EmitVertex();
    gl_Position = vec4(b.xy + (-side + along) * b.w, b.zw); EmitVertex();
    EndPrimitive();
}
