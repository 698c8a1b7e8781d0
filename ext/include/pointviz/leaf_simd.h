// pointviz — the disks of one leaf tested eight at a time (AVX2). A surfel is exactly eight
// floats, so eight of them load as the rows of an 8x8 block whose transpose is the
// structure-of-arrays the vector test needs. Without AVX2 the scalar loop in trace.h is used.
#pragma once

#include <cstdint>

#include "pointviz/surfel.h"

#if defined(__AVX2__)
#include <immintrin.h>
#define POINTVIZ_LEAF_SIMD 1
#endif

namespace pointviz {

#if defined(POINTVIZ_LEAF_SIMD)

/// Results of up to eight ray–disk tests: a bit per disk hit, and each lane's t, (d/r)^2 and
/// facing. Same rejections as intersect_disk (culling, parallel rays, t-interval, radius).
struct LeafHits {
    uint32_t mask;
    alignas(32) float t[8], u2[8], facing[8];
};

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
    const __m256 dx = _mm256_set1_ps(ray.d.x), dy = _mm256_set1_ps(ray.d.y),
                 dz = _mm256_set1_ps(ray.d.z);
    const __m256 ox = _mm256_set1_ps(ray.o.x), oy = _mm256_set1_ps(ray.o.y),
                 oz = _mm256_set1_ps(ray.o.z);
    __m256 facing = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(nx, dx), _mm256_mul_ps(ny, dy)),
                                  _mm256_mul_ps(nz, dz));
    __m256 pox = _mm256_sub_ps(px, ox), poy = _mm256_sub_ps(py, oy), poz = _mm256_sub_ps(pz, oz);
    __m256 num = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(pox, nx), _mm256_mul_ps(poy, ny)),
                               _mm256_mul_ps(poz, nz));
    __m256 t = _mm256_div_ps(num, facing);
    __m256 qx = _mm256_sub_ps(_mm256_mul_ps(dx, t), pox);
    __m256 qy = _mm256_sub_ps(_mm256_mul_ps(dy, t), poy);
    __m256 qz = _mm256_sub_ps(_mm256_mul_ps(dz, t), poz);
    __m256 q2 = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(qx, qx), _mm256_mul_ps(qy, qy)),
                              _mm256_mul_ps(qz, qz));
    __m256 r2 = _mm256_mul_ps(rr, rr);
    const __m256 abs_mask = _mm256_castsi256_ps(_mm256_set1_epi32(0x7fffffff));
    __m256 ok = _mm256_cmp_ps(_mm256_and_ps(facing, abs_mask), _mm256_set1_ps(kParallelCos), _CMP_GE_OQ);
    if (cull) ok = _mm256_and_ps(ok, _mm256_cmp_ps(facing, _mm256_setzero_ps(), _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(t, _mm256_set1_ps(ray.tmin), _CMP_GE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(t, _mm256_set1_ps(tmax), _CMP_LE_OQ));
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(q2, r2, _CMP_LE_OQ));
    out.mask = uint32_t(_mm256_movemask_ps(ok)) & ((1u << count) - 1u);
    if (out.mask == 0) return;
    _mm256_store_ps(out.t, t);
    _mm256_store_ps(out.u2, _mm256_div_ps(q2, r2));
    _mm256_store_ps(out.facing, facing);
}

#endif

}  // namespace pointviz
