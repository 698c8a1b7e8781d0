// pointviz — consistent orientation of unoriented normals: toward the scanner when viewpoints
// are known, else by propagation along a minimum spanning tree of the neighbour graph
// (Hoppe et al. 1992), each connected part then facing outward.
#pragma once

#include <cstddef>
#include <cstdint>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Flips normals[i] to face its viewpoint: `viewpoints` holds one row (all points) or n rows.
/// Returns how many were flipped. On `threads` workers (0: all cores).
size_t orient_toward(const double *points, float *normals, size_t n, const double *viewpoints,
                     size_t n_viewpoints, int threads = 0);

/// Options of the spanning-tree orientation.
struct OrientOptions {
    /// Neighbours linked per point (Hoppe et al. use k ~ 8): enough to keep a sampled surface
    /// in one piece, few enough that the graph rarely jumps across thin parts.
    uint32_t k = 8;
    /// Weight of the edge length (in units of the median length) added to the cost
    /// 1 - |n_i . n_j|: on flat parts that cost is ~0 everywhere, and short edges must win.
    double distance_weight = 0.1;
    /// A part whose normals point away from its centroid for a fraction within this margin
    /// of one half is undecided (an open patch): with an up hint it faces up instead. Terrain
    /// is rarely flat: lidar/simple.las (a shallow valley) votes 0.605 for facing down; closed
    /// scans vote > 0.8 for their outside.
    double undecided_margin = 0.2;
    bool has_up = false;
    double up[3] = {0, 0, 1};
};

/// What the orientation did.
struct OrientResult {
    size_t components = 0;   ///< connected parts of the neighbour graph
    size_t flipped = 0;      ///< normals whose sign changed
};

/// Orients `normals` in place (sign only) over the first `opt.k` columns of `nb`. Deterministic.
OrientResult orient_mst(const double *points, float *normals, const NeighbourTable &nb,
                        const OrientOptions &opt, Progress *progress = nullptr);

}  // namespace pointviz
