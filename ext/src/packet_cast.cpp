// pointviz — the batch queries of one instruction set (closest and any hits) that trace
// coherent groups of rays as packets (packet_cast.h, packet_trace.h). Compiled once per instruction set alongside cast.cpp
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

/// Any hits of the rays `idx[0, k)` of the batch (in [t_min, t_max[i]] in the caller's
/// units, two-sided) as one group: a packet when packet_covers them, else one at a time. Writes
/// every ray's answer and adds it to `local`.
template <class T>
void occlude_group(const SurfelTree &tree, const T *rays, const float *t_max, const size_t *idx,
                   int k, const TraceOptions &opt, const LodGates &gates, float t_min,
                   float pixel_angle, uint32_t centre, uint8_t *hit, BatchStats &local) {
    Ray ray[kPacket];
    bool ok[kPacket];
    bool valid = true;
    for (int r = 0; r < k; ++r) {
        const size_t i = idx[r];
        const double len = local_ray(tree, rays + 6 * i, ray[r]);
        ok[r] = len != 0.0 && !std::isnan(t_max[i]);
        valid = valid && ok[r];
        if (!ok[r]) continue;
        ray[r].tmin = float(double(t_min) * len);
        ray[r].tmax = float(double(t_max[i]) * len);
        ray[r].spread = pixel_angle;
    }
    uint8_t h[kPacket];
    const bool packet = valid && packet_covers(tree, ray, k, opt, false);
    if (packet) any_hits_packet(tree, ray, k, opt, gates, false, h, centre);
    for (int r = 0; r < k; ++r) {
        const size_t i = idx[r];
        hit[i] = 0;
        if (!ok[r]) {
            ++local.invalid;
            local.first_invalid = std::min(local.first_invalid, i);
            continue;
        }
        NoStats ns;
        const bool a = packet ? h[r] != 0 : any_hit(tree, ray[r], opt, gates, false, ns);
        hit[i] = a;
        local.hits += a;
    }
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
    const LodGates gates = lod_gates(opt);
    for_groups(rays, n, threads, stats,
               [&](const size_t *idx, int k, uint32_t centre, BatchStats &local) {
                   trace_group(tree, rays, idx, k, opt, gates, pixel_angle, centre, out, local);
               });
    return true;
}

template <class T>
bool occluded_packets(const SurfelTree &tree, const T *rays, const float *t_max, size_t n,
                      const TraceOptions &opt, float t_min, float pixel_angle, int threads,
                      uint8_t *hit, bool, BatchStats &stats) {
    if (!starts_coherent(rays, n)) return false;
    const LodGates gates = lod_gates(opt);
    for_groups(rays, n, threads, stats,
               [&](const size_t *idx, int k, uint32_t centre, BatchStats &local) {
                   occlude_group(tree, rays, t_max, idx, k, opt, gates, t_min, pixel_angle,
                                 centre, hit, local);
               });
    return true;
}

template bool cast_packets<float>(const SurfelTree &, const float *, size_t, const TraceOptions &,
                                  float, int, CastOutput, bool, BatchStats &);
template bool cast_packets<double>(const SurfelTree &, const double *, size_t,
                                   const TraceOptions &, float, int, CastOutput, bool, BatchStats &);
template bool occluded_packets<float>(const SurfelTree &, const float *, const float *, size_t,
                                      const TraceOptions &, float, float, int, uint8_t *, bool,
                                      BatchStats &);
template bool occluded_packets<double>(const SurfelTree &, const double *, const float *, size_t,
                                       const TraceOptions &, float, float, int, uint8_t *, bool,
                                       BatchStats &);

POINTVIZ_ISA_END
}  // namespace pointviz
