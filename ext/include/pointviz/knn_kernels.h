// pointviz — the inner loops of the all-points neighbour search (knn_each, knn.h), one set per
// instruction set, chosen at run time: the portable build (x86-64: SSE2) everywhere, AVX2 or
// AVX-512 where the CPU has them. Every set gives the same rows, bit for bit: the distances are the same
// operations in the same order (the build turns floating-point contraction off), and the
// selection is exact.
#pragma once

#include <cstddef>
#include <cstdint>

#include "pointviz/isa.h"

namespace pointviz {

/// The candidate and selection loops of one instruction set.
struct KnnKernels {
    Isa isa;
    const char *name;
    /// Writes to `out`, in order, the positions a in [0, m) of the boxes within squared
    /// distance rq of q (not farther: !(d > rq)); their corners in `lohi`, one coordinate at
    /// a time: lo x, lo y, lo z, hi x, hi y, hi z, m values each. Returns how many; writes up
    /// to 8 slots past the last one.
    size_t (*boxes)(const double *lohi, size_t m, const double *q, double rq, uint32_t *out);
    /// Appends to (d2, idx), from position `cnt` on, the squared distance and index of each
    /// stored point s in [b, e) (coordinates x[s], y[s], z[s]; index id[s]) whose squared
    /// distance to q is at most rq and whose index is not `self`, in the order of s; returns
    /// the new count. Writes up to 8 slots past the last one counted (the buffers need them).
    size_t (*near)(const double *x, const double *y, const double *z, const uint32_t *id,
                   uint32_t b, uint32_t e, const double *q, double rq, uint32_t self,
                   double *d2, uint32_t *idx, size_t cnt);
    /// The k smallest of `cnt` candidates (squared distances `d2`, finite, with 8 free slots
    /// after d2[cnt - 1]; distinct indices `id`) by (distance, index), written to `row` in
    /// ascending order; returns the k-th distance.
    double (*rank)(double *d2, const uint32_t *id, size_t cnt, uint32_t k, uint32_t *row);
};

/// The kernels of `isa` (Auto: the best this build and this CPU run: Avx512, Avx2 or Base).
/// Throws std::invalid_argument when `isa` is unavailable (Sse42 has no kernels of its own).
const KnnKernels &knn_kernels(Isa isa);

/// Whether knn_kernels(isa) has kernels of that set here (Auto, Base: always).
bool knn_kernels_available(Isa isa);

}  // namespace pointviz
