// pointviz — the batch queries (closest and any hits) that trace coherent groups of rays as
// packets (packet_trace.h). They live in their own translation units (ext/src/packet_cast.cpp for
// closest hits, ext/src/packet_occlude.cpp for any hits: together, the closest-hit loop's helpers
// would no longer be inlined), compiled once per instruction set as the single-ray kernels of
// ext/src/cast.cpp are, so that the single-ray traversal there compiles exactly as it does
// without them; dispatch.cpp enters them once per batch, and they take one chunk of rays at a time.
#pragma once

#include <cstddef>
#include <cstdint>

#include "pointviz/cast.h"
#include "pointviz/isa.h"
#include "pointviz/trace.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

/// cast_rays without statistics (`count` must be false), for the wide traversal: coherent
/// groups of rays traversed as packets (packet_trace.h, packet_covers) — blocks of 2x4 pixels
/// when the rays are rows of camera rays in raster order, else groups of kPacket consecutive
/// rays — and the others one at a time. Results equal the single-ray kernels' for every ray,
/// bit for bit. Returns false, having done nothing, when the batch does not start with a
/// coherent group (scattered rays: the single-ray kernels serve them).
template <class T>
bool cast_packets(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
                  float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats);

/// occluded without statistics (`count` must be false), grouped as cast_packets groups: any
/// hits of coherent groups as packets (any_hits_packet), the others one at a time. Answers
/// equal the single-ray kernels' for every ray. Returns false, having done nothing, when the
/// batch does not start with a coherent group.
template <class T>
bool occluded_packets(const SurfelTree &tree, const T *rays, const float *t_max, size_t n,
                      const TraceOptions &opt, float t_min, float pixel_angle, int threads,
                      uint8_t *hit, bool count, BatchStats &stats);

POINTVIZ_ISA_END
}  // namespace pointviz
