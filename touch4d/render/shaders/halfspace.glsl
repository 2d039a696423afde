// The half-space kernel of touch4d.geometry.halfspace, per fragment: does the ray that the tactile
// model casts through screen point u (paper eq. 4-6: from (u, 0) along +w, or from the eye through
// it in perspective) enter a body before the fragment's own 4D point? That one test is back-cell
// culling, hidden-hypersurface removal and hidden-line removal, for interpenetrating bodies too.
// In view space every such ray is the line (u, v), v >= 0, and a cell h.(x - c) <= 1 bounds it
// where v = (1 - h.(u - c, -c_v)) / h_v, as in halfspace.depth_bounds. Only the bodies whose screen
// bounds can hold u are asked: those listed in u's cell of the body grid built each frame
// (grid.frag), or, for a cell listing more than fit, all whose bounds do.
#include "scene.glsl"

uniform sampler2D t_lo;           // per body: bounds in view space (u, v), from bounds.frag
uniform sampler2D t_hi;
uniform sampler2D t_centres;      // per body: its centre in view space, from bounds.frag
uniform sampler2D t_cells0;       // per grid cell: (count, body, body, body)
uniform sampler2D t_cells1;       // ... 4 more bodies each
uniform sampler2D t_cells2;
uniform sampler2D t_cells3;
uniform vec4 u_grid;              // (lowest corner, cell size, cells per axis, 0)
uniform int u_bodies;

// float32 tolerances (the CPU kernel works in float64 with GRAZE = 1e-9): a ray must run DEPTH_TOL
// (in w, relative to the depth, at least in screen units) inside a body before the body hides what
// lies behind; a point within SLACK of a cell it leaves through or runs along (a fraction of the
// cell's distance from the body's centre) counts as inside, so that the faces on a body's back, whose
// points lie on such cells, are hidden by its front whatever the rounding. A cell whose normal is
// within PARALLEL (cosine) of orthogonal to the ray counts as running along it: the ray's depth
// across it is not known well enough to order anything by.
const float DEPTH_TOL = 2e-4;
const float SLACK = 1e-5;
const float PARALLEL = 1e-4;
const int GRID_SLOTS = 15;

// The ray through screen point u in body b: where it enters and leaves it in view depth v, from
// the screen (v = 0) on; (1, 0) (enter > leave) when it misses the body. The one ray test that the
// picture (`hides`) and the touch (tactile.frag: paper eq. 4-6 per hand sample) both ask.
vec2 ray_span(int b, vec3 u) {
    vec4 span = fetch(t_bodies, 3 * b);
    vec4 o = vec4(u, 0.0) - fetch(t_centres, b);
    float enter = 0.0;                          // the ray starts on the screen
    float leave = 3.0e38;
    int start = int(span.x + 0.5);
    int count = int(span.y + 0.5);
    for (int k = 0; k < count; ++k) {
        vec4 h = fetch(t_view, start + k);
        float r = 1.0 - dot(h, o);              // h.(o + v e_w) <= 1  <=>  v h_w <= r
        if (h.w * h.w <= PARALLEL * PARALLEL * dot(h, h)) {
            if (r < -SLACK) return vec2(1.0, 0.0);           // runs along it, outside
        } else if (h.w < 0.0) {
            enter = max(enter, r / h.w);                     // the ray enters through this cell
        } else {
            leave = min(leave, (r + SLACK) / h.w);           // ... leaves through it
        }
        if (enter > leave) return vec2(1.0, 0.0);
    }
    return vec2(enter, leave);
}

// Whether the point at view depth v on the ray through u lies in body b: the slice view's touch
// (tactile.frag), a point of the cross-section at v. The cells of ray_span, tested at one depth.
bool inside_at(int b, vec3 u, float v) {
    vec4 span = fetch(t_bodies, 3 * b);
    vec4 o = vec4(u, v) - fetch(t_centres, b);
    int start = int(span.x + 0.5);
    int count = int(span.y + 0.5);
    for (int k = 0; k < count; ++k) {
        if (dot(fetch(t_view, start + k), o) > 1.0 + SLACK) return false;
    }
    return true;
}

// Whether body b hides the point at view depth v on the ray through u (tolerance `tol` in v).
bool hides(int b, vec3 u, float v, float tol) {
    vec2 span = ray_span(b, u);
    return span.x + tol < min(span.y, v);
}

// Whether body b can hide the point (u, v): u lies within its screen bounds and the body begins
// before depth v.
bool may_hide(int b, vec3 u, float v) {
    vec4 lo = fetch(t_lo, b);
    return lo.w < v && all(greaterThanEqual(u, lo.xyz)) && all(lessThanEqual(u, fetch(t_hi, b).xyz));
}

// Whether the fragment at screen point u and view depth v is hidden (or lies before the screen,
// where the ray does not go); body `skip` (the fragment's own, when its cell faces the viewer, or -1)
// is not asked.
bool hidden(vec3 u, float v, int skip) {
    float w = u_eye > 0.0 ? v * u_eye / (1.0 - v) : v;
    // DEPTH_TOL in w, as a depth v: dv/dw = d / (w + d)^2 = (1 - v)^2 / d in perspective.
    float tol = DEPTH_TOL * max(1.0, abs(w)) * (u_eye > 0.0 ? (1.0 - v) * (1.0 - v) / u_eye : 1.0);
    if (v < -tol) return true;
    int n = int(u_grid.z + 0.5);
    ivec3 c = clamp(ivec3(floor((u - u_grid.x) / u_grid.y)), ivec3(0), ivec3(n - 1));
    int cell = c.x + n * (c.y + n * c.z);
    vec4 c0 = fetch(t_cells0, cell);
    int count = int(c0.x + 0.5);
    if (count == 0 || (count == 1 && int(c0.y + 0.5) == skip)) return false;   // the usual lone body
    if (count <= GRID_SLOTS) {
        // The cell's bodies, four to a texel after the count: (count, b0, b1, b2), (b3 .. b6), ...
        vec4 slots = c0;
        for (int k = 0; k < count; ++k) {
            int j = (k + 1) & 3;
            if (j == 0) slots = k < 4 ? fetch(t_cells1, cell) : k < 8 ? fetch(t_cells2, cell) : fetch(t_cells3, cell);
            int b = int((j == 0 ? slots.x : j == 1 ? slots.y : j == 2 ? slots.z : slots.w) + 0.5);
            if (b != skip && may_hide(b, u, v) && hides(b, u, v, tol)) return true;
        }
        return false;
    }
    for (int b = 0; b < u_bodies; ++b) {
        if (b != skip && may_hide(b, u, v) && hides(b, u, v, tol)) return true;
    }
    return false;
}
