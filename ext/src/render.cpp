// pointviz — the tile renderer: primary rays, shading, shadow rays, reflections.
//
// Each tile runs as a small wavefront: all its rays are intersected as one batch, shaded, and
// their shadow and reflection rays traced as further batches. A batch interface is what lets a
// geometry backend behind a Python callback (embreex meshes) share this exact shading code.
#include "pointviz/render.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <ctime>

#include "pointviz/parallel.h"
#include "pointviz/shading_lanes.h"
#include "pointviz/shading_math.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(POINTVIZ_NO_SIMD)
#include <immintrin.h>
#endif

namespace pointviz {
namespace {

constexpr float kPi = 3.14159265358979f;
/// R2 low-discrepancy sequence constants (Roberts 2018): well-stratified for any sample count.
constexpr double kR2a = 0.7548776662466927, kR2b = 0.5698402909980532;
/// Smallest offset for rays leaving a surface, relative to the scene's size: keeps offsets
/// above float rounding where neither a disk radius nor a footprint is available.
constexpr float kMinOffsetRel = 1e-5f;

/// Margin on an object's bounds (relative to their radius) when deciding which rays can reach
/// it: the queries test the same bounds in the tree's own frame, rounded differently.
constexpr float kBoundsMargin = 1e-4f;

/// A sphere around what a ray can hit in one object.
struct Reach {
    Vec3 c;
    float r = 0.f, r2 = 0.f;   ///< radius, squared radius
    bool known = false;   ///< false: unknown, every ray may hit
};

/// Whether the segment [tmin, tmax] of the ray o + t d (unit d) comes within the sphere: no
/// division, no square root (rays that start inside it, a surface's shadow rays, pass at once).
inline bool meets(const Reach &s, Vec3 o, Vec3 d, float tmin, float tmax) {
    const Vec3 oc = s.c - o;
    const float c2 = length2(oc);
    if (c2 <= s.r2) return true;
    const float tca = dot(oc, d);   // parameter of the point nearest to the centre
    if (c2 - tca * tca > s.r2) return false;
    // the ray meets the sphere around tca; the segment reaches it unless it ends before or
    // starts after the sphere: compare squared distances of its ends from the nearest point
    const float lo = tca - tmax, hi = tmin - tca;   // > 0: the segment ends before / starts after
    const float h2 = s.r2 - (c2 - tca * tca);       // squared half-chord
    if (lo > 0.f && lo * lo > h2) return false;
    if (hi > 0.f && hi * hi > h2) return false;
    return true;
}

/// A vector in double precision: the tile tests bound float quantities from outside.
struct D3 {
    double x, y, z;
    D3(double a, double b, double c) : x(a), y(b), z(c) {}
    explicit D3(Vec3 v) : x(v.x), y(v.y), z(v.z) {}
    D3 operator+(D3 o) const { return {x + o.x, y + o.y, z + o.z}; }
    D3 operator-(D3 o) const { return {x - o.x, y - o.y, z - o.z}; }
    D3 operator*(double s) const { return {x * s, y * s, z * s}; }
    double dot(D3 o) const { return x * o.x + y * o.y + z * o.z; }
    double norm() const { return std::sqrt(dot(*this)); }
    D3 cross(D3 o) const { return {y * o.z - z * o.y, z * o.x - x * o.z, x * o.y - y * o.x}; }
};

/// Distance from the origin to the segment [a, b] of the plane.
inline double segment_distance(double ax, double ay, double bx, double by) {
    const double ex = bx - ax, ey = by - ay, e2 = ex * ex + ey * ey;
    const double s = e2 > 0.0 ? std::clamp(-(ax * ex + ay * ey) / e2, 0.0, 1.0) : 0.0;
    return std::hypot(ax + ex * s, ay + ey * s);
}

/// What every camera sample of a tile sees, when it is proven to be one thing.
enum class TileView {
    Mixed,    ///< not proven: the samples take the general path
    Miss,     ///< every sample misses every object's bounds and the ground
    Faded,    ///< every sample misses every object's bounds and meets the ground beyond its fade
};

/// A clock in nanoseconds: CLOCK_THREAD_CPUTIME_ID (the calling thread's CPU time: a system
/// call, about a microsecond) or CLOCK_MONOTONIC (read in user space, tens of nanoseconds).
inline uint64_t clock_ns(clockid_t id) {
    timespec ts;
    clock_gettime(id, &ts);
    return uint64_t(ts.tv_sec) * 1000000000ull + uint64_t(ts.tv_nsec);
}

/// The phases of RenderStats::ns, in PhaseTimes order.
enum Phase { kPrimary, kReflection, kShadow, kShading, kTile, kPhases };

/// Phase times of one worker (RenderSettings::phase_times). A phase's length is read on the
/// monotonic clock, cheap enough for several reads per tile; the thread's CPU time is read once
/// per tile, and each tile's phases are scaled by CPU time over elapsed time since the previous
/// read, so that time the worker spent preempted (a shared machine) is not counted. Reading the
/// CPU clock at every phase boundary instead (8 reads a tile with one bounce, ~0.8 us each) cost
/// up to 4 ms of a 480x360 frame, inside the phases it timed.
class PhaseClock {
public:
    explicit PhaseClock(bool on) : on_(on) {}
    /// Starts a tile: the time since the last read belongs to no phase.
    void start_tile() {
        if (!on_) return;
        if (cpu_mark_ == 0) {
            cpu_mark_ = clock_ns(CLOCK_THREAD_CPUTIME_ID);
            wall_mark_ = clock_ns(CLOCK_MONOTONIC);
        }
        last_ = clock_ns(CLOCK_MONOTONIC);
    }
    /// The time since the previous read goes to phase `p`.
    void lap(Phase p) {
        if (!on_) return;
        const uint64_t now = clock_ns(CLOCK_MONOTONIC);
        phase_[p] += now - last_;
        last_ = now;
    }
    /// Ends a tile: its phases, scaled to CPU time, go to `out`.
    void end_tile(PhaseTimes &out) {
        if (!on_) return;
        const uint64_t cpu = clock_ns(CLOCK_THREAD_CPUTIME_ID), wall = clock_ns(CLOCK_MONOTONIC);
        const double scale = wall > wall_mark_ ? double(cpu - cpu_mark_) / double(wall - wall_mark_) : 0.0;
        std::atomic<uint64_t> *dst[kPhases] = {&out.primary, &out.reflection, &out.shadow,
                                               &out.shading, &out.tile};
        for (int p = 0; p < kPhases; ++p) {
            *dst[p] += uint64_t(double(phase_[p]) * std::min(scale, 1.0));
            phase_[p] = 0;
        }
        cpu_mark_ = cpu;
        wall_mark_ = wall;
    }

private:
    bool on_;
    uint64_t cpu_mark_ = 0, wall_mark_ = 0, last_ = 0;
    uint64_t phase_[kPhases] = {};
};

/// A counter-based random number: depends only on its key, never on thread scheduling.
inline float rand01(uint64_t seed, uint64_t pixel, uint32_t sample, uint32_t dim) {
    uint64_t z = seed * 0x9E3779B97F4A7C15ull ^ (pixel * 0xBF58476D1CE4E5B9ull) ^
                 (uint64_t(sample) << 32 | dim) * 0x94D049BB133111EBull;
    z ^= z >> 30;
    z *= 0xBF58476D1CE4E5B9ull;
    z ^= z >> 27;
    z *= 0x94D049BB133111EBull;
    z ^= z >> 31;
    return float(z >> 40) * (1.f / 16777216.f);
}

/// Fractional part of a non-negative x below 2^63: the same value as std::fmod(x, 1.0) (both
/// are exact: x - floor(x) subtracts an integer that shares x's exponent range), without a
/// library call (truncation is floor for x >= 0; the baseline instruction set has no rounding
/// instruction, so std::floor is a call into libm).
inline double frac(double x) { return x - double(int64_t(x)); }

/// Point j of the R2 sequence, shifted per pixel and dimension pair (Cranley–Patterson): the
/// samples of one pixel stay stratified over the square whatever their number.
inline void r2_point(uint64_t seed, uint64_t pixel, uint32_t j, uint32_t dim, float &u1, float &u2) {
    float s1 = rand01(seed, pixel, 0, dim), s2 = rand01(seed, pixel, 0, dim + 1);
    u1 = float(frac(kR2a * double(j) + double(s1)));
    u2 = float(frac(kR2b * double(j) + double(s2)));
}

/// Random-number dimensions used by one bounce: lights take two each from kDimLights, the
/// glossy lobe two at kDimGloss, sky-visibility rays two at kDimOcclusion.
constexpr uint32_t kDimsPerBounce = 64, kDimLights = 2, kDimGloss = 46, kDimOcclusion = 48;
/// Lights beyond this many share random dimensions with the glossy lobe (still unbiased).
constexpr uint32_t kMaxStratifiedLights = (kDimGloss - kDimLights) / 2;

/// Footprint growth of a shadow ray toward `L` from a point `dist` away (inf: directional), the
/// ray's width at its origin being `width0` (the pixel's footprint there). A directional light's
/// rays are parallel but for its angular diameter, which blurs a shadow edge over that angle:
/// occluder detail finer than it is not seen. Toward a point or area light the beam converges
/// from the pixel's footprint at the origin to the light's size at the light (a hard point
/// light: to a point), so the width is width0 + t (size - width0) / dist, never negative on
/// the ray's length.
inline float shadow_spread(const Light &L, float dist, float width0) {
    if (L.type == LightType::Directional) return 2.f * L.angle;
    if (!(dist > 0.f && dist < kInf)) return 0.f;
    const float size = L.type == LightType::Area ? std::sqrt(length(cross(L.edge_u, L.edge_v)))
                                                 : 2.f * L.radius;
    return (size - width0) / dist;
}

inline float srgb_to_linear(float c) {
    return c <= 0.04045f ? c / 12.92f : std::pow((c + 0.055f) / 1.055f, 2.4f);
}
inline Vec3 srgb_to_linear(Vec3 c) { return {srgb_to_linear(c.x), srgb_to_linear(c.y), srgb_to_linear(c.z)}; }

/// An orthonormal basis (t, b) of the plane normal to a unit vector (make_basis).
struct Basis {
    Vec3 t, b;
};
inline Basis basis_of(Vec3 n) {
    Basis out;
    make_basis(n, out.t, out.b);
    return out;
}

/// Whether two vectors are the same bits (not only equal: 0 and -0 differ).
inline bool same_bits(Vec3 a, Vec3 b) {
    uint32_t ua[3], ub[3];
    std::memcpy(ua, &a, sizeof ua);
    std::memcpy(ub, &b, sizeof ub);
    return ua[0] == ub[0] && ua[1] == ub[1] && ua[2] == ub[2];
}

/// The last value of `F`, kept with its argument: runs of one argument (the ground's normal on
/// most pixels of a view, the one colour of an uncoloured cloud) pay for one call. Arguments are
/// compared bit for bit, so every result is F's own.
template <class T, T (*F)(Vec3)>
class LastValue {
public:
    const T &of(Vec3 v) {
        if (!valid_ || !same_bits(v, key_)) {
            key_ = v;
            value_ = F(v);
            valid_ = true;
        }
        return value_;
    }

private:
    Vec3 key_;
    T value_{};
    bool valid_ = false;
};

/// Cosine-weighted direction in the hemisphere around unit `n`, `t`, `b` its basis (make_basis).
inline Vec3 sample_cosine(Vec3 n, Vec3 t, Vec3 b, float u1, float u2) {
    float r = std::sqrt(u1), c, s;
    turn_sincos(u2, c, s);
    return normalize(t * (r * c) + b * (r * s) + n * std::sqrt(std::max(0.f, 1.f - u1)));
}

inline Vec3 clamp01(Vec3 c) {
    return {std::clamp(c.x, 0.f, 1.f), std::clamp(c.y, 0.f, 1.f), std::clamp(c.z, 0.f, 1.f)};
}

/// A cone of directions: its unit axis, the axis's basis (make_basis) and the cosine of its
/// half-angle; a directional light's is found once per tile renderer.
struct Cone {
    Vec3 axis, t, b;
    float cos_max;
    Cone(Vec3 a, float angle) : axis(a), cos_max(std::cos(angle)) { make_basis(a, t, b); }
};

/// Uniform direction in the cone `c`.
inline Vec3 sample_cone(const Cone &c, float u1, float u2) {
    float cz = 1.f - u1 * (1.f - c.cos_max);
    float sz = std::sqrt(std::max(0.f, 1.f - cz * cz));
    float cs, sn;
    turn_sincos(u2, cs, sn);
    return normalize(c.t * (sz * cs) + c.b * (sz * sn) + c.axis * cz);
}
/// Uniform direction in the cone of half-angle `angle` around unit `axis`.
inline Vec3 sample_cone(Vec3 axis, float angle, float u1, float u2) {
    return sample_cone(Cone(axis, angle), u1, u2);
}

/// One path vertex waiting to be intersected.
struct PathRay {
    Ray ray;
    Vec3 weight;       ///< throughput, including 1/spp
    uint32_t pixel;    ///< index within the tile
    uint32_t sample;
    bool albedo = true;   ///< still adds to the albedo guide (camera rays and sharp mirror paths)
};

/// A shadow (or sky-visibility) ray and what it adds if nothing blocks it.
struct ShadowRay {
    Ray ray;
    Vec3 add;
    uint32_t pixel;
    bool ground_blocks;   ///< false for sky-visibility rays: the ground is part of the sky model
    RayKind kind;         ///< Shadow (toward a light) or Sky (sky visibility)
    /// false: no object lies within the ray's length of its origin (nor does the ground block
    /// it), so it is not blocked and `ray` is not even set.
    bool may_hit = true;
};

struct Nearest {
    SurfaceHit hit;
    int object;   ///< -1 miss, -2 ground, else object index
};

// ---- the faded ground's distances, a row at a time ----------------------------------------
//
// CameraModel::direction_at and intersect()'s expressions per pixel: each lane's operations are
// the scalar ones, in the same order (IEEE single precision, correctly rounded whatever the
// vector width; no fused multiply-add: -ffp-contract=off and no FMA instructions), so the values
// are the same bits. The vector versions compute both sides of normalize()'s `l > 0` and select
// (the scalar loop's branch kept the compiler from vectorising it: a division by a zero length
// must not be executed speculatively under the default trapping-math rules).

/// One pixel: the portable expression, and the tail of the vector loops.
inline float ground_distance(float sx, float py, float h, Vec3 f, Vec3 r, Vec3 u, Vec3 gn) {
    // forward + right * sx + up * py, component by component
    const float ax = (f.x + r.x * sx) + u.x * py;
    const float ay = (f.y + r.y * sx) + u.y * py;
    const float az = (f.z + r.z * sx) + u.z * py;
    const float l = std::sqrt((ax * ax + ay * ay) + az * az);
    const float inv = 1.f / l;
    const float dx = l > 0.f ? ax * inv : ax, dy = l > 0.f ? ay * inv : ay, dz = l > 0.f ? az * inv : az;
    return h / ((dx * gn.x + dy * gn.y) + dz * gn.z);
}

#if defined(__x86_64__) && defined(__GNUC__) && !defined(POINTVIZ_NO_SIMD)
#define POINTVIZ_GROUND_SIMD 1

/// Four pixels a step (SSE2: every x86-64 CPU); returns how many were done.
int ground_distances_sse2(const float *px, int n, float py, float h, Vec3 f, Vec3 r, Vec3 u,
                          Vec3 gn, float *t) {
    // the row's constants: f + u * py is not one of the expressions (the sums go f + r sx first)
    const __m128 fx = _mm_set1_ps(f.x), fy = _mm_set1_ps(f.y), fz = _mm_set1_ps(f.z);
    const __m128 rx = _mm_set1_ps(r.x), ry = _mm_set1_ps(r.y), rz = _mm_set1_ps(r.z);
    const __m128 uyx = _mm_set1_ps(u.x * py), uyy = _mm_set1_ps(u.y * py), uyz = _mm_set1_ps(u.z * py);
    const __m128 gx = _mm_set1_ps(gn.x), gy = _mm_set1_ps(gn.y), gz = _mm_set1_ps(gn.z);
    const __m128 hh = _mm_set1_ps(h), one = _mm_set1_ps(1.f), zero = _mm_setzero_ps();
    int i = 0;
    for (; i + 4 <= n; i += 4) {
        const __m128 sx = _mm_loadu_ps(px + i);
        const __m128 ax = _mm_add_ps(_mm_add_ps(fx, _mm_mul_ps(rx, sx)), uyx);
        const __m128 ay = _mm_add_ps(_mm_add_ps(fy, _mm_mul_ps(ry, sx)), uyy);
        const __m128 az = _mm_add_ps(_mm_add_ps(fz, _mm_mul_ps(rz, sx)), uyz);
        const __m128 l = _mm_sqrt_ps(_mm_add_ps(_mm_add_ps(_mm_mul_ps(ax, ax), _mm_mul_ps(ay, ay)),
                                                _mm_mul_ps(az, az)));
        const __m128 inv = _mm_div_ps(one, l);
        const __m128 pos = _mm_cmpgt_ps(l, zero);
        const __m128 dx = _mm_or_ps(_mm_and_ps(pos, _mm_mul_ps(ax, inv)), _mm_andnot_ps(pos, ax));
        const __m128 dy = _mm_or_ps(_mm_and_ps(pos, _mm_mul_ps(ay, inv)), _mm_andnot_ps(pos, ay));
        const __m128 dz = _mm_or_ps(_mm_and_ps(pos, _mm_mul_ps(az, inv)), _mm_andnot_ps(pos, az));
        const __m128 den = _mm_add_ps(_mm_add_ps(_mm_mul_ps(dx, gx), _mm_mul_ps(dy, gy)), _mm_mul_ps(dz, gz));
        _mm_storeu_ps(t + i, _mm_div_ps(hh, den));
    }
    return i;
}

#endif

/// ground_distance for the pixel centres px[i], i < n, of the row at py.
void ground_distances_row(const float *px, int n, float py, float h, Vec3 f, Vec3 r, Vec3 u,
                          Vec3 gn, float *t) {
    int i = 0;
#ifdef POINTVIZ_GROUND_SIMD
    i = ground_distances_sse2(px, n, py, h, f, r, u, gn, t);
#endif
    for (; i < n; ++i) t[i] = ground_distance(px[i], py, h, f, r, u, gn);
}

class TileRenderer {
public:
    TileRenderer(const RenderScene &s, const CameraModel &c, const RenderSettings &st,
                 float scale, RenderStats &stats)
        : scene_(s), cam_(c), set_(st), min_offset_(kMinOffsetRel * scale), stats_(stats),
          clock_(st.phase_times) {
        for (const auto &o : s.objects) {
            Box b;
            Reach reach;
            if (o.geometry->bounds(b)) {   // the sphere around the box, grown by the margin
                const float half = 0.5f * length(b.hi - b.lo);
                const float r = half * (1.f + kBoundsMargin) + min_offset_;
                reach = {(b.lo + b.hi) * 0.5f, r, r * r, true};
            }
            reach_.push_back(reach);
        }
        make_basis(s.ground_normal, ground_t_, ground_b_);
        // Squared distance beyond which the ground fade is 1 whatever the rounding: twice the
        // fade distance, with a margin far above float error (sqrt and division are correctly
        // rounded, so d >= 2.0001 fade gives d / fade - 1 >= 1 and a smoothstep of exactly 1).
        const float fade_end = 2.0001f * s.sky.ground_fade;
        fade_end2_ = s.sky.ground_fade > 0.f ? fade_end * fade_end : kInf;
        for (const Light &L : s.lights) light_cones_.emplace_back(L.direction, L.angle);
        // a tile can be proven to show only background only when every object's bounds are known
        background_possible_ = std::all_of(reach_.begin(), reach_.end(), [](const Reach &r) { return r.known; });
    }

