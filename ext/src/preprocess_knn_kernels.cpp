// pointviz — the candidate and selection loops of the all-points neighbour search, per
// instruction set (see knn_kernels.h).
#include "pointviz/knn_kernels.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#if defined(__SSE2__) && !defined(POINTVIZ_NO_SIMD)
#include <emmintrin.h>
#endif
// AVX2 and AVX-512 kernels: compiled with a target attribute on each function (not for the
// whole file), so the rest runs on any x86-64 CPU; chosen only where the CPU has AVX2, or
// AVX-512 F/VL/DQ.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(POINTVIZ_NO_SIMD)
#define POINTVIZ_KNN_SIMD 1
#include <immintrin.h>
#define POINTVIZ_TARGET_AVX2 __attribute__((target("avx2,popcnt")))
#define POINTVIZ_TARGET_AVX512 __attribute__((target("avx2,avx512f,avx512vl,avx512dq,popcnt")))
#endif

namespace pointviz {

namespace {

// ---- portable (x86-64: SSE2) ----

size_t near_base(const double *x, const double *y, const double *z, const uint32_t *id,
                 uint32_t b, uint32_t e, const double *q, double rq, uint32_t self, double *d2,
                 uint32_t *idx, size_t cnt) {
    // branch-free: every distance is written, the count advances over those that are near
    for (uint32_t s = b; s < e; ++s) {
        double dx = x[s] - q[0], dy = y[s] - q[1], dz = z[s] - q[2];
        double d = dx * dx + dy * dy + dz * dz;
        d2[cnt] = d;
        idx[cnt] = id[s];
        cnt += (d <= rq) & (id[s] != self);
    }
    return cnt;
}

/// boxes_base over the boxes from `first` on (positions still counted from 0).
size_t boxes_base_from(const double *lohi, size_t m, size_t first, const double *q, double rq,
                       uint32_t *out) {
    size_t cnt = 0;
    for (size_t a = first; a < m; ++a) {
        double d = 0;
        for (int j = 0; j < 3; ++j) {
            double e = std::max({lohi[j * m + a] - q[j], q[j] - lohi[(3 + j) * m + a], 0.0});
            d += e * e;
        }
        out[cnt] = uint32_t(a);
        cnt += !(d > rq);
    }
    return cnt;
}

size_t boxes_base(const double *lohi, size_t m, const double *q, double rq, uint32_t *out) {
    return boxes_base_from(lohi, m, 0, q, rq, out);
}

/// Each candidate's place is counted (how many come before it) instead of found by sorting:
/// the comparisons are independent of the data and vectorised, where nth_element + sort of a
/// few dozen keys mispredicted about every other comparison (CPU of the 31 neighbours of the
/// dragon's 469k raw points / of the 1M points of 8 sphere scans, one thread: 0.757 / 1.420 s
/// -> 0.653 / 1.135 s, the same tables).
double rank_base(double *d2, const uint32_t *id, size_t cnt, uint32_t k, uint32_t *row) {
    const size_t pairs = (cnt + 1) / 2;
    d2[cnt] = std::numeric_limits<double>::quiet_NaN();  // the odd slot: compares false
    double kth = 0;
    for (size_t a = 0; a < cnt; a += 2) {
        // below[h], equal[h]: the candidates closer than / as close as a + h
        uint64_t below[2], equal[2];
#if defined(__SSE2__) && !defined(POINTVIZ_NO_SIMD)
        // two candidates against two others at a time: compare masks are -1, so subtracting
        // them counts
        const __m128d v0 = _mm_set1_pd(d2[a]), v1 = _mm_set1_pd(d2[a + 1]);
        __m128i below0 = _mm_setzero_si128(), equal0 = _mm_setzero_si128();
        __m128i below1 = _mm_setzero_si128(), equal1 = _mm_setzero_si128();
        for (size_t b = 0; b < pairs; ++b) {
            const __m128d vb = _mm_loadu_pd(d2 + 2 * b);
            below0 = _mm_sub_epi64(below0, _mm_castpd_si128(_mm_cmplt_pd(vb, v0)));
            equal0 = _mm_sub_epi64(equal0, _mm_castpd_si128(_mm_cmpeq_pd(vb, v0)));
            below1 = _mm_sub_epi64(below1, _mm_castpd_si128(_mm_cmplt_pd(vb, v1)));
            equal1 = _mm_sub_epi64(equal1, _mm_castpd_si128(_mm_cmpeq_pd(vb, v1)));
        }
        uint64_t lanes[4][2];
        _mm_storeu_si128(reinterpret_cast<__m128i *>(lanes[0]), below0);
        _mm_storeu_si128(reinterpret_cast<__m128i *>(lanes[1]), below1);
        _mm_storeu_si128(reinterpret_cast<__m128i *>(lanes[2]), equal0);
        _mm_storeu_si128(reinterpret_cast<__m128i *>(lanes[3]), equal1);
        for (int h = 0; h < 2; ++h) {
            below[h] = lanes[h][0] + lanes[h][1];
            equal[h] = lanes[2 + h][0] + lanes[2 + h][1];
        }
#else
        for (int h = 0; h < 2; ++h) {
            below[h] = equal[h] = 0;
            for (size_t b = 0; b < 2 * pairs; ++b) {
                below[h] += d2[b] < d2[a + h];
                equal[h] += d2[b] == d2[a + h];
            }
        }
#endif
        for (size_t h = 0; h < 2 && a + h < cnt; ++h) {
            const double da = d2[a + h];
            uint64_t place = below[h];
            if (equal[h] > 1)  // ties (itself included): broken by index
                for (size_t b = 0; b < cnt; ++b) place += d2[b] == da && id[b] < id[a + h];
            if (place < k) {
                row[place] = id[a + h];
                if (place == k - 1) kth = da;
            }
        }
    }
    return kth;
}

/// The vector kernels' selection: candidates a .. a + lanes - 1 counted `place` (how many are
/// closer), those among the k nearest written to `row`; `seen` marks the places taken (counts
/// that are not all distinct mean ties, which rank_base breaks by index), `kth` gets the k-th
/// distance.
template <class Count>
inline void take_places(const Count *place, size_t a, size_t lanes, const double *d2,
                        const uint32_t *id, uint32_t k, uint32_t *row, uint64_t &seen,
                        double &kth) {
    for (size_t h = 0; h < lanes; ++h) {
        seen |= uint64_t(1) << place[h];
        if (place[h] < k) {
            row[place[h]] = id[a + h];
            if (place[h] == k - 1) kth = d2[a + h];
        }
    }
}

constexpr KnnKernels kBase{Isa::Base, "base", boxes_base, near_base, rank_base};

#if defined(POINTVIZ_KNN_SIMD)

// ---- AVX2: four candidates at a time ----

/// boxes_base's distances (the same operations in the same order), four boxes at a time.
POINTVIZ_TARGET_AVX2
size_t boxes_avx2(const double *lohi, size_t m, const double *q, double rq, uint32_t *out) {
    const __m256d zero = _mm256_setzero_pd(), r = _mm256_set1_pd(rq);
    __m256d qv[3];
    for (int j = 0; j < 3; ++j) qv[j] = _mm256_set1_pd(q[j]);
    size_t cnt = 0, a = 0;
    for (; a + 4 <= m; a += 4) {
        __m256d d = zero;
        for (int j = 0; j < 3; ++j) {
            const __m256d lo = _mm256_loadu_pd(lohi + j * m + a);
            const __m256d hi = _mm256_loadu_pd(lohi + (3 + j) * m + a);
            const __m256d e = _mm256_max_pd(
                _mm256_max_pd(_mm256_sub_pd(lo, qv[j]), _mm256_sub_pd(qv[j], hi)), zero);
            d = _mm256_add_pd(d, _mm256_mul_pd(e, e));
        }
        for (unsigned keep = unsigned(_mm256_movemask_pd(_mm256_cmp_pd(d, r, _CMP_NGT_UQ)));
             keep; keep &= keep - 1)
            out[cnt++] = uint32_t(a) + uint32_t(__builtin_ctz(keep));
    }
    return cnt + boxes_base_from(lohi, m, a, q, rq, out + cnt);
}

/// near_base's distances, four points at a time (the rest as near_base does them).
POINTVIZ_TARGET_AVX2
size_t near_avx2(const double *x, const double *y, const double *z, const uint32_t *id,
                 uint32_t b, uint32_t e, const double *q, double rq, uint32_t self, double *d2,
                 uint32_t *idx, size_t cnt) {
    const __m256d qx = _mm256_set1_pd(q[0]), qy = _mm256_set1_pd(q[1]);
    const __m256d qz = _mm256_set1_pd(q[2]), r = _mm256_set1_pd(rq);
    uint32_t s = b;
    for (; s + 4 <= e; s += 4) {
        const __m256d dx = _mm256_sub_pd(_mm256_loadu_pd(x + s), qx);
        const __m256d dy = _mm256_sub_pd(_mm256_loadu_pd(y + s), qy);
        const __m256d dz = _mm256_sub_pd(_mm256_loadu_pd(z + s), qz);
        const __m256d d = _mm256_add_pd(
            _mm256_add_pd(_mm256_mul_pd(dx, dx), _mm256_mul_pd(dy, dy)), _mm256_mul_pd(dz, dz));
        const unsigned near = unsigned(_mm256_movemask_pd(_mm256_cmp_pd(d, r, _CMP_LE_OQ)));
        double dd[4];
        _mm256_storeu_pd(dd, d);
        for (unsigned h = 0; h < 4; ++h) {
            d2[cnt] = dd[h];
            idx[cnt] = id[s + h];
            cnt += ((near >> h) & 1u) & unsigned(id[s + h] != self);
        }
    }
    return near_base(x, y, z, id, s, e, q, rq, self, d2, idx, cnt);
}

/// rank_avx512's count (without ties), four candidates at a time.
POINTVIZ_TARGET_AVX2
double rank_avx2(double *d2, const uint32_t *id, size_t cnt, uint32_t k, uint32_t *row) {
    if (cnt > 64) return rank_base(d2, id, cnt, k, row);
    double kth = 0;
    uint64_t seen = 0;  // the places taken
    const __m256d none = _mm256_set1_pd(std::numeric_limits<double>::quiet_NaN());
    for (size_t a = 0; a < cnt; a += 4) {
        // lanes past the end: NaN, which compares false
        __m256d va = none;
        if (cnt - a >= 4) {
            va = _mm256_loadu_pd(d2 + a);
        } else {
            double t[4];
            _mm256_storeu_pd(t, none);
            for (size_t h = 0; a + h < cnt; ++h) t[h] = d2[a + h];
            va = _mm256_loadu_pd(t);
        }
        // compare masks are -1: subtracting them counts
        __m256i below = _mm256_setzero_si256();
        for (size_t b = 0; b < cnt; ++b)
            below = _mm256_sub_epi64(
                below, _mm256_castpd_si256(_mm256_cmp_pd(_mm256_set1_pd(d2[b]), va, _CMP_LT_OQ)));
        uint64_t place[4];
        _mm256_storeu_si256(reinterpret_cast<__m256i *>(place), below);
        take_places(place, a, std::min<size_t>(4, cnt - a), d2, id, k, row, seen, kth);
    }
    if (size_t(__builtin_popcountll(seen)) != cnt) return rank_base(d2, id, cnt, k, row);
    return kth;
}

constexpr KnnKernels kAvx2{Isa::Avx2, "avx2", boxes_avx2, near_avx2, rank_avx2};

bool cpu_has_avx2() {
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("popcnt");
}

// ---- AVX-512: eight candidates at a time ----

/// boxes_base's distances (the same operations in the same order), eight boxes at a time.
POINTVIZ_TARGET_AVX512
size_t boxes_avx512(const double *lohi, size_t m, const double *q, double rq, uint32_t *out) {
    const __m512d zero = _mm512_setzero_pd(), r = _mm512_set1_pd(rq);
    __m512d qv[3];
    for (int j = 0; j < 3; ++j) qv[j] = _mm512_set1_pd(q[j]);
    const __m256i lane = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    size_t cnt = 0;
    for (size_t a = 0; a < m; a += 8) {
        const __mmask8 in = m - a >= 8 ? __mmask8(0xff) : __mmask8((1u << (m - a)) - 1);
        __m512d d = zero;
        for (int j = 0; j < 3; ++j) {
            const __m512d lo = _mm512_maskz_loadu_pd(in, lohi + j * m + a);
            const __m512d hi = _mm512_maskz_loadu_pd(in, lohi + (3 + j) * m + a);
            // (maskz_max: the plain max trips a false "uninitialised" warning in GCC 12's header)
            const __m512d out_lo = _mm512_sub_pd(lo, qv[j]), out_hi = _mm512_sub_pd(qv[j], hi);
            const __m512d e = _mm512_maskz_max_pd(
                __mmask8(0xff), _mm512_maskz_max_pd(__mmask8(0xff), out_lo, out_hi), zero);
            d = _mm512_add_pd(d, _mm512_mul_pd(e, e));
        }
        const __mmask8 keep = _mm512_mask_cmp_pd_mask(in, d, r, _CMP_NGT_UQ);
        const __m256i idx = _mm256_add_epi32(lane, _mm256_set1_epi32(int(a)));
        _mm256_storeu_si256(reinterpret_cast<__m256i *>(out + cnt),
                            _mm256_maskz_compress_epi32(keep, idx));
        cnt += size_t(__builtin_popcount(unsigned(keep)));
    }
    return cnt;
}

/// The same distances as near_base (the same operations in the same order), eight points at a
/// time; the near ones are packed in a register and stored whole (a packing store to memory is
/// slow on some CPUs), so up to 8 slots past the count are written.
POINTVIZ_TARGET_AVX512
size_t near_avx512(const double *x, const double *y, const double *z, const uint32_t *id,
                   uint32_t b, uint32_t e, const double *q, double rq, uint32_t self,
                   double *d2, uint32_t *idx, size_t cnt) {
    const __m512d qx = _mm512_set1_pd(q[0]), qy = _mm512_set1_pd(q[1]);
    const __m512d qz = _mm512_set1_pd(q[2]);
    const __m512d r = _mm512_set1_pd(rq);
    const __m256i me = _mm256_set1_epi32(int(self));
    for (uint32_t s = b; s < e; s += 8) {
        const __mmask8 in = e - s >= 8 ? __mmask8(0xff) : __mmask8((1u << (e - s)) - 1);
        const __m512d dx = _mm512_sub_pd(_mm512_maskz_loadu_pd(in, x + s), qx);
        const __m512d dy = _mm512_sub_pd(_mm512_maskz_loadu_pd(in, y + s), qy);
        const __m512d dz = _mm512_sub_pd(_mm512_maskz_loadu_pd(in, z + s), qz);
        const __m512d d = _mm512_add_pd(
            _mm512_add_pd(_mm512_mul_pd(dx, dx), _mm512_mul_pd(dy, dy)), _mm512_mul_pd(dz, dz));
        const __m256i ids = _mm256_maskz_loadu_epi32(in, id + s);
        const __mmask8 keep = _mm512_mask_cmp_pd_mask(in, d, r, _CMP_LE_OQ) &
                              _mm256_cmpneq_epi32_mask(ids, me);
        _mm512_storeu_pd(d2 + cnt, _mm512_maskz_compress_pd(keep, d));
        _mm256_storeu_si256(reinterpret_cast<__m256i *>(idx + cnt),
                            _mm256_maskz_compress_epi32(keep, ids));
        cnt += size_t(__builtin_popcount(unsigned(keep)));
    }
    return cnt;
}

/// rank_base's count for eight candidates at a time (one per lane), against each candidate in
/// turn, without ties: distinct distances have distinct counts, so when the counts are not
/// all distinct some distances are equal, and rank_base (which breaks ties by index) answers.
POINTVIZ_TARGET_AVX512
double rank_avx512(double *d2, const uint32_t *id, size_t cnt, uint32_t k, uint32_t *row) {
    if (cnt > 64) return rank_base(d2, id, cnt, k, row);
    double kth = 0;
    uint64_t seen = 0;  // the places taken
    const __m256i one = _mm256_set1_epi32(1);
    for (size_t a = 0; a < cnt; a += 8) {
        const __mmask8 in = cnt - a >= 8 ? __mmask8(0xff) : __mmask8((1u << (cnt - a)) - 1);
        const __m512d va = _mm512_maskz_loadu_pd(in, d2 + a);
        __m256i below = _mm256_setzero_si256();
        for (size_t b = 0; b < cnt; ++b)
            below = _mm256_mask_add_epi32(
                below, _mm512_cmp_pd_mask(_mm512_set1_pd(d2[b]), va, _CMP_LT_OQ), below, one);
        uint32_t place[8];
        _mm256_storeu_si256(reinterpret_cast<__m256i *>(place), below);
        take_places(place, a, std::min<size_t>(8, cnt - a), d2, id, k, row, seen, kth);
    }
    if (size_t(__builtin_popcountll(seen)) != cnt) return rank_base(d2, id, cnt, k, row);
    return kth;
}

constexpr KnnKernels kAvx512{Isa::Avx512, "avx512", boxes_avx512, near_avx512, rank_avx512};

bool cpu_has_avx512() {
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("popcnt");
}

#endif

}  // namespace

bool knn_kernels_available(Isa isa) {
    switch (isa) {
        case Isa::Auto:
        case Isa::Base: return true;
#if defined(POINTVIZ_KNN_SIMD)
        case Isa::Avx2: return cpu_has_avx2();
        case Isa::Avx512: return cpu_has_avx512();
#endif
        default: return false;
    }
}

const KnnKernels &knn_kernels(Isa isa) {
#if defined(POINTVIZ_KNN_SIMD)
    // the CPU does not change while the process runs: decided once
    static const bool avx512 = cpu_has_avx512(), avx2 = cpu_has_avx2();
    if ((isa == Isa::Auto || isa == Isa::Avx512) && avx512) return kAvx512;
    if ((isa == Isa::Auto || isa == Isa::Avx2) && avx2) return kAvx2;
#endif
    if (isa == Isa::Auto || isa == Isa::Base) return kBase;
    throw std::invalid_argument("knn kernels: instruction set not available on this build or CPU");
}

}  // namespace pointviz
