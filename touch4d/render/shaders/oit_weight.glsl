// Weighted blended order-independent transparency (McGuire and Bavoil 2013): a fragment of opacity a
// weighs more the nearer it is (its depth from gl_FragCoord.w). Shared by every translucent layer.
float oit_weight(float a) {
    float z = 1.0 / gl_FragCoord.w;
    return a * clamp(10.0 / (1e-5 + pow(z / 5.0, 2.0) + pow(z / 200.0, 6.0)), 1e-2, 3e3);
}
