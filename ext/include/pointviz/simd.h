// pointviz — float lanes for the disk kernel (disk_kernel.h): eight (AVX2) or four (SSE2, part of
// every x86-64 CPU), and the scalar lane's matching operations, so that one kernel source serves
// one disk and several disks at a time.
#pragma once

#include <cmath>
#include <cstdint>

#include "pointviz/isa.h"

#if defined(__AVX2__) && !defined(POINTVIZ_NO_SIMD)
#include <immintrin.h>
#define POINTVIZ_AVX2 1
#elif defined(__SSE2__) && !defined(POINTVIZ_NO_SIMD)
#include <emmintrin.h>
#define POINTVIZ_SSE2 1
#endif

namespace pointviz {
POINTVIZ_ISA_BEGIN

#if defined(POINTVIZ_AVX2)

/// Eight floats in an AVX register. Comparisons give lane masks (all bits set where true).
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
inline F8 operator|(F8 a, F8 b) { return F8(_mm256_or_ps(a.v, b.v)); }
inline F8 operator<(F8 a, F8 b) { return F8(_mm256_cmp_ps(a.v, b.v, _CMP_LT_OQ)); }
inline F8 operator>(F8 a, F8 b) { return F8(_mm256_cmp_ps(a.v, b.v, _CMP_GT_OQ)); }
/// Lane-wise a < b ? a : b and a > b ? a : b (the scalar lane's vmin / vmax below).
inline F8 vmin(F8 a, F8 b) { return F8(_mm256_min_ps(a.v, b.v)); }
inline F8 vmax(F8 a, F8 b) { return F8(_mm256_max_ps(a.v, b.v)); }
inline F8 vsqrt(F8 a) { return F8(_mm256_sqrt_ps(a.v)); }
/// Lane-wise m ? a : b for a mask m.
inline F8 select(F8 m, F8 a, F8 b) { return F8(_mm256_blendv_ps(b.v, a.v, m.v)); }
/// One bit per lane of a mask, lane 0 lowest.
inline uint32_t movemask(F8 m) { return uint32_t(_mm256_movemask_ps(m.v)); }

#elif defined(POINTVIZ_SSE2)

/// Four floats in an SSE register. Comparisons give lane masks (all bits set where true).
struct F4 {
    __m128 v;
    F4() = default;
    explicit F4(__m128 x) : v(x) {}
    explicit F4(float s) : v(_mm_set1_ps(s)) {}
    void store(float *p) const { _mm_store_ps(p, v); }
};
inline F4 operator+(F4 a, F4 b) { return F4(_mm_add_ps(a.v, b.v)); }
inline F4 operator-(F4 a, F4 b) { return F4(_mm_sub_ps(a.v, b.v)); }
inline F4 operator*(F4 a, F4 b) { return F4(_mm_mul_ps(a.v, b.v)); }
inline F4 operator/(F4 a, F4 b) { return F4(_mm_div_ps(a.v, b.v)); }
inline F4 vabs(F4 a) { return F4(_mm_andnot_ps(_mm_set1_ps(-0.f), a.v)); }
inline F4 operator<=(F4 a, F4 b) { return F4(_mm_cmple_ps(a.v, b.v)); }
inline F4 operator>=(F4 a, F4 b) { return F4(_mm_cmpge_ps(a.v, b.v)); }
inline F4 operator&(F4 a, F4 b) { return F4(_mm_and_ps(a.v, b.v)); }
inline F4 operator|(F4 a, F4 b) { return F4(_mm_or_ps(a.v, b.v)); }
inline F4 operator<(F4 a, F4 b) { return F4(_mm_cmplt_ps(a.v, b.v)); }
inline F4 operator>(F4 a, F4 b) { return F4(_mm_cmpgt_ps(a.v, b.v)); }
/// Lane-wise a < b ? a : b and a > b ? a : b (the scalar lane's vmin / vmax below).
inline F4 vmin(F4 a, F4 b) { return F4(_mm_min_ps(a.v, b.v)); }
inline F4 vmax(F4 a, F4 b) { return F4(_mm_max_ps(a.v, b.v)); }
inline F4 vsqrt(F4 a) { return F4(_mm_sqrt_ps(a.v)); }
/// Lane-wise m ? a : b for a mask m.
inline F4 select(F4 m, F4 a, F4 b) { return F4(_mm_or_ps(_mm_and_ps(m.v, a.v), _mm_andnot_ps(m.v, b.v))); }
/// One bit per lane of a mask, lane 0 lowest.
inline uint32_t movemask(F4 m) { return uint32_t(_mm_movemask_ps(m.v)); }

#endif

/// The scalar lane: the same operations on one float (masks are bools).
inline float vabs(float a) { return std::fabs(a); }
inline uint32_t movemask(bool m) { return m ? 1u : 0u; }
inline float vmin(float a, float b) { return a < b ? a : b; }
inline float vmax(float a, float b) { return a > b ? a : b; }
inline float vsqrt(float a) { return std::sqrt(a); }
inline float select(bool m, float a, float b) { return m ? a : b; }

POINTVIZ_ISA_END
}  // namespace pointviz