    void render_tile(int x0, int y0, int x1, int y1, FrameBuffers &out) {
        clock_.start_tile();
        const int tw = x1 - x0, th = y1 - y0, npix = tw * th;
        const int spp = std::max(1, set_.spp);
        const bool jitter = (set_.sequence_spp ? set_.sequence_spp : uint32_t(spp)) > 1;
        if (set_.background_shortcut) {
            const TileView view = classify_tile(x0, y0, x1, y1);
            if (view != TileView::Mixed) {
                fill_background_tile(view, x0, y0, x1, y1, jitter, spp, out);
                clock_.lap(kTile);
                clock_.end_tile(stats_.ns);
                return;
            }
        }
        color_.assign(size_t(npix), Vec3{0, 0, 0});
        depth_sum_.assign(size_t(npix), 0.f);
        nsum_.assign(size_t(npix), Vec3{0, 0, 0});
        hits_.assign(size_t(npix), 0u);
        object_hits_.assign(size_t(npix), 0u);
        albedo_.assign(size_t(npix), Vec3{0, 0, 0});
        rays_.clear();
        const float spread = set_.lod_pixels > 0.f ? cam_.pixel_angle() : 0.f;
        if (!jitter) {   // pixel centres: the image-plane coordinates of the tile's columns, once
            plane_x_.resize(size_t(tw));
            for (int x = x0; x < x1; ++x) plane_x_[size_t(x - x0)] = cam_.plane_x(float(x) + 0.5f);
        }
        for (int y = y0; y < y1; ++y) {
            const float row_y = jitter ? 0.f : cam_.plane_y(float(y) + 0.5f);
            for (int x = x0; x < x1; ++x) {
                uint64_t gp = uint64_t(y) * uint64_t(cam_.width) + uint64_t(x);
                float sx = 0.f, sy = 0.f;
                if (jitter) {
                    sx = rand01(set_.seed, gp, 0, 0);
                    sy = rand01(set_.seed, gp, 0, 1);
                }
                for (int i = 0; i < spp; ++i) {
                    const uint32_t s = set_.sample_offset + uint32_t(i);
                    float u = 0.5f, v = 0.5f;
                    if (jitter) {   // R2 points, shifted per pixel (Cranley–Patterson)
                        u = float(frac(kR2a * s + sx));
                        v = float(frac(kR2b * s + sy));
                    }
                    PathRay &pr = rays_.emplace_back();   // in place: a copied ray stalls on store forwarding
                    pr.ray.o = cam_.eye;
                    pr.ray.d = jitter ? cam_.direction(float(x) + u, float(y) + v)
                                      : cam_.direction_at(plane_x_[size_t(x - x0)], row_y);
                    pr.ray.spread = spread;
                    pr.weight = Vec3{1, 1, 1} * (1.f / float(spp));
                    pr.pixel = uint32_t((y - y0) * tw + (x - x0));
                    pr.sample = s;
                }
            }
        }
        stats_.primary += rays_.size();
        clock_.lap(kTile);
        for (int bounce = 0; !rays_.empty(); ++bounce) {
            trace_bounce(bounce, x0, y0, tw);
            if (bounce >= set_.reflections) break;
            rays_.swap(next_);
            stats_.reflection += rays_.size();
        }
        for (int y = y0; y < y1; ++y)
            for (int x = x0; x < x1; ++x) {
                size_t lp = size_t((y - y0) * tw + (x - x0));
                size_t gp = size_t(y) * size_t(cam_.width) + size_t(x);
                for (int k = 0; k < 3; ++k) out.color[3 * gp + k] = color_[lp][k];
                uint32_t h = hits_[lp];
                // (x / 1 is x: one sample or one hit needs no division)
                out.alpha[gp] = spp == 1 ? float(h) : float(h) / float(spp);
                out.depth[gp] = h == 1 ? depth_sum_[lp] : h ? depth_sum_[lp] / float(h) : kInf;
                Vec3 n = h ? unit_normal_.of(nsum_[lp]) : Vec3{0, 0, 0};
                for (int k = 0; k < 3; ++k) out.normal[3 * gp + k] = n[k];
                for (int k = 0; k < 3; ++k) out.albedo[3 * gp + k] = std::min(1.f, albedo_[lp][k]);
                out.object_alpha[gp] = spp == 1 ? float(object_hits_[lp]) : float(object_hits_[lp]) / float(spp);
            }
        clock_.lap(kTile);
        clock_.end_tile(stats_.ns);
    }

private:
    /// Closest hits of rays_ with the objects (those of the rays that can reach each) and
    /// the ground. Returns how many ray-object queries were made.
    uint64_t intersect(std::vector<Nearest> &near, RayKind kind) {
        const size_t n = rays_.size();
        near.assign(n, Nearest{SurfaceHit{}, -1});
        uint64_t traced = 0;
        for (size_t o = 0; o < scene_.objects.size(); ++o) {
            const Reach &reach = reach_[o];
            batch_.clear();
            index_.clear();
            for (size_t i = 0; i < n; ++i) {
                Ray r = rays_[i].ray;
                r.tmax = std::min(r.tmax, near[i].hit.t);
                if (reach.known && !meets(reach, r.o, r.d, r.tmin, r.tmax)) continue;
                batch_.push_back(r);
                index_.push_back(uint32_t(i));
            }
            const size_t m = batch_.size();
            if (m == 0) continue;
            traced += m;
            tmp_.resize(m);
            scene_.objects[o].geometry->intersect_as(batch_.data(), m, tmp_.data(), kind);
            for (size_t k = 0; k < m; ++k) {
                const uint32_t i = index_[k];
                if (tmp_[k].t < near[i].hit.t) near[i] = {tmp_[k], int(o)};
            }
        }
        if (scene_.ground) {
            for (size_t i = 0; i < n; ++i) {
                const Ray &r = rays_[i].ray;
                float den = dot(r.d, scene_.ground_normal);
                if (std::fabs(den) < kParallelCos) continue;
                float t = dot(scene_.ground_point - r.o, scene_.ground_normal) / den;
                if (t > r.tmin && t < std::min(r.tmax, near[i].hit.t)) {
                    SurfaceHit h;
                    h.t = t;
                    h.n = scene_.ground_normal;
                    h.color = {1, 1, 1};
                    h.radius = 0.f;
                    h.count = 1;
                    near[i] = {h, -2};
                }
            }
        }
        return traced;
    }

