// pointviz — surfel radii that cover the sampled surface: each point's disk reaches a margin
// beyond its Voronoi cell in its tangent plane, so the disks tile the surface with no holes and
// little more overlap than the blending needs.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Options of the coverage radii (defaults measured hole-free: tests/test_estimation.py).
struct CoverOptions {
    /// Directions sampled around each point when measuring its cell (underestimates the cell's
    /// radius by at most 1 - cos(pi / 16), 2%).
    uint32_t directions = 16;  // at most 64
    /// Margin over the Voronoi radius: the overlap the interpolation blends over; it absorbs
    /// curvature and the sampled directions' underestimate.
    double margin = 1.2;
    /// Cap in units of the farthest neighbour's distance: an open boundary has no bisector on
    /// its outer side, and a near-tangent one would put the cell's far end very far away.
    double cap = 1.0;
    /// Global cap in units of the cloud's 99th-percentile radius (clouds of >= 100 points): a
    /// small stray cluster's cell would reach out to the distant surface.
    double global_cap = 4.0;
    int threads = 0;
};

/// Radii for `points` with unit `normals`, from the neighbours in `nb` (all its columns).
/// A point whose neighbours all coincide with it gets 0: the caller resolves those stacks of
/// duplicates (see pointviz/estimation.py). Deterministic. Throws Cancelled.
std::vector<float> coverage_radii(const double *points, const float *normals,
                                  const NeighbourTable &nb, const CoverOptions &opt,
                                  Progress *progress = nullptr);

/// The same radii with the `k` nearest neighbours (k <= n - 1) searched on `tree` (built on
/// `points`, answering with their indices) point by point as each radius is measured: the
/// neighbour table is never stored.
std::vector<float> coverage_radii(const double *points, const float *normals,
                                  const KnnTree &tree, uint32_t k, const CoverOptions &opt,
                                  Progress *progress = nullptr);

}  // namespace pointviz
