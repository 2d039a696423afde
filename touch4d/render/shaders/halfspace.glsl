// The half-space kernel of touch4d.geometry.halfspace, per fragment: does the ray that the tactile
// model casts through screen point u (paper eq. 4-6: from (u, 0) along +w, or from the eye through
// it in perspective) enter a body before the fragment's own 4D point? That one test is back-cell
// culling, hidden-hypersurface removal and hidden-line removal, for interpenetrating bodies too.
// Only the bodies whose screen bounds can hold u are asked: those listed in u's cell of the body
// grid built each frame (grid.frag), or, for a cell listing more than fit, all whose bounds do.
#include "scene.glsl"

uniform sampler2D t_lo;           // per body: screen bounds, from bounds.frag
uniform sampler2D t_hi;
uniform sampler2D t_cells0;       // per grid cell: (count, body, body, body)
uniform sampler2D t_cells1;       // ... 4 more bodies each
uniform sampler2D t_cells2;
uniform sampler2D t_cells3;
uniform vec4 u_grid;              // (lowest corner, cell size, cells per axis, 0)
uniform int u_bodies;

// float32 tolerances (the CPU kernel works in float64 with GRAZE = 1e-9): a ray must run DEPTH_TOL
// inside a body (relative to its depth, at least in screen units) before the body hides what lies
// behind; a point within SLACK of a cell it leaves through or runs along (a fraction of the cell's
// distance from the body's centre) counts as inside, so that the faces on a body's back, whose
// points lie on such cells, are hidden by its front whatever the rounding.
// A cell whose normal is this close to orthogonal to the ray (cosine) counts as running along it:
// the ray's depth across it is not known well enough to order anything by.
const float DEPTH_TOL = 2e-4;
const float SLACK = 1e-5;
const float PARALLEL = 1e-4;
const int GRID_SLOTS = 15;

// The ray x(w) = (u, 0) + w dir, dir = (0, 0, 0, 1) or, from the eye (0, 0, 0, -d), (u / d, 1), in
// the local coordinates of one object (the bodies of an object, often asked one after the other,
// share it).
struct Ray {
    int object;
    vec4 origin;
    vec4 dir;
};

Ray ray_of(int object, vec3 u) {
    Pose q = object_pose(object);
    mat4 inv = transpose(q.r) / q.s;
    vec4 dir = u_eye > 0.0 ? vec4(u / u_eye, 1.0) : vec4(0.0, 0.0, 0.0, 1.0);
    return Ray(object, inv * (vec4(u, 0.0) - q.p), inv * dir);
}

// [enter, leave] in world depth w of the ray through u inside body b, from the screen (w = 0) on;
// false when it misses. `ray` is made for b's object if it is another's.
bool ray_body(int b, vec3 u, inout Ray ray, out float enter, out float leave) {
    vec4 span = fetch(t_bodies, 3 * b);
    vec4 m = fetch(t_bodies, 3 * b + 1);
    int object = int(span.z + 0.5);
    if (object != ray.object) ray = ray_of(object, u);
    vec4 o = ray.origin - m;
    vec4 d = ray.dir;
    enter = 0.0;
    leave = 3.0e38;
    float parallel = PARALLEL * PARALLEL * dot(d, d);
    int start = int(span.x + 0.5);
    int count = int(span.y + 0.5);
    for (int k = 0; k < count; ++k) {
        vec4 h = fetch(t_halfspaces, start + k);
        float r = 1.0 - dot(h, o);          // h.(o + w d) <= 1  <=>  w (h.d) <= r
        float s = dot(h, d);
        if (s * s <= parallel * dot(h, h)) {
            if (r < -SLACK) return false;                    // runs along it, outside
        } else if (s < 0.0) {
            enter = max(enter, r / s);                       // the ray enters through this cell
        } else {
            leave = min(leave, (r + SLACK) / s);             // ... leaves through it
        }
        if (enter > leave) return false;
    }
    return true;
}

// Whether body b hides the point at world depth w on the ray through u.
bool hides(int b, vec3 u, float w, inout Ray ray) {
    float enter, leave;
    if (!ray_body(b, u, ray, enter, leave)) return false;
    return enter + DEPTH_TOL * max(1.0, abs(w)) < min(leave, w);
}

bool inside_bounds(int b, vec3 u) {
    return all(greaterThanEqual(u, fetch(t_lo, b).xyz)) && all(lessThanEqual(u, fetch(t_hi, b).xyz));
}

// Whether the fragment at screen point u and view depth v is hidden (or lies before the screen,
// where the ray does not go); body `skip` (the fragment's own, when its cell faces the viewer, or -1)
// is not asked.
bool hidden(vec3 u, float v, int skip) {
    float w = world_depth(v);
    if (w < -DEPTH_TOL) return true;
    int n = int(u_grid.z + 0.5);
    ivec3 c = clamp(ivec3(floor((u - u_grid.x) / u_grid.y)), ivec3(0), ivec3(n - 1));
    int cell = c.x + n * (c.y + n * c.z);
    vec4 c0 = fetch(t_cells0, cell);
    int count = int(c0.x + 0.5);
    if (count == 0 || (count == 1 && int(c0.y + 0.5) == skip)) return false;   // the usual lone body
    Ray ray = Ray(-1, vec4(0.0), vec4(0.0));
    if (count <= GRID_SLOTS) {
        vec4 c1 = fetch(t_cells1, cell);
        vec4 c2 = fetch(t_cells2, cell);
        vec4 c3 = fetch(t_cells3, cell);
        float slots[GRID_SLOTS] = float[GRID_SLOTS](c0.y, c0.z, c0.w, c1.x, c1.y, c1.z, c1.w,
                                                    c2.x, c2.y, c2.z, c2.w, c3.x, c3.y, c3.z, c3.w);
        for (int k = 0; k < count; ++k) {
            int b = int(slots[k] + 0.5);
            if (b != skip && inside_bounds(b, u) && hides(b, u, w, ray)) return true;
        }
        return false;
    }
    for (int b = 0; b < u_bodies; ++b) {
        if (b != skip && inside_bounds(b, u) && hides(b, u, w, ray)) return true;
    }
    return false;
}
