// pointviz — how the packet kernels (ext/src/packet_cast.cpp: closest hits,
// ext/src/packet_occlude.cpp: any hits) cut a batch of rays into groups: blocks of 2x4 pixels
// when the rays are rows of camera rays in raster order, else eight consecutive rays. Only the
// grouping depends on it, never a result (packet_trace.h's packet_covers decides per group).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <mutex>

#include "pointviz/cast_rows.h"
#include "pointviz/isa.h"
#include "pointviz/packet_trace.h"
#include "pointviz/parallel.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN
// Internal linkage, as cast_rows.h: each kernel unit gets its own copy.
namespace {

/// The length of the rows when `rays` look like camera rays in raster order (Camera.rays():
/// row by row, one origin): the first ray k at which the direction turns back towards the
/// first ray's (along a row it turns steadily away), k >= 4 and two rows in the batch; 0
/// otherwise. Only the grouping of the rays into packets depends on it, not a result:
/// packet_covers still decides which groups are coherent.
template <class T>
size_t raster_width(const T *rays, size_t n) {
    if (n < 16) return 0;
    auto cosine = [&](size_t k) {
        const T *a = rays + 3, *b = rays + 6 * k + 3;
        const double ab = double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2];
        const double bb = double(b[0]) * b[0] + double(b[1]) * b[1] + double(b[2]) * b[2];
        return ab / std::sqrt(bb);  // / |a|: the same for every k
    };
    double prev = cosine(1);
    for (size_t k = 2; 2 * k <= n; ++k) {
        const double c = cosine(k);
        if (!(c < prev)) return k >= 4 && c > prev ? k : 0;
        prev = c;
    }
    return 0;
}

/// Whether the batch's first kPacket rays are coherent (one origin, directions within
/// kPacketMinCos of the first): batches that do not start so (scattered rays) are not worth
/// grouping.
template <class T>
bool starts_coherent(const T *rays, size_t n) {
    if (n < size_t(kPacket)) return false;
    const T *f = rays;
    const double ff = double(f[3]) * f[3] + double(f[4]) * f[4] + double(f[5]) * f[5];
    for (size_t r = 1; r < size_t(kPacket); ++r) {
        const T *x = rays + 6 * r;
        if (!(x[0] == f[0] && x[1] == f[1] && x[2] == f[2])) return false;
        const double fx = double(f[3]) * x[3] + double(f[4]) * x[4] + double(f[5]) * x[5];
        const double xx = double(x[3]) * x[3] + double(x[4]) * x[4] + double(x[5]) * x[5];
        if (!(fx >= double(kPacketMinCos) * std::sqrt(ff * xx))) return false;
    }
    return true;
}

/// Runs `group(idx, k, centre, local)` over the batch in groups of at most kPacket rays on
/// `threads` threads — blocks of 2x4 pixels when the rays are rows of camera rays in raster
/// order (raster_width; a last single row in fours), else eight consecutive rays — and adds
/// the threads' sums to `stats`.
template <class T, class Group>
void for_groups(const T *rays, size_t n, int threads, BatchStats &stats, Group group) {
    std::mutex m;
    const size_t w = raster_width(rays, n);
    if (w == 0) {
        parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
            BatchStats local;
            size_t idx[kPacket];
            for (size_t g = b; g < e; g += kPacket) {
                const int k = int(std::min(e - g, size_t(kPacket)));
                for (int r = 0; r < k; ++r) idx[r] = g + size_t(r);
                group(idx, k, kRowCentre, local);
            }
            local.rays = e - b;
            merge(stats, local, m);
        });
        return;
    }
    // Rows of w pixels: two rows at a time.
    const size_t pairs = (n + 2 * w - 1) / (2 * w);
    parallel_for(pairs, std::max<size_t>(1, kRayGrain / (2 * w)), threads,
                 [&](size_t b, size_t e, int) {
        BatchStats local;
        size_t idx[kPacket];
        for (size_t p = b; p < e; ++p) {
            const size_t top = 2 * p * w, bottom = top + w;
            for (size_t c = 0; c < w; c += 4) {
                int k = 0;
                for (size_t row : {top, bottom})
                    for (size_t j = c; j < std::min(w, c + 4); ++j)
                        if (row + j < n) idx[k++] = row + j;
                group(idx, k, kBlockCentre, local);
                local.rays += size_t(k);
            }
        }
        merge(stats, local, m);
    });
}

}  // namespace
POINTVIZ_ISA_END
}  // namespace pointviz
