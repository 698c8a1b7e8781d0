// pointviz — the disks of one leaf (up to eight) tested at once: eight lanes with AVX2, twice four
// with SSE2 (the base and SSE4.2 kernels, dispatch.h). A surfel is exactly eight floats, so the
// leaf loads as the rows of an 8x8 block (or two 4x4 blocks per four surfels) whose transpose is
// the structure-of-arrays the disk kernel (disk_kernel.h) takes. Without SIMD (POINTVIZ_NO_SIMD)
// the same kernel runs one disk at a time (trace.h).
#pragma once

#include <cstdint>

#include "pointviz/disk_kernel.h"
#include "pointviz/isa.h"
#include "pointviz/simd.h"
#include "pointviz/surfel.h"

#if defined(POINTVIZ_AVX2) || defined(POINTVIZ_SSE2)
#define POINTVIZ_LEAF_SIMD 1
#endif

namespace pointviz {
POINTVIZ_ISA_BEGIN

#if defined(POINTVIZ_LEAF_SIMD)

/// Results of up to eight ray–disk tests: a bit per disk hit, and each lane's t, (d/r)^2 and
/// facing: disk_lanes (disk_kernel.h) on eight lanes.
struct LeafHits {
    uint32_t mask;
    alignas(32) float t[8], u2[8], facing[8];
};

#if defined(POINTVIZ_AVX2)

inline void transpose8(__m256 &r0, __m256 &r1, __m256 &r2, __m256 &r3, __m256 &r4, __m256 &r5,
                       __m256 &r6, __m256 &r7) {
    __m256 t0 = _mm256_unpacklo_ps(r0, r1), t1 = _mm256_unpackhi_ps(r0, r1);
    __m256 t2 = _mm256_unpacklo_ps(r2, r3), t3 = _mm256_unpackhi_ps(r2, r3);
    __m256 t4 = _mm256_unpacklo_ps(r4, r5), t5 = _mm256_unpackhi_ps(r4, r5);
    __m256 t6 = _mm256_unpacklo_ps(r6, r7), t7 = _mm256_unpackhi_ps(r6, r7);
    __m256 s0 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 s1 = _mm256_shuffle_ps(t0, t2, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 s2 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 s3 = _mm256_shuffle_ps(t1, t3, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 s4 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 s5 = _mm256_shuffle_ps(t4, t6, _MM_SHUFFLE(3, 2, 3, 2));
    __m256 s6 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(1, 0, 1, 0));
    __m256 s7 = _mm256_shuffle_ps(t5, t7, _MM_SHUFFLE(3, 2, 3, 2));
    r0 = _mm256_permute2f128_ps(s0, s4, 0x20);
    r1 = _mm256_permute2f128_ps(s1, s5, 0x20);
    r2 = _mm256_permute2f128_ps(s2, s6, 0x20);
    r3 = _mm256_permute2f128_ps(s3, s7, 0x20);
    r4 = _mm256_permute2f128_ps(s0, s4, 0x31);
    r5 = _mm256_permute2f128_ps(s1, s5, 0x31);
    r6 = _mm256_permute2f128_ps(s2, s6, 0x31);
    r7 = _mm256_permute2f128_ps(s3, s7, 0x31);
}

/// Tests `ray` against surfels [first, first + count), count in 1..8.
inline void intersect_leaf8(const Ray &ray, const Surfel *first, uint32_t count, float tmax,
                            bool cull, LeafHits &out) {
    const float *base = reinterpret_cast<const float *>(first);
    __m256 px, py, pz, rr, nx, ny, nz, col;
    __m256 *rows[8] = {&px, &py, &pz, &rr, &nx, &ny, &nz, &col};
    for (uint32_t k = 0; k < 8; ++k)  // lanes past the leaf repeat its first surfel (masked)
        *rows[k] = _mm256_loadu_ps(base + 8 * (k < count ? k : 0));
    transpose8(px, py, pz, rr, nx, ny, nz, col);
    F8 t, u2, facing;
    const F8 ok = disk_lanes<F8>(F8(px), F8(py), F8(pz), F8(rr), F8(nx), F8(ny), F8(nz), ray, tmax,
                                 cull, t, u2, facing);
    out.mask = movemask(ok) & ((1u << count) - 1u);
    if (out.mask == 0) return;
    t.store(out.t);
    u2.store(out.u2);
    facing.store(out.facing);
}

#else  // SSE2: the leaf as two groups of four lanes

/// Tests `ray` against surfels [first, first + count), count in 1..8. A surfel's two halves,
/// (p, r) and (n, rgba), load as rows of two 4x4 blocks whose transposes are the lanes.
inline void intersect_leaf8(const Ray &ray, const Surfel *first, uint32_t count, float tmax,
                            bool cull, LeafHits &out) {
    const float *base = reinterpret_cast<const float *>(first);
    out.mask = 0;
    for (uint32_t g = 0; g < count; g += 4) {
        __m128 a[4], n[4];
        for (uint32_t k = 0; k < 4; ++k) {  // lanes past the leaf repeat its first surfel (masked)
            const float *s = base + 8 * (g + k < count ? g + k : 0);
            a[k] = _mm_loadu_ps(s);
            n[k] = _mm_loadu_ps(s + 4);
        }
        _MM_TRANSPOSE4_PS(a[0], a[1], a[2], a[3]);
        _MM_TRANSPOSE4_PS(n[0], n[1], n[2], n[3]);
        F4 t, u2, facing;
        const F4 ok = disk_lanes<F4>(F4(a[0]), F4(a[1]), F4(a[2]), F4(a[3]), F4(n[0]), F4(n[1]),
                                     F4(n[2]), ray, tmax, cull, t, u2, facing);
        const uint32_t lanes = count - g < 4 ? count - g : 4;
        const uint32_t m = movemask(ok) & ((1u << lanes) - 1u);
        if (m == 0) continue;
        out.mask |= m << g;
        t.store(out.t + g);
        u2.store(out.u2 + g);
        facing.store(out.facing + g);
    }
}

#endif  // POINTVIZ_AVX2

#endif

POINTVIZ_ISA_END
}  // namespace pointviz
