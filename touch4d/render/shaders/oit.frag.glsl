// Resolves the order-independent transparency targets over what is drawn: the weighted mean colour,
// covering 1 - (the product of (1 - alpha)).
uniform sampler2D t_accum;
uniform sampler2D t_weight;
out vec4 f_color;

void main() {
    ivec2 p = ivec2(gl_FragCoord.xy);
    vec4 accum = texelFetch(t_accum, p, 0);
    float revealage = accum.a;
    if (revealage >= 1.0 - 1e-4) discard;
    float weight = texelFetch(t_weight, p, 0).r;
    f_color = vec4(accum.rgb / max(weight, 1e-5), 1.0 - revealage);
}
