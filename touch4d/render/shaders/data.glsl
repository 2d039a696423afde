// Data textures (touch4d.render.scene_geometry.data_texture): RGBA32F, 1024 texels wide, texel i at
// column i % 1024, row i / 1024 (a mask and a shift: integer division is slow on software GPUs).
vec4 fetch(sampler2D t, int i) {
    return texelFetch(t, ivec2(i & 1023, i >> 10), 0);
}