    /// What every camera sample of the tile [x0, x1) x [y0, y1) sees, proven from the tile's
    /// corner rays (in double precision, with margins far above the float rounding of the
    /// samples' own tests): their rays all lie in the pyramid spanned by the corners of the
    /// tile's image-plane rectangle (jittered samples too). The pyramid misses an object's
    /// bounds when the sphere lies beyond one of its faces or behind the eye; it misses the
    /// ground when every corner ray points away from the plane, and meets it, in the convex
    /// quadrilateral of the corner rays' hits, when every corner ray points toward it; that
    /// quadrilateral is beyond the fade when its distance from the ground point exceeds the
    /// fade's end. Anything not proven is Mixed.
    TileView classify_tile(int x0, int y0, int x1, int y1) const {
        if (!background_possible_) return TileView::Mixed;
        // the rectangle, grown by a hundredth of a pixel
        const double px = 0.01 * (double(cam_.plane_x(1.f)) - double(cam_.plane_x(0.f)));
        const double py = 0.01 * (double(cam_.plane_y(0.f)) - double(cam_.plane_y(1.f)));
        const double sx0 = double(cam_.plane_x(float(x0))) - px, sx1 = double(cam_.plane_x(float(x1))) + px;
        const double sy0 = double(cam_.plane_y(float(y1))) - py, sy1 = double(cam_.plane_y(float(y0))) + py;
        const D3 f(cam_.forward), r(cam_.right), u(cam_.up), eye(cam_.eye);
        const D3 corner[4] = {f + r * sx0 + u * sy0, f + r * sx1 + u * sy0, f + r * sx1 + u * sy1,
                              f + r * sx0 + u * sy1};
        const D3 mid = f + r * (0.5 * (sx0 + sx1)) + u * (0.5 * (sy0 + sy1));
        D3 face[4] = {D3(0, 0, 0), D3(0, 0, 0), D3(0, 0, 0), D3(0, 0, 0)};   // inward unit normals
        for (int i = 0; i < 4; ++i) {
            D3 n = corner[i].cross(corner[(i + 1) % 4]);
            if (n.dot(mid) < 0.0) n = n * -1.0;
            const double len = n.norm();
            if (!(len > 0.0)) return TileView::Mixed;
            face[i] = n * (1.0 / len);
        }
        const D3 fwd = f * (1.0 / f.norm());
        for (const Reach &reach : reach_) {
            const D3 q = D3(reach.c) - eye;
            const double dist = q.norm();
            const double rr = double(reach.r) * (1.0 + 1e-3) + 1e-5 * dist;
            if (!(dist > rr)) return TileView::Mixed;
            bool outside = q.dot(fwd) < -rr;
            for (int i = 0; i < 4 && !outside; ++i) outside = q.dot(face[i]) < -rr;
            if (!outside) return TileView::Mixed;
        }
        if (!scene_.ground) return TileView::Miss;
        const D3 gn(scene_.ground_normal), gp(scene_.ground_point);
        const double h = (gp - eye).dot(gn);   // the eye's signed distance below the plane
        if (!(std::fabs(h) > 1e-6 * double(min_offset_ / kMinOffsetRel))) return TileView::Mixed;
        // the cosine of a sample's direction with the plane's normal, times the sign of h, is
        // at least the corners' smallest (its numerator is linear over the rectangle) over
        // their largest length (convex): it must clear kParallelCos and the rounding by far
        double lo = kInf, hi = -kInf, longest = 0.0;
        for (const D3 &c : corner) {
            const double den = c.dot(gn) * (h > 0.0 ? 1.0 : -1.0);
            lo = std::min(lo, den);
            hi = std::max(hi, den);
            longest = std::max(longest, c.norm());
        }
        constexpr double kClear = 1e-4;
        if (hi < -kClear * longest) return TileView::Miss;   // every sample points away from the plane
        if (!(lo > kClear * longest) || !(scene_.sky.ground_fade > 0.f)) return TileView::Mixed;
        // every sample meets the plane: the hits' convex quadrilateral, in the plane's basis
        const D3 gt(ground_t_), gb(ground_b_);
        double qx[4], qy[4], tmax = 0.0;
        for (int i = 0; i < 4; ++i) {
            const double t = h / corner[i].dot(gn);   // along the unnormalised corner ray
            const D3 g = eye + corner[i] * t - gp;
            tmax = std::max(tmax, t * corner[i].norm());
            qx[i] = g.dot(gt);
            qy[i] = g.dot(gb);
        }
        bool inside = true;   // the ground point inside the quadrilateral
        double sign = 0.0, near = kInf;
        for (int i = 0; i < 4; ++i) {
            const int j = (i + 1) % 4;
            const double c = qx[i] * qy[j] - qy[i] * qx[j];
            if (sign == 0.0) sign = c;
            if (c * sign < 0.0) inside = false;
            near = std::min(near, segment_distance(qx[i], qy[i], qx[j], qy[j]));
        }
        if (inside) return TileView::Mixed;
        const double fade_end = std::sqrt(double(fade_end2_));
        const double margin = 1e-4 * (fade_end + (gp - eye).norm() + tmax);
        return near > fade_end + margin ? TileView::Faded : TileView::Mixed;
    }

