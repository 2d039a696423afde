// Data textures (touch4d.render.scene_geometry.data_texture): RGBA32F, texel i at column i % width,
// row i / width.
vec4 fetch(sampler2D t, int i) {
    int w = textureSize(t, 0).x;
    return texelFetch(t, ivec2(i % w, i / w), 0);
}
