// pointviz — the any-hit batch queries of one instruction set that trace coherent groups of rays
// as packets (packet_cast.h, packet_trace.h). Compiled once per instruction set as
// packet_cast.cpp is (ext/CMakeLists.txt), and kept out of it: sharing a unit with the any-hit
// packets, the closest-hit packet loop's helpers are no longer inlined (3-5 % slower).
#include "pointviz/packet_cast.h"

#include <algorithm>
#include <cmath>

#include "pointviz/cast_rows.h"
#include "pointviz/packet_groups.h"
#include "pointviz/packet_trace.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace {

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

}  // namespace

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

template bool occluded_packets<float>(const SurfelTree &, const float *, const float *, size_t,
                                      const TraceOptions &, float, float, int, uint8_t *, bool,
                                      BatchStats &);
template bool occluded_packets<double>(const SurfelTree &, const double *, const float *, size_t,
                                       const TraceOptions &, float, float, int, uint8_t *, bool,
                                       BatchStats &);

POINTVIZ_ISA_END
}  // namespace pointviz
