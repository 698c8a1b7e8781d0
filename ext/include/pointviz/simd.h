// pointviz — four floats at a time: the lane type of the wide tree's child tests.
//
// SSE2 is part of every x86-64 CPU, so this path needs no run-time dispatch; other targets get
// the same operations on plain arrays. min/max follow std::min/std::max exactly (including
// which operand wins on NaN), so the vector tests give the scalar tests' results bit for bit.
#pragma once

#include "pointviz/isa.h"

#include <cmath>
#include <cstdint>

#if (defined(__SSE2__) || defined(_M_X64)) && !defined(POINTVIZ_NO_SIMD)
#include <emmintrin.h>
#define POINTVIZ_SSE2 1
#endif
#if defined(__AVX2__) && !defined(POINTVIZ_NO_SIMD)
#include <immintrin.h>
#define POINTVIZ_AVX2 1
#endif

namespace pointviz {

/// Lanes of the wide tree's nodes.
constexpr int kWide = 4;

POINTVIZ_ISA_BEGIN

#if defined(POINTVIZ_SSE2)

/// Four floats in an SSE register.
struct F4 {
    __m128 v;
    F4() = default;
    explicit F4(__m128 x) : v(x) {}
    explicit F4(float s) : v(_mm_set1_ps(s)) {}
    static F4 load(const float *p) { return F4(_mm_load_ps(p)); }
    void store(float *p) const { _mm_store_ps(p, v); }
};
inline F4 operator+(F4 a, F4 b) { return F4(_mm_add_ps(a.v, b.v)); }
inline F4 operator-(F4 a, F4 b) { return F4(_mm_sub_ps(a.v, b.v)); }
inline F4 operator*(F4 a, F4 b) { return F4(_mm_mul_ps(a.v, b.v)); }
inline F4 operator/(F4 a, F4 b) { return F4(_mm_div_ps(a.v, b.v)); }
/// std::min(a, b) per lane: (b < a) ? b : a.
inline F4 vmin(F4 a, F4 b) { return F4(_mm_min_ps(b.v, a.v)); }
/// std::max(a, b) per lane: (a < b) ? b : a.
inline F4 vmax(F4 a, F4 b) { return F4(_mm_max_ps(b.v, a.v)); }
inline F4 vsqrt(F4 a) { return F4(_mm_sqrt_ps(a.v)); }
inline F4 vabs(F4 a) { return F4(_mm_andnot_ps(_mm_set1_ps(-0.f), a.v)); }
/// Lane masks (all bits set where true).
inline F4 operator<=(F4 a, F4 b) { return F4(_mm_cmple_ps(a.v, b.v)); }
inline F4 operator>(F4 a, F4 b) { return F4(_mm_cmpgt_ps(a.v, b.v)); }
inline F4 operator&(F4 a, F4 b) { return F4(_mm_and_ps(a.v, b.v)); }
inline F4 operator|(F4 a, F4 b) { return F4(_mm_or_ps(a.v, b.v)); }
/// mask ? a : b per lane.
inline F4 select(F4 mask, F4 a, F4 b) {
    return F4(_mm_or_ps(_mm_and_ps(mask.v, a.v), _mm_andnot_ps(mask.v, b.v)));
}
/// One bit per lane of a mask, lane 0 lowest.
inline uint32_t movemask(F4 m) { return uint32_t(_mm_movemask_ps(m.v)); }

#else

/// Four floats in an array (targets without SSE2).
struct F4 {
    alignas(16) float v[4];
    F4() = default;
    explicit F4(float s) { v[0] = v[1] = v[2] = v[3] = s; }
    static F4 load(const float *p) {
        F4 r;
        for (int k = 0; k < 4; ++k) r.v[k] = p[k];
        return r;
    }
    void store(float *p) const {
        for (int k = 0; k < 4; ++k) p[k] = v[k];
    }
};
template <class Op>
inline F4 lanewise(F4 a, F4 b, Op op) {
    F4 r;
    for (int k = 0; k < 4; ++k) r.v[k] = op(a.v[k], b.v[k]);
    return r;
}
inline float mask_of(bool b) {
    uint32_t u = b ? 0xffffffffu : 0u;
    float f;
    __builtin_memcpy(&f, &u, 4);
    return f;
}
inline uint32_t bits_of(float f) {
    uint32_t u;
    __builtin_memcpy(&u, &f, 4);
    return u;
}
inline F4 operator+(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return x + y; }); }
inline F4 operator-(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return x - y; }); }
inline F4 operator*(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return x * y; }); }
inline F4 operator/(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return x / y; }); }
inline F4 vmin(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return y < x ? y : x; }); }
inline F4 vmax(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return x < y ? y : x; }); }
inline F4 vsqrt(F4 a) {
    for (float &x : a.v) x = std::sqrt(x);
    return a;
}
inline F4 vabs(F4 a) {
    for (float &x : a.v) x = std::fabs(x);
    return a;
}
inline F4 operator<=(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return mask_of(x <= y); }); }
inline F4 operator>(F4 a, F4 b) { return lanewise(a, b, [](float x, float y) { return mask_of(x > y); }); }
inline F4 operator&(F4 a, F4 b) {
    return lanewise(a, b, [](float x, float y) { return mask_of(bits_of(x) & bits_of(y)); });
}
inline F4 operator|(F4 a, F4 b) {
    return lanewise(a, b, [](float x, float y) { return mask_of(bits_of(x) | bits_of(y)); });
}
inline F4 select(F4 m, F4 a, F4 b) {
    F4 r;
    for (int k = 0; k < 4; ++k) r.v[k] = bits_of(m.v[k]) ? a.v[k] : b.v[k];
    return r;
}
inline uint32_t movemask(F4 m) {
    uint32_t r = 0;
    for (int k = 0; k < 4; ++k) r |= (bits_of(m.v[k]) >> 31) << k;
    return r;
}

#endif

#if defined(POINTVIZ_AVX2)

/// Eight floats in an AVX register (the disks of a leaf, disk_kernel.h).
struct F8 {
    __m256 v;
    F8() = default;
    explicit F8(__m256 x) : v(x) {}
    explicit F8(float s) : v(_mm256_set1_ps(s)) {}
    void store(float *p) const { _mm256_store_ps(p, v); }
};
inline F8 operator+(F8 a, F8 b) { return F8(_mm256_add_ps(a.v, b.v)); }
inline F8 operator-(F8 a, F8 b) { return F8(_mm256_sub_ps(a.v, b.v)); }
inline F8 operator*(F8 a, F8 b) { return F8(_mm256_mul_ps(a.v, b.v)); }
inline F8 operator/(F8 a, F8 b) { return F8(_mm256_div_ps(a.v, b.v)); }
inline F8 vabs(F8 a) { return F8(_mm256_andnot_ps(_mm256_set1_ps(-0.f), a.v)); }
inline F8 operator<=(F8 a, F8 b) { return F8(_mm256_cmp_ps(a.v, b.v, _CMP_LE_OQ)); }
inline F8 operator>=(F8 a, F8 b) { return F8(_mm256_cmp_ps(a.v, b.v, _CMP_GE_OQ)); }
inline F8 operator&(F8 a, F8 b) { return F8(_mm256_and_ps(a.v, b.v)); }
inline uint32_t movemask(F8 m) { return uint32_t(_mm256_movemask_ps(m.v)); }

#endif

/// The scalar lane: the same operations on one float (masks are bools).
inline float vabs(float a) { return std::fabs(a); }

POINTVIZ_ISA_END

}  // namespace pointviz
