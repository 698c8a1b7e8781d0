// pointviz — the batch queries of one instruction set that trace coherent groups of rays as
// packets (packet_cast.h, packet_trace.h). Compiled once per instruction set alongside cast.cpp
// (ext/CMakeLists.txt; POINTVIZ_ISA_NS names the inline namespace, isa.h), and kept out of
// cast.cpp so that the single-ray traversal there keeps its own code generation.
#include "pointviz/packet_cast.h"

#include <algorithm>
#include <mutex>

#include "pointviz/cast_rows.h"
#include "pointviz/packet_trace.h"
#include "pointviz/parallel.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace {

/// Rays converted and traced together: a few packets' worth, on the stack.
constexpr size_t kPacketBlock = 64;

/// Closest hits of the local rays [0, n) whose skip[i] is zero, into out[i] (no statistics):
/// groups of kPacket consecutive rays that packet_covers as packets, the others one at a time.
void closest_hits_block(const SurfelTree &tree, const Ray *rays, size_t n, const TraceOptions &opt,
                        const LodGates &gates, SurfaceHit *out, const uint8_t *skip) {
    for (size_t g = 0; g < n; g += kPacket) {
        const int k = int(std::min(n - g, size_t(kPacket)));
        bool packet = true;
        for (int r = 0; r < k; ++r) packet = packet && skip[g + size_t(r)] == 0;
        if (packet && packet_covers(tree, rays + g, k, opt)) {
            closest_hits_packet(tree, rays + g, k, opt, gates, out + g);
            continue;
        }
        for (int r = 0; r < k; ++r) {
            if (skip[g + size_t(r)]) continue;
            NoStats ns;
            closest_hit(tree, rays[g + size_t(r)], opt, gates, out[g + size_t(r)], ns);
        }
    }
}

}  // namespace

template <class T>
void cast_packets(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
                  float pixel_angle, int threads, CastOutput out, bool, BatchStats &stats) {
    std::mutex m;
    const LodGates gates = lod_gates(opt);
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        Ray ray[kPacketBlock];
        double len[kPacketBlock];
        SurfaceHit h[kPacketBlock];
        uint8_t skip[kPacketBlock];
        for (size_t g = b; g < e; g += kPacketBlock) {
            const size_t k = std::min(e - g, kPacketBlock);
            for (size_t r = 0; r < k; ++r) {
                len[r] = local_ray(tree, rays + 6 * (g + r), ray[r]);
                ray[r].spread = pixel_angle;
                skip[r] = len[r] == 0.0;  // cannot be traced
            }
            closest_hits_block(tree, ray, k, opt, gates, h, skip);
            for (size_t r = 0; r < k; ++r) {
                const size_t i = g + r;
                double rd[6];
                for (int c = 0; c < 6; ++c) rd[c] = double(rays[6 * i + c]);
                bool hit = false;
                if (len[r] == 0.0) {
                    ++local.invalid;
                    local.first_invalid = std::min(local.first_invalid, i);
                } else {
                    hit = h[r].t != kInf;
                }
                local.hits += hit;
                write_hit(out, i, hit, h[r], len[r], rd, tree);
            }
        }
        local.rays = e - b;
        merge(stats, local, m);
    });
}

template void cast_packets<float>(const SurfelTree &, const float *, size_t, const TraceOptions &,
                                  float, int, CastOutput, bool, BatchStats &);
template void cast_packets<double>(const SurfelTree &, const double *, size_t,
                                   const TraceOptions &, float, int, CastOutput, bool, BatchStats &);

POINTVIZ_ISA_END
}  // namespace pointviz