    /// The ground's distance along the camera rays through the pixel centres (px[i], py), i < n,
    /// given h = dot(ground point - eye, normal): ground_distances_row with this camera.
    void ground_distances(const float *px, int n, float py, float h, float *t) const {
        ground_distances_row(px, n, py, h, cam_.forward, cam_.right, cam_.up, scene_.ground_normal, t);
    }

    /// A tile classify_tile proved to show only background, written to `out`: per sample the
    /// direction and (on the ground) the distance, with the expressions of render_tile,
    /// intersect() and trace_bounce(), and the same sums in the same order, so the pixels are
    /// the bits the general path gives them; what no sample changes (the background's colour
    /// unless it is the sky, the ground's normal) is summed once.
    void fill_background_tile(TileView view, int x0, int y0, int x1, int y1, bool jitter, int spp,
                              FrameBuffers &out) {
        const Sky &sky_model = scene_.sky;
        const bool faded = view == TileView::Faded, sky_bg = sky_model.background_is_sky;
        const Vec3 eye = cam_.eye, gn = scene_.ground_normal;
        const float h = dot(scene_.ground_point - eye, gn);
        const Vec3 weight = Vec3{1, 1, 1} * (1.f / float(spp));
        // (the faded ground adds weight * bg * f with a fade f of 1: the same bits as a miss)
        Vec3 color{0, 0, 0}, albedo{0, 0, 0}, nsum{0, 0, 0};   // the sums no sample changes
        if (!sky_bg)
            for (int i = 0; i < spp; ++i) {
                color += weight * sky_model.background;
                albedo += weight * clamp01(sky_model.background);
            }
        const uint32_t hits = faded ? uint32_t(spp) : 0u;
        if (faded) {   // every sample's direction has the sign of h against the normal
            const Vec3 n = h > 0.f ? -gn : gn;
            for (int i = 0; i < spp; ++i) nsum += n;
        }
        const Vec3 normal = hits ? unit_normal_.of(nsum) : Vec3{0, 0, 0};
        // the general path's hits / spp and object hits / spp: every sample or none, no object
        const float alpha = faded ? 1.f : 0.f, object_alpha = 0.f;
        const int tw = x1 - x0;
        if (!jitter) {
            plane_x_.resize(size_t(tw));
            for (int x = x0; x < x1; ++x) plane_x_[size_t(x - x0)] = cam_.plane_x(float(x) + 0.5f);
        }
        if (!jitter && spp == 1 && !sky_bg) {   // one sample at the pixel centre: rows of distances
            // every row is the same but for the distances: its three-channel runs made once
            row_rgb_.resize(3 * size_t(tw) * 3);
            float *row_color = row_rgb_.data(), *row_normal = row_color + 3 * tw, *row_albedo = row_normal + 3 * tw;
            for (int i = 0; i < tw; ++i)
                for (int k = 0; k < 3; ++k) {
                    row_color[3 * i + k] = color[k];
                    row_normal[3 * i + k] = normal[k];
                    row_albedo[3 * i + k] = std::min(1.f, albedo[k]);
                }
            const size_t rgb_bytes = 3 * size_t(tw) * sizeof(float);
            for (int y = y0; y < y1; ++y) {
                const size_t gp = size_t(y) * size_t(cam_.width) + size_t(x0);
                std::memcpy(&out.color[3 * gp], row_color, rgb_bytes);
                std::memcpy(&out.normal[3 * gp], row_normal, rgb_bytes);
                std::memcpy(&out.albedo[3 * gp], row_albedo, rgb_bytes);
                std::fill_n(&out.alpha[gp], tw, alpha);
                std::fill_n(&out.object_alpha[gp], tw, object_alpha);
                if (faded)
                    ground_distances(plane_x_.data(), tw, cam_.plane_y(float(y) + 0.5f), h, &out.depth[gp]);
                else
                    std::fill_n(&out.depth[gp], tw, kInf);
            }
        } else for (int y = y0; y < y1; ++y) {
            const float row_y = jitter ? 0.f : cam_.plane_y(float(y) + 0.5f);
            for (int x = x0; x < x1; ++x) {
                const uint64_t gp = uint64_t(y) * uint64_t(cam_.width) + uint64_t(x);
                float sx = 0.f, sy = 0.f;
                if (jitter) {
                    sx = rand01(set_.seed, gp, 0, 0);
                    sy = rand01(set_.seed, gp, 0, 1);
                }
                float depth = 0.f;
                Vec3 c = color, a = albedo;
                if (sky_bg) c = a = Vec3{0, 0, 0};
                // (a plain background beyond no ground: nothing depends on the direction)
                for (int i = 0; i < spp && (faded || sky_bg); ++i) {
                    const uint32_t s = set_.sample_offset + uint32_t(i);
                    float u = 0.5f, v = 0.5f;
                    if (jitter) {
                        u = float(frac(kR2a * s + sx));
                        v = float(frac(kR2b * s + sy));
                    }
                    const Vec3 d = jitter ? cam_.direction(float(x) + u, float(y) + v)
                                          : cam_.direction_at(plane_x_[size_t(x - x0)], row_y);
                    if (faded) depth += h / dot(d, gn);
                    if (sky_bg) {
                        const Vec3 bg = sky(d);
                        c += weight * bg;
                        a += weight * clamp01(bg);
                    }
                }
                for (int k = 0; k < 3; ++k) out.color[3 * gp + k] = c[k];
                out.alpha[gp] = alpha;
                out.depth[gp] = hits ? depth / float(hits) : kInf;
                for (int k = 0; k < 3; ++k) out.normal[3 * gp + k] = normal[k];
                for (int k = 0; k < 3; ++k) out.albedo[3 * gp + k] = std::min(1.f, a[k]);
                out.object_alpha[gp] = object_alpha;
            }
        }
        const uint64_t samples = uint64_t(tw) * uint64_t(y1 - y0) * uint64_t(spp);
        stats_.primary += samples;
        stats_.background += samples;
    }

