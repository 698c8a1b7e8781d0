// pointviz — the batch queries of one instruction set that trace coherent groups of rays as
// packets (packet_cast.h, packet_trace.h). Compiled once per instruction set alongside cast.cpp
// (ext/CMakeLists.txt; POINTVIZ_ISA_NS names the inline namespace, isa.h), and kept out of
// cast.cpp so that the single-ray traversal there keeps its own code generation.
#include "pointviz/packet_cast.h"

#include <algorithm>
#include <cmath>
#include <mutex>

#include "pointviz/cast_rows.h"
#include "pointviz/packet_trace.h"
#include "pointviz/parallel.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace {

/// Rays converted and traced together: a few packets' worth, on the stack.
constexpr size_t kPacketBlock = 64;

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

/// Closest hits of the rays `idx[0, k)` of the batch as one group: a packet (rays in the order
/// given; `centre`: its middle rays, packet_key_ray) when packet_covers them, else one at a
/// time. Writes every ray's output and adds it to `local`.
template <class T>
void trace_group(const SurfelTree &tree, const T *rays, const size_t *idx, int k,
                 const TraceOptions &opt, const LodGates &gates, float pixel_angle,
                 uint32_t centre, const CastOutput &out, BatchStats &local) {
    Ray ray[kPacket];
    double len[kPacket];
    SurfaceHit h[kPacket];
    bool valid = true;
    for (int r = 0; r < k; ++r) {
        len[r] = local_ray(tree, rays + 6 * idx[r], ray[r]);
        ray[r].spread = pixel_angle;
        valid = valid && len[r] != 0.0;
    }
    const bool packet = valid && packet_covers(tree, ray, k, opt);
    if (packet) closest_hits_packet(tree, ray, k, opt, gates, h, centre);
    for (int r = 0; r < k; ++r) {
        const size_t i = idx[r];
        double rd[6];
        for (int c = 0; c < 6; ++c) rd[c] = double(rays[6 * i + c]);
        bool hit = false;
        if (len[r] == 0.0) {
            ++local.invalid;
            local.first_invalid = std::min(local.first_invalid, i);
        } else if (packet) {
            hit = h[r].t != kInf;
        } else {
            NoStats ns;
            hit = closest_hit(tree, ray[r], opt, gates, h[r], ns);
        }
        local.hits += hit;
        write_hit(out, i, hit, h[r], len[r], rd, tree);
    }
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

}  // namespace

template <class T>
bool cast_packets(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
                  float pixel_angle, int threads, CastOutput out, bool, BatchStats &stats) {
    if (!starts_coherent(rays, n)) return false;
    std::mutex m;
    const LodGates gates = lod_gates(opt);
    const size_t w = raster_width(rays, n);
    if (w == 0) {
        // Groups of eight consecutive rays.
        parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
            BatchStats local;
            size_t idx[kPacket];
            for (size_t g = b; g < e; g += kPacket) {
                const int k = int(std::min(e - g, size_t(kPacket)));
                for (int r = 0; r < k; ++r) idx[r] = g + size_t(r);
                trace_group(tree, rays, idx, k, opt, gates, pixel_angle, kRowCentre, out, local);
            }
            local.rays = e - b;
            merge(stats, local, m);
        });
        return true;
    }
    // Rows of w pixels: blocks of 2x4 pixels, two rows at a time (a last single row in fours).
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
                trace_group(tree, rays, idx, k, opt, gates, pixel_angle, kBlockCentre, out, local);
                local.rays += size_t(k);
            }
        }
        merge(stats, local, m);
    });
    return true;
}

template bool cast_packets<float>(const SurfelTree &, const float *, size_t, const TraceOptions &,
                                  float, int, CastOutput, bool, BatchStats &);
template bool cast_packets<double>(const SurfelTree &, const double *, size_t,
                                   const TraceOptions &, float, int, CastOutput, bool, BatchStats &);

POINTVIZ_ISA_END
}  // namespace pointviz
