// pointviz — the lit ground's analytic shading several samples at a time (render.cpp).
//
// The renderer's per-sample expressions (the studio fade, a directional light's cone sample,
// the half vector and lobe power, a sky-visibility ray's cosine-weighted direction) written once
// over a lane type: F1 (one float: the scalar tail, and every build without SIMD) or F4 (SSE2,
// four floats: every x86-64 CPU). Each lane does the scalar expressions of render.cpp and vec.h
// in the same order (IEEE single precision: +, -, *, / and the square root are correctly rounded
// at any width; the build turns contraction off, so no fused multiply-add), normalize()'s
// `l > 0` branch and std::max / std::clamp computed both ways and selected, so every value is the
// bits the scalar code gives (tests/cpp/core_tests.cpp, test_shading_lanes, against the scalar
// functions; tests/cpp, test_render_ground_lanes, whole frames against the scalar path).
// Eight lanes (AVX) were not tried here: the renderer is 128-bit code, and AVX in short bursts
// called from it paid the 256-bit unit's start-up (benchmarks/README.md, "the far frame's
// fixed cost, cut": the ground's distances eight pixels a step were slower than four).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>

#include "pointviz/isa.h"
#include "pointviz/shading_math.h"
#include "pointviz/vec.h"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(POINTVIZ_NO_SIMD)
#include <emmintrin.h>
#define POINTVIZ_SHADING_LANES_SSE2 1
#endif