    /// The local scale of OffsetPolicy for the rays leaving hit `h` of ray `r`: the blended disk
    /// radius, the ray's footprint where level-of-detail disks may stand for the surface
    /// (RenderSettings::footprint_offsets), and the floor. Not the footprint on the ground: an
    /// exact plane, whose rays meet no disk of their own, and whose footprint-sized clearance
    /// would let them pass the objects standing on it (a mirror ground showed the background
    /// through the foot of what it reflects, shadows and sky visibility lost their contact).
    float offset_scale(const SurfaceHit &h, const Ray &r, bool ground) const {
        return std::max({h.radius, set_.footprint_offsets && !ground ? r.footprint(h.t) : 0.f, min_offset_});
    }

    /// Whether some object may lie within `dist` of `p`: false when `p` is farther than `dist`
    /// from every object's bounds (with a relative margin of 1e-3 over float rounding, itself
    /// harmless: a ray let through is traced and finds nothing).
    bool object_within(Vec3 p, float dist) const {
        for (const Reach &reach : reach_) {
            if (!reach.known) return true;
            const float reach_r = (reach.r + dist) * (1.f + 1e-3f);
            if (length2(reach.c - p) <= reach_r * reach_r) return true;
        }
        return false;
    }

    Vec3 sky(Vec3 d) const {
        float e = dot(d, scene_.sky.up);
        if (e >= 0.f) {
            float k = std::pow(1.f - e, 3.f);
            return scene_.sky.zenith * (1.f - k) + scene_.sky.horizon * k;
        }
        float k = std::min(1.f, -e * 4.f);
        return scene_.sky.horizon * (1.f - k) + scene_.sky.below * k;
    }

    /// Ambient light from the sky on a surface of normal n (hemisphere blend).
    Vec3 ambient(Vec3 n) const {
        float e = 0.5f + 0.5f * dot(n, scene_.sky.up);
        Vec3 top = (scene_.sky.zenith + scene_.sky.horizon) * 0.5f;
        return (top * e + scene_.sky.below * (1.f - e)) * scene_.sky.ambient;
    }

