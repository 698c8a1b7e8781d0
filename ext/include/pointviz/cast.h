// pointviz — batched ray queries on a tree, in world coordinates, over all cores.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "pointviz/trace.h"

namespace pointviz {

/// Output buffers of cast_rays; any pointer may be null to skip that output.
struct CastOutput {
    float *t = nullptr;          ///< (n,) parameter along the caller's direction; inf on a miss
    float *normal = nullptr;     ///< (n, 3)
    float *color = nullptr;      ///< (n, 3)
    float *radius = nullptr;     ///< (n,)
    int32_t *index = nullptr;    ///< (n,) input index of the nearest surfel; -1 miss; -2 LoD disk
    uint8_t *count = nullptr;    ///< (n,) disks blended
    double *position = nullptr;  ///< (n, 3) world hit point (origin + t * direction); inf on a miss
};

/// Sums over a batch (divide by the number of rays for the paper's per-ray means), and the
/// rays that could not be traced (NaN/inf or a zero direction), which count as misses.
struct BatchStats {
    uint64_t nodes = 0, disks = 0, depth_sum = 0, hits = 0;
    uint32_t max_depth = 0;
    size_t rays = 0;
    size_t invalid = 0;                 ///< rays with NaN/inf or a zero direction
    size_t first_invalid = size_t(-1);  ///< lowest index of such a ray

    /// Adds another part of the batch's sums (a worker's rays).
    void add(const BatchStats &o) {
        nodes += o.nodes;
        disks += o.disks;
        depth_sum += o.depth_sum;
        hits += o.hits;
        rays += o.rays;
        invalid += o.invalid;
        first_invalid = std::min(first_invalid, o.first_invalid);
        max_depth = std::max(max_depth, o.max_depth);
    }
};

/// Rays in world coordinates, (n, 6) of float or double: origin, direction (any non-zero
/// length). t is returned in units of the given direction. `pixel_angle` > 0 gives primary
/// rays a footprint (enables LoD). Results do not depend on `threads`. `stats` must not be null.
template <class T>
void cast_rays(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats);

/// Any-hit for (n, 6) world rays within (t_min, t_max[i]) (caller's units); `hit` is (n,).
template <class T>
void occluded(const SurfelTree &tree, const T *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float pixel_angle, int threads, uint8_t *hit,
              bool count, BatchStats &stats);

}  // namespace pointviz
