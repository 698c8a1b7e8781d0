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
/// One bit per lane of a mask, lane 0 lowest.
inline uint32_t movemask(F4 m) { return uint32_t(_mm_movemask_ps(m.v)); }

#endif

/// The scalar lane: the same operations on one float (masks are bools).
inline float vabs(float a) { return std::fabs(a); }

POINTVIZ_ISA_END
}  // namespace pointviz