    /// The ground's samples of this bounce, before they are shaded in order (simd_lanes):
    /// their fade (camera rays), and for those the fade leaves visible each directional light's
    /// direction, ndl and specular lobe and their sky-visibility directions, computed in lanes
    /// (shading_lanes.h) with trace_bounce's scalar expressions; trace_bounce then reads them
    /// in the same order it meets the samples. The random numbers stay scalar (64-bit hashes).
    void shade_ground_lanes(int bounce, const std::vector<Nearest> &near, int x0, int y0, int tw) {
        GroundLanes &g = gl_;
        const Sky &sky_model = scene_.sky;
        const Material &m = scene_.ground_material;
        const bool fading = bounce == 0 && sky_model.ground_fade > 0.f;
        for (auto *v : {&g.ox, &g.oy, &g.oz, &g.dx, &g.dy, &g.dz, &g.t}) v->clear();
        for (size_t i = 0; i < rays_.size(); ++i) {
            if (near[i].object != -2) continue;
            const Ray &r = rays_[i].ray;
            g.ox.push_back(r.o.x), g.oy.push_back(r.o.y), g.oz.push_back(r.o.z);
            g.dx.push_back(r.d.x), g.dy.push_back(r.d.y), g.dz.push_back(r.d.z);
            g.t.push_back(near[i].hit.t);
        }
        const size_t count = g.t.size();
        g.fade.resize(count);
        if (fading)
            lanes::over_lanes(count, true, [&](size_t i, auto lane) {
                using L = decltype(lane);
                lanes::ground_fade(L::load(&g.ox[i]), L::load(&g.oy[i]), L::load(&g.oz[i]),
                                   L::load(&g.dx[i]), L::load(&g.dy[i]), L::load(&g.dz[i]),
                                   L::load(&g.t[i]), scene_.ground_point, scene_.ground_normal,
                                   sky_model.ground_fade, fade_end2_)
                    .store(&g.fade[i]);
            });
        // the samples the fade leaves visible
        const size_t nl = scene_.lights.size();
        for (auto *v : {&g.nx, &g.ny, &g.nz, &g.sdx, &g.sdy, &g.sdz}) v->clear();
        g.within.clear();
        g.light.resize(nl);
        for (auto &lv : g.light) for (auto &v : lv) v.clear();
        for (auto &v : g.occ) v.clear();
        const uint32_t dim0 = uint32_t(bounce) * kDimsPerBounce;
        const int n_occ = sky_model.occlusion_distance > 0.f && set_.occlusion_rays > 0
                              ? (bounce == 0 ? set_.occlusion_rays : 1) : 0;
        size_t k = 0;
        for (size_t i = 0; i < rays_.size(); ++i) {
            if (near[i].object != -2) continue;
            if (fading && g.fade[k++] >= 1.f) continue;
            const PathRay &pr = rays_[i];
            const Ray &r = pr.ray;
            const SurfaceHit &h = near[i].hit;
            const Vec3 n = dot(h.n, r.d) > 0.f ? -h.n : h.n;
            g.nx.push_back(n.x), g.ny.push_back(n.y), g.nz.push_back(n.z);
            g.sdx.push_back(r.d.x), g.sdy.push_back(r.d.y), g.sdz.push_back(r.d.z);
            const uint64_t gp = pixel_id(pr.pixel, x0, y0, tw);
            for (size_t li = 0; li < nl; ++li) {
                const Light &L = scene_.lights[li];
                if (L.type != LightType::Directional || !(L.angle > 0.f)) continue;
                float u1, u2;
                const uint32_t ld = uint32_t(std::min<size_t>(li, kMaxStratifiedLights));
                r2_point(set_.seed, gp, pr.sample, dim0 + kDimLights + 2 * ld, u1, u2);
                g.light[li][0].push_back(u1);
                g.light[li][1].push_back(u2);
            }
            uint8_t within = 0;
            if (n_occ > 0) {
                const Vec3 p = r.o + r.d * h.t;
                const float scale = offset_scale(h, r, true);
                const Vec3 origin = p + n * (set_.offsets.normal_offset * scale);
                const float tmin = set_.offsets.tmin * scale;
                within = object_within(origin, std::max(tmin, sky_model.occlusion_distance));
                if (within) {
                    const Basis &basis = basis_.of(n);
                    for (int j = 0; j < n_occ; ++j) {
                        float u1, u2;
                        r2_point(set_.seed, gp, pr.sample * uint32_t(n_occ) + uint32_t(j),
                                 dim0 + kDimOcclusion, u1, u2);
                        const float in[11] = {n.x, n.y, n.z, basis.t.x, basis.t.y, basis.t.z,
                                              basis.b.x, basis.b.y, basis.b.z, u1, u2};
                        for (int c = 0; c < 11; ++c) g.occ[c].push_back(in[c]);
                    }
                }
            }
            g.within.push_back(within);
        }
        const size_t shaded = g.nx.size();
        // each directional light's direction and terms
        for (size_t li = 0; li < nl; ++li) {
            const Light &L = scene_.lights[li];
            if (L.type != LightType::Directional) continue;
            auto &lv = g.light[li];
            for (int c = 2; c < 7; ++c) lv[c].resize(shaded);
            const bool soft = L.angle > 0.f;
            const Cone &cone = light_cones_[li];
            lanes::over_lanes(shaded, true, [&](size_t i, auto lane) {
                using L4 = decltype(lane);
                L4 lx, ly, lz;
                if (soft) {
                    lanes::cone_direction(cone.axis, cone.t, cone.b, cone.cos_max, L4::load(&lv[0][i]),
                                          L4::load(&lv[1][i]), lx, ly, lz);
                } else {
                    lx = L4::splat(L.direction.x), ly = L4::splat(L.direction.y), lz = L4::splat(L.direction.z);
                }
                L4 ndl, spec;
                lanes::light_terms(L4::load(&g.nx[i]), L4::load(&g.ny[i]), L4::load(&g.nz[i]), lx, ly, lz,
                                   L4::load(&g.sdx[i]), L4::load(&g.sdy[i]), L4::load(&g.sdz[i]),
                                   m.specular, m.shininess, ndl, spec);
                lx.store(&lv[2][i]), ly.store(&lv[3][i]), lz.store(&lv[4][i]);
                ndl.store(&lv[5][i]), spec.store(&lv[6][i]);
            });
        }
        // the sky-visibility rays' directions
        const size_t occ = g.occ[0].size();
        for (int c = 11; c < 14; ++c) g.occ[c].resize(occ);
        lanes::over_lanes(occ, true, [&](size_t i, auto lane) {
            using L = decltype(lane);
            L x, y, z;
            lanes::cosine_direction(L::load(&g.occ[0][i]), L::load(&g.occ[1][i]), L::load(&g.occ[2][i]),
                                    L::load(&g.occ[3][i]), L::load(&g.occ[4][i]), L::load(&g.occ[5][i]),
                                    L::load(&g.occ[6][i]), L::load(&g.occ[7][i]), L::load(&g.occ[8][i]),
                                    L::load(&g.occ[9][i]), L::load(&g.occ[10][i]), x, y, z);
            x.store(&g.occ[11][i]), y.store(&g.occ[12][i]), z.store(&g.occ[13][i]);
        });
    }

