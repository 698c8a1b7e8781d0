// pointviz — the closest-hit batch queries of one instruction set that trace coherent groups of
// rays as packets (packet_cast.h, packet_trace.h). Compiled once per instruction set alongside cast.cpp
// (ext/CMakeLists.txt; POINTVIZ_ISA_NS names the inline namespace, isa.h), and kept out of
// cast.cpp so that the single-ray traversal there keeps its own code generation.
#include "pointviz/packet_cast.h"

#include <algorithm>

#include "pointviz/cast_rows.h"
#include "pointviz/packet_groups.h"
#include "pointviz/packet_trace.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace {

/// Rays converted and traced together: a few packets' worth, on the stack.
constexpr size_t kPacketBlock = 64;

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

template bool cast_packets<float>(const SurfelTree &, const float *, size_t, const TraceOptions &,
                                  float, int, CastOutput, bool, BatchStats &);
template bool cast_packets<double>(const SurfelTree &, const double *, size_t,
                                   const TraceOptions &, float, int, CastOutput, bool, BatchStats &);
POINTVIZ_ISA_END
}  // namespace pointviz