namespace pointviz {
namespace lanes {
POINTVIZ_ISA_BEGIN

// ---- one lane --------------------------------------------------------------------------------

struct F1 {
    float v;
    static constexpr int width = 1;
    static F1 load(const float *p) { return {*p}; }
    static F1 splat(float x) { return {x}; }
    void store(float *p) const { *p = v; }
};
struct M1 {
    bool v;
};
inline F1 operator+(F1 a, F1 b) { return {a.v + b.v}; }
inline F1 operator-(F1 a, F1 b) { return {a.v - b.v}; }
inline F1 operator*(F1 a, F1 b) { return {a.v * b.v}; }
inline F1 operator/(F1 a, F1 b) { return {a.v / b.v}; }
inline F1 vsqrt(F1 a) { return {std::sqrt(a.v)}; }
inline M1 gt(F1 a, F1 b) { return {a.v > b.v}; }
inline M1 lt(F1 a, F1 b) { return {a.v < b.v}; }
inline F1 select(M1 m, F1 a, F1 b) { return m.v ? a : b; }
/// std::max(0.f, a)
inline F1 max0(F1 a) { return {std::max(0.f, a.v)}; }
inline void turn_sincos(F1 u, F1 &c, F1 &s) { pointviz::turn_sincos(u.v, c.v, s.v); }
inline F1 lobe_pow(F1 x, float e) { return {pointviz::lobe_pow(x.v, e)}; }

// ---- four lanes (SSE2) -------------------------------------------------------------------------

#ifdef POINTVIZ_SHADING_LANES_SSE2
struct F4 {
    __m128 v;
    static constexpr int width = 4;
    static F4 load(const float *p) { return {_mm_loadu_ps(p)}; }
    static F4 splat(float x) { return {_mm_set1_ps(x)}; }
    void store(float *p) const { _mm_storeu_ps(p, v); }
};
struct M4 {
    __m128 v;
};
inline F4 operator+(F4 a, F4 b) { return {_mm_add_ps(a.v, b.v)}; }
inline F4 operator-(F4 a, F4 b) { return {_mm_sub_ps(a.v, b.v)}; }
inline F4 operator*(F4 a, F4 b) { return {_mm_mul_ps(a.v, b.v)}; }
inline F4 operator/(F4 a, F4 b) { return {_mm_div_ps(a.v, b.v)}; }
inline F4 vsqrt(F4 a) { return {_mm_sqrt_ps(a.v)}; }
inline M4 gt(F4 a, F4 b) { return {_mm_cmpgt_ps(a.v, b.v)}; }
inline M4 lt(F4 a, F4 b) { return {_mm_cmplt_ps(a.v, b.v)}; }
inline F4 select(M4 m, F4 a, F4 b) { return {_mm_or_ps(_mm_and_ps(m.v, a.v), _mm_andnot_ps(m.v, b.v))}; }
/// std::max(0.f, a) is `0 < a ? a : 0`: maxps(a, 0) returns its second operand unless a > 0
/// (NaN and -0 give +0, as the scalar does).
inline F4 max0(F4 a) { return {_mm_max_ps(a.v, _mm_setzero_ps())}; }

/// shading_math.h's turn_sincos, lane by lane: the same quarter turn (truncation of u * 4 +
/// 0.5, u >= 0), the same polynomials in the same order, the quarter's rotation selected.
inline void turn_sincos(F4 u, F4 &c, F4 &s) {
    const __m128i k = _mm_cvttps_epi32(_mm_add_ps(_mm_mul_ps(u.v, _mm_set1_ps(4.f)), _mm_set1_ps(0.5f)));
    const F4 r = (u - F4{_mm_mul_ps(_mm_cvtepi32_ps(k), _mm_set1_ps(0.25f))}) * F4::splat(2.f * 3.14159265358979f);
    const F4 r2 = r * r;
    const auto K = [](float x) { return F4::splat(x); };
    const F4 sr = r * (K(1.f) + r2 * (K(-1.f / 6.f) + r2 * (K(1.f / 120.f) + r2 * (K(-1.f / 5040.f) + r2 * K(1.f / 362880.f)))));
    const F4 cr = K(1.f) + r2 * (K(-0.5f) + r2 * (K(1.f / 24.f) + r2 * (K(-1.f / 720.f) + r2 * (K(1.f / 40320.f) + r2 * K(-1.f / 3628800.f)))));
    const __m128i q = _mm_and_si128(k, _mm_set1_epi32(3));
    const M4 q1{_mm_castsi128_ps(_mm_cmpeq_epi32(q, _mm_set1_epi32(1)))};
    const M4 q2{_mm_castsi128_ps(_mm_cmpeq_epi32(q, _mm_set1_epi32(2)))};
    const M4 q3{_mm_castsi128_ps(_mm_cmpeq_epi32(q, _mm_set1_epi32(3)))};
    // unary minus flips the sign bit (0 - x would give +0 for x = 0)
    const __m128 sign = _mm_set1_ps(-0.f);
    const F4 msr{_mm_xor_ps(sr.v, sign)}, mcr{_mm_xor_ps(cr.v, sign)};
    // case 0: (cr, sr); 1: (-sr, cr); 2: (-cr, -sr); 3: (sr, -cr)
    c = select(q1, msr, select(q2, mcr, select(q3, sr, cr)));
    s = select(q1, cr, select(q2, msr, select(q3, mcr, sr)));
}

/// shading_math.h's lobe_pow, lane by lane: the same products when e is a whole number in
/// [1, 1024] (e is one material's, the same in every lane), std::pow per lane otherwise.
inline F4 lobe_pow(F4 x, float e) {
    if (!(e >= 1.f && e <= 1024.f) || float(int(e)) != e) {
        alignas(16) float t[4];
        _mm_store_ps(t, x.v);
        for (float &v : t) v = std::pow(v, e);
        return {_mm_load_ps(t)};
    }
    unsigned n = unsigned(e);
    F4 r = F4::splat(1.f), b = x;
    for (;;) {
        if (n & 1u) r = r * b;
        n >>= 1;
        if (!n) break;
        b = b * b;
    }
    return r;
}
#endif

// ---- the expressions, over any lane type -----------------------------------------------------

/// vec.h's normalize: v * (1 / |v|) when |v| > 0, else v.
template <class L>
inline void normalize3(L &x, L &y, L &z) {
    const L l = vsqrt((x * x + y * y) + z * z);
    const L inv = L::splat(1.f) / l;
    const auto pos = gt(l, L::splat(0.f));
    x = select(pos, x * inv, x);
    y = select(pos, y * inv, y);
    z = select(pos, z * inv, z);
}

/// render.cpp's sample_cone(Cone, u1, u2): axis (ax, ay, az), basis t and b, cosine cos_max.
template <class L>
inline void cone_direction(const Vec3 &axis, const Vec3 &t, const Vec3 &b, float cos_max, L u1, L u2,
                           L &x, L &y, L &z) {
    const L cz = L::splat(1.f) - u1 * L::splat(1.f - cos_max);
    const L sz = vsqrt(max0(L::splat(1.f) - cz * cz));
    L cs, sn;
    turn_sincos(u2, cs, sn);
    const L a = sz * cs, c = sz * sn;
    x = (L::splat(t.x) * a + L::splat(b.x) * c) + L::splat(axis.x) * cz;
    y = (L::splat(t.y) * a + L::splat(b.y) * c) + L::splat(axis.y) * cz;
    z = (L::splat(t.z) * a + L::splat(b.z) * c) + L::splat(axis.z) * cz;
    normalize3(x, y, z);
}

/// render.cpp's sample_cosine(n, t, b, u1, u2), with n, t, b per lane.
template <class L>
inline void cosine_direction(L nx, L ny, L nz, L tx, L ty, L tz, L bx, L by, L bz, L u1, L u2,
                             L &x, L &y, L &z) {
    const L r = vsqrt(u1);
    L c, s;
    turn_sincos(u2, c, s);
    const L a = r * c, d = r * s, h = vsqrt(max0(L::splat(1.f) - u1));
    x = (tx * a + bx * d) + nx * h;
    y = (ty * a + by * d) + ny * h;
    z = (tz * a + bz * d) + nz * h;
    normalize3(x, y, z);
}

/// The studio fade of a camera ray's ground hit o + d t (trace_bounce): 1 where the squared
/// distance in the plane from the ground point exceeds fade_end2, else the smoothstep of
/// clamp(distance / fade - 1, 0, 1).
template <class L>
inline L ground_fade(L ox, L oy, L oz, L dx, L dy, L dz, L t, Vec3 gp, Vec3 gn, float fade, float fade_end2) {
    const L gx = (ox + dx * t) - L::splat(gp.x), gy = (oy + dy * t) - L::splat(gp.y),
            gz = (oz + dz * t) - L::splat(gp.z);
    const L dg = (gx * L::splat(gn.x) + gy * L::splat(gn.y)) + gz * L::splat(gn.z);
    const L qx = gx - L::splat(gn.x) * dg, qy = gy - L::splat(gn.y) * dg, qz = gz - L::splat(gn.z) * dg;
    const L d2 = (qx * qx + qy * qy) + qz * qz;
    L f = vsqrt(d2) / L::splat(fade) - L::splat(1.f);
    f = select(lt(f, L::splat(0.f)), L::splat(0.f), select(lt(L::splat(1.f), f), L::splat(1.f), f));
    f = f * f * (L::splat(3.f) - L::splat(2.f) * f);
    return select(gt(d2, L::splat(fade_end2)), L::splat(1.f), f);
}

/// A light's terms at a surface sample (trace_bounce): ndl = dot(n, l) and the specular lobe
/// specular * lobe_pow(max(0, dot(n, normalize(l - d))), shininess).
template <class L>
inline void light_terms(L nx, L ny, L nz, L lx, L ly, L lz, L dx, L dy, L dz, float specular,
                        float shininess, L &ndl, L &spec) {
    ndl = (nx * lx + ny * ly) + nz * lz;
    L hx = lx - dx, hy = ly - dy, hz = lz - dz;
    normalize3(hx, hy, hz);
    spec = L::splat(specular) * lobe_pow(max0((nx * hx + ny * hy) + nz * hz), shininess);
}

// ---- the passes over arrays --------------------------------------------------------------------

/// Runs `step(i, lane)` over i < n: four at a time where SSE2 is built (`four` true), one at a
/// time for the tail (or everything when `four` is false).
template <class Step>
inline void over_lanes(size_t n, bool four, Step step) {
    size_t i = 0;
#ifdef POINTVIZ_SHADING_LANES_SSE2
    if (four)
        for (; i + 4 <= n; i += 4) step(i, F4{});
#else
    (void)four;
#endif
    for (; i < n; ++i) step(i, F1{});
}

POINTVIZ_ISA_END
}  // namespace lanes
}  // namespace pointviz