    void trace_bounce(int bounce, int x0, int y0, int tw) {
        std::vector<Nearest> &near = near_;
        const uint64_t traced = intersect(near, bounce == 0 ? RayKind::Camera : RayKind::Reflection);
        clock_.lap(bounce == 0 ? kPrimary : kReflection);
        (bounce == 0 ? stats_.primary_traced : stats_.reflection_traced) += traced;
        shadows_.clear();
        next_.clear();
        const Sky &sky_model = scene_.sky;
        const bool lanes_on = set_.simd_lanes && scene_.ground;
        if (lanes_on) shade_ground_lanes(bounce, near, x0, y0, tw);
        size_t gk = 0, sk = 0, ok = 0;   // the next ground sample, shaded ground sample, sky ray in gl_
        for (size_t i = 0; i < rays_.size(); ++i) {
            const PathRay &pr = rays_[i];
            const Nearest &nh = near[i];
            const Ray &r = pr.ray;
            if (nh.object == -1) {
                Vec3 bg = (bounce == 0 && !sky_model.background_is_sky) ? sky_model.background : sky(r.d);
                color_[pr.pixel] += pr.weight * bg;
                if (pr.albedo) albedo_[pr.pixel] += pr.weight * clamp01(bg);
                continue;
            }
            const SurfaceHit &h = nh.hit;
            const bool lane = lanes_on && nh.object == -2;   // its analytic terms are in gl_
            const size_t gslot = lane ? gk++ : 0;
            Vec3 p = r.o + r.d * h.t;
            Vec3 n = dot(h.n, r.d) > 0.f ? -h.n : h.n;
            Vec3 weight = pr.weight;
            if (bounce == 0) {
                depth_sum_[pr.pixel] += h.t;
                nsum_[pr.pixel] += n;
                hits_[pr.pixel] += 1;
                if (nh.object >= 0) object_hits_[pr.pixel] += 1;
                if (nh.object == -2 && sky_model.ground_fade > 0.f) {
                    // studio backdrop: the far ground blends into the background
                    float f = 1.f;   // beyond the fade's end (most of a far view's pixels): exactly 1
                    if (lane) {
                        f = gl_.fade[gslot];
                    } else {
                        Vec3 g = p - scene_.ground_point;
                        const float d2 = length2(g - scene_.ground_normal * dot(g, scene_.ground_normal));
                        if (!(d2 > fade_end2_)) {
                            f = std::clamp(std::sqrt(d2) / sky_model.ground_fade - 1.f, 0.f, 1.f);
                            f = f * f * (3.f - 2.f * f);
                        }
                    }
                    Vec3 bg = sky_model.background_is_sky ? sky(r.d) : sky_model.background;
                    color_[pr.pixel] += weight * bg * f;
                    albedo_[pr.pixel] += weight * clamp01(bg) * f;
                    weight = weight * (1.f - f);
                    if (f >= 1.f) continue;
                }
            }
            const size_t sslot = lane ? sk++ : 0;
            const Material &m = nh.object == -2 ? scene_.ground_material
                                                : scene_.objects[size_t(nh.object)].material;
            Vec3 albedo = m.base_color;
            if (nh.object >= 0 && m.use_point_colors) albedo = albedo * point_color_.of(h.color);
            if (nh.object == -2 && m.checker_size > 0.f) {
                long cx = long(std::floor(dot(p, ground_t_) / m.checker_size));
                long cy = long(std::floor(dot(p, ground_b_) / m.checker_size));
                if ((cx + cy) & 1) albedo = m.checker;
            }
            const float keep = 1.f - m.mirror;
            const bool reflects = m.mirror > 0.f && bounce < set_.reflections;
            // The denoiser's albedo follows sharp mirror paths as the colour does, so that what
            // a mirror shows stays sharp; a glossy lobe's samples would make it noisy, so a
            // glossy surface stands for what it reflects with its own colour.
            const bool follow = reflects && m.roughness == 0.f;
            if (pr.albedo)
                albedo_[pr.pixel] += weight * clamp01(albedo) * (follow ? keep : 1.f);
            const float scale = offset_scale(h, r, nh.object == -2);
            const Vec3 origin = p + n * (set_.offsets.normal_offset * scale);
            const float tmin = set_.offsets.tmin * scale;
            const uint64_t gp = pixel_id(pr.pixel, x0, y0, tw);
            const uint32_t dim0 = uint32_t(bounce) * kDimsPerBounce;
            const Vec3 ambient_add = weight * albedo * ambient(n) * (keep * m.diffuse);
            const int n_occ = sky_model.occlusion_distance > 0.f && set_.occlusion_rays > 0
                                  ? (bounce == 0 ? set_.occlusion_rays : 1) : 0;
            if (n_occ == 0) {
                color_[pr.pixel] += ambient_add;
            } else if (!(lane ? gl_.within[sslot] != 0
                              : object_within(origin, std::max(tmin, sky_model.occlusion_distance)))) {
                // no object within the rays' length: none is blocked, whatever its direction
                for (int k = 0; k < n_occ; ++k) {
                    ShadowRay &sr = shadows_.emplace_back();
                    sr.add = ambient_add * (1.f / float(n_occ));
                    sr.pixel = pr.pixel;
                    sr.ground_blocks = false;
                    sr.kind = RayKind::Sky;
                    sr.may_hit = false;
                }
            } else {   // the directions from the lanes (ground samples), or sampled here
                const Basis *basis = lane ? nullptr : &basis_.of(n);
                for (int k = 0; k < n_occ; ++k) {
                    Vec3 d;
                    if (lane) {
                        d = {gl_.occ[11][ok], gl_.occ[12][ok], gl_.occ[13][ok]};
                        ++ok;
                    } else {
                        float u1, u2;
                        r2_point(set_.seed, gp, pr.sample * uint32_t(n_occ) + uint32_t(k),
                                 dim0 + kDimOcclusion, u1, u2);
                        d = sample_cosine(n, basis->t, basis->b, u1, u2);
                    }
                    ShadowRay &sr = shadows_.emplace_back();
                    sr.ray.o = origin;
                    sr.ray.d = d;
                    sr.ray.tmin = tmin;
                    sr.ray.tmax = std::max(tmin, sky_model.occlusion_distance);
                    sr.ray.width0 = r.footprint(h.t);
                    sr.ray.spread = 0.f;
                    sr.add = ambient_add * (1.f / float(n_occ));
                    sr.pixel = pr.pixel;
                    sr.ground_blocks = false;
                    sr.kind = RayKind::Sky;
                }
            }
            for (size_t li = 0; li < scene_.lights.size(); ++li) {
                const Light &L = scene_.lights[li];
                Vec3 ldir, radiance = L.color;
                float dist = kInf, ndl, spec = 0.f;
                const bool from_lanes = lane && L.type == LightType::Directional;
                if (from_lanes) {   // direction, ndl and lobe from the lanes
                    const auto &lv = gl_.light[li];
                    ldir = {lv[2][sslot], lv[3][sslot], lv[4][sslot]};
                    ndl = lv[5][sslot];
                    spec = lv[6][sslot];
                } else {
                    float u1 = 0.f, u2 = 0.f;   // a point on the light (not needed by a hard one)
                    const bool hard = L.type == LightType::Directional ? !(L.angle > 0.f)
                                      : L.type == LightType::Point && !(L.radius > 0.f);
                    uint32_t ld = uint32_t(std::min<size_t>(li, kMaxStratifiedLights));
                    if (!hard) r2_point(set_.seed, gp, pr.sample, dim0 + kDimLights + 2 * ld, u1, u2);
                    if (L.type == LightType::Directional) {
                        ldir = L.angle > 0.f ? sample_cone(light_cones_[li], u1, u2) : L.direction;
                    } else {
                        Vec3 q = L.position;
                        float cos_light = 1.f;
                        if (L.type == LightType::Area) {
                            q = q + L.edge_u * u1 + L.edge_v * u2;
                            Vec3 ln = normalize(cross(L.edge_u, L.edge_v));
                            Vec3 dq = normalize(q - p);
                            cos_light = std::fabs(dot(ln, dq));
                        } else if (L.radius > 0.f) {
                            q = q + sample_cone(normalize(p - q), 0.5f * kPi, u1, u2) * L.radius;
                        }
                        Vec3 dq = q - p;
                        dist = length(dq);
                        if (!(dist > 0.f)) continue;
                        ldir = dq / dist;
                        radiance = L.color * (cos_light / (dist * dist));
                    }
                    ndl = dot(n, ldir);
                }
                if (ndl <= 0.f) continue;
                if (!from_lanes) {
                    Vec3 hv = normalize(ldir - r.d);
                    spec = m.specular * lobe_pow(std::max(0.f, dot(n, hv)), m.shininess);
                }
                Vec3 add = weight * radiance * (albedo * (keep * m.diffuse * ndl) + Vec3{1, 1, 1} * (spec * ndl));
                if (!set_.shadows || !L.cast_shadows) {
                    color_[pr.pixel] += add;
                    continue;
                }
                ShadowRay &sr = shadows_.emplace_back();
                sr.ray.o = origin;
                sr.ray.d = ldir;
                sr.ray.tmin = tmin;
                sr.ray.tmax = dist == kInf ? kInf : std::max(0.f, dist * (1.f - 1e-4f) - set_.offsets.normal_offset * scale);
                sr.ray.width0 = r.footprint(h.t);
                sr.ray.spread = sr.ray.width0 > 0.f ? shadow_spread(L, dist, sr.ray.width0) : 0.f;
                sr.add = add;
                sr.pixel = pr.pixel;
                sr.ground_blocks = true;
                sr.kind = RayKind::Shadow;
            }
            if (reflects) {
                Vec3 rd = reflect(r.d, n);
                if (m.roughness > 0.f) {
                    float u1, u2;
                    r2_point(set_.seed, gp, pr.sample, dim0 + kDimGloss, u1, u2);
                    Vec3 g = sample_cone(rd, std::min(m.roughness, 1.f) * 0.5f * kPi, u1, u2);
                    rd = dot(g, n) > 0.f ? g : rd;
                }
                PathRay &nr = next_.emplace_back();
                nr.ray.o = origin;
                nr.ray.d = rd;
                nr.ray.tmin = tmin;
                nr.ray.width0 = r.footprint(h.t);
                nr.ray.spread = r.spread + m.roughness;
                nr.weight = weight * m.mirror;
                nr.pixel = pr.pixel;
                nr.sample = pr.sample;
                nr.albedo = pr.albedo && follow;
            }
        }
        clock_.lap(kShading);
        trace_shadows();
        clock_.lap(kShadow);
    }

