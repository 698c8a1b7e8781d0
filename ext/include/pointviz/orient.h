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
    /// The sensor saw every surface from `up`'s side (aerial and most terrestrial LiDAR: from
    /// above or from the side, never from below): orient_above() instead of the spanning tree.
    bool from_above = false;
    /// orient_above(): |n . up| from which `up` alone decides a normal's sign (a surface tilted
    /// at most acos(steep) from vertical is seen from its upper side).
    double steep = 0.3;
    /// orient_above(): from |n . up| >= steep up to `flat`, the up decides only a normal that
    /// agrees (|n_i . n_j| >= `agree`) with half of its k neighbours' or more: a corner's PCA
    /// normal, tilted up between two walls, would lead the walls beside it inward.
    double flat = 0.7, agree = 0.9;
    /// orient_above(): rounds of propagation to the steeper normals.
    uint32_t rounds = 32;
};

/// What the orientation did.
struct OrientResult {
    size_t components = 0;   ///< connected parts of the neighbour graph
    size_t flipped = 0;      ///< normals whose sign changed
    size_t steep = 0;        ///< orient_above: normals too steep for the up to decide alone
    size_t unreached = 0;    ///< orient_above: of those, no oriented neighbour reached: by sign
};

/// Orients `normals` in place (sign only) for a cloud seen from above (opt.from_above): a normal
/// with |n . up| >= opt.steep faces up (below opt.flat only one that agrees with its
/// neighbours'); a steeper one (a wall, a cliff, a trunk) takes the sign
/// that agrees with its already oriented neighbours among the first `opt.k` columns of `nb`
/// (rounds in which every such point votes with the state of the round before: the result
/// does not depend on the thread count), and one that none reaches in opt.rounds rounds faces
/// up by its sign. Linear in n and on the workers, where orient_mst sorts every edge on one
/// thread.
OrientResult orient_above(const double *points, float *normals, const NeighbourTable &nb,
                          const OrientOptions &opt, int threads, Progress *progress = nullptr);

/// Orients `normals` in place (sign only) over the first `opt.k` columns of `nb`. Deterministic.
OrientResult orient_mst(const double *points, float *normals, const NeighbourTable &nb,
                        const OrientOptions &opt, Progress *progress = nullptr);

}  // namespace pointviz