    void trace_shadows() {
        const size_t n = shadows_.size();
        if (n == 0) return;
        stats_.shadow += n;
        std::vector<uint8_t> &blocked = blocked_, &tmp = occluded_;
        std::vector<uint32_t> &live = live_;
        blocked.assign(n, 0);
        live.resize(n);
        for (size_t i = 0; i < n; ++i) live[i] = uint32_t(i);
        uint64_t traced = 0;
        for (size_t o = 0; o < scene_.objects.size(); ++o) {
            if (live.empty()) break;
            const Reach &reach = reach_[o];
            // one batch per kind of ray: the level of detail's error model depends on it
            bool any = false;
            for (const RayKind kind : {RayKind::Shadow, RayKind::Sky}) {
                batch_.clear();
                index_.clear();   // positions in `live` of the rays that can reach the object
                for (size_t k = 0; k < live.size(); ++k) {
                    const ShadowRay &s = shadows_[live[k]];
                    const Ray &r = s.ray;
                    if (s.kind != kind || !s.may_hit ||
                        (reach.known && !meets(reach, r.o, r.d, r.tmin, r.tmax)))
                        continue;
                    batch_.push_back(r);
                    index_.push_back(uint32_t(k));
                }
                if (batch_.empty()) continue;
                any = true;
                traced += batch_.size();
                tmp.assign(batch_.size(), 0);
                scene_.objects[o].geometry->occluded_as(batch_.data(), batch_.size(), tmp.data(), kind);
                for (size_t k = 0; k < batch_.size(); ++k)
                    if (tmp[k]) blocked[live[index_[k]]] = 1;
            }
            if (!any) continue;
            size_t w = 0;
            for (size_t k = 0; k < live.size(); ++k)
                if (!blocked[live[k]]) live[w++] = live[k];
            live.resize(w);
        }
        stats_.shadow_traced += traced;
        for (uint32_t i : live) {
            const ShadowRay &s = shadows_[i];
            if (scene_.ground && s.ground_blocks) {
                float den = dot(s.ray.d, scene_.ground_normal);
                if (std::fabs(den) >= kParallelCos) {
                    float t = dot(scene_.ground_point - s.ray.o, scene_.ground_normal) / den;
                    if (t > s.ray.tmin && t < s.ray.tmax) continue;
                }
            }
            color_[s.pixel] += s.add;
        }
    }

    uint64_t pixel_id(uint32_t local, int x0, int y0, int tw) const {
        int y = y0 + int(local) / tw, x = x0 + int(local) % tw;
        return uint64_t(y) * uint64_t(cam_.width) + uint64_t(x);
    }

    const RenderScene &scene_;
    const CameraModel &cam_;
    const RenderSettings &set_;
    float min_offset_;
    RenderStats &stats_;
    PhaseClock clock_;
    Vec3 ground_t_, ground_b_;   ///< the ground plane's basis (checker cells)
    float fade_end2_;   ///< squared distance from the ground point where its fade reaches 1
    LastValue<Vec3, normalize> unit_normal_;   ///< a pixel's mean normal, normalised
    LastValue<Vec3, srgb_to_linear> point_color_;   ///< a hit's colour, sRGB-decoded
    LastValue<Basis, basis_of> basis_;   ///< a shading normal's basis (sky-visibility rays)
    std::vector<Cone> light_cones_;   ///< per light: the cone of a directional light's directions
    std::vector<Vec3> color_, nsum_;
    std::vector<float> depth_sum_;
    std::vector<uint32_t> hits_, object_hits_;
    std::vector<Vec3> albedo_;
    std::vector<PathRay> rays_, next_;
    std::vector<ShadowRay> shadows_;
    std::vector<Reach> reach_;   ///< per object: the sphere around Geometry::bounds, grown by kBoundsMargin
    std::vector<Nearest> near_;
    std::vector<Ray> batch_;
    std::vector<uint32_t> index_;
    std::vector<SurfaceHit> tmp_;
    std::vector<uint8_t> blocked_, occluded_;   ///< trace_shadows: per shadow ray, per batch ray
    std::vector<uint32_t> live_;   ///< trace_shadows: the shadow rays not yet blocked
    std::vector<float> plane_x_;   ///< render_tile: image-plane x of the tile's pixel centres
    std::vector<float> row_rgb_;   ///< fill_background_tile: a row's colour, normal and albedo
    /// shade_ground_lanes: a bounce's ground samples and what the lanes computed for them
    struct GroundLanes {
        std::vector<float> ox, oy, oz, dx, dy, dz, t, fade;   ///< every ground sample
        std::vector<float> nx, ny, nz, sdx, sdy, sdz;   ///< each one shaded: normal, ray direction
        std::vector<uint8_t> within;   ///< each one shaded: an object within its sky rays' length
        /// per light, each sample shaded: u1, u2 (a soft directional light's), direction x, y,
        /// z, ndl, specular lobe (a directional light's)
        std::vector<std::array<std::vector<float>, 7>> light;
        /// per sky-visibility ray: normal, basis t, b, u1, u2; direction x, y, z
        std::array<std::vector<float>, 14> occ;
    } gl_;
    bool background_possible_ = false;   ///< every object's bounds known (classify_tile)
};

}  // namespace

bool render(const RenderScene &scene, const CameraModel &camera, const RenderSettings &settings,
            FrameBuffers &out, RenderStats &stats, Progress &progress) {
    const int w = camera.width, h = camera.height;
    const size_t np = size_t(w) * size_t(h);
    out.color.assign(3 * np, 0.f);
    out.depth.assign(np, kInf);
    out.normal.assign(3 * np, 0.f);
    out.alpha.assign(np, 0.f);
    out.albedo.assign(3 * np, 0.f);
    out.object_alpha.assign(np, 0.f);
    bool thread_safe = true;
    for (const auto &o : scene.objects) thread_safe = thread_safe && o.geometry->thread_safe();
    // A callback backend gets bigger tiles: fewer, larger batches per call.
    const int tile = std::max(1, thread_safe ? settings.tile : settings.tile * 4);
    const int tx = (w + tile - 1) / tile, ty = (h + tile - 1) / tile;
    stats.tiles_total = uint64_t(tx) * uint64_t(ty);
    progress.total = stats.tiles_total;
    const float scale = scene.scale > 0.f ? scene.scale : 1.f;
    const int threads = thread_safe ? settings.threads : 1;
    std::vector<std::unique_ptr<TileRenderer>> workers(size_t(resolve_threads(threads)));
    parallel_for(stats.tiles_total, 1, threads, [&](size_t b, size_t e, int worker) {
        auto &tr = workers[size_t(worker)];
        if (!tr) tr = std::make_unique<TileRenderer>(scene, camera, settings, scale, stats);
        for (size_t t = b; t < e; ++t) {
            int x0 = int(t % size_t(tx)) * tile, y0 = int(t / size_t(tx)) * tile;
            tr->render_tile(x0, y0, std::min(w, x0 + tile), std::min(h, y0 + tile), out);
            stats.tiles_done += 1;
            progress.advance();
        }
    }, &progress.cancel);
    return !progress.cancelled();
}

}  // namespace pointviz
