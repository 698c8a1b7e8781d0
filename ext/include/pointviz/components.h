// pointviz — stray clusters of a scanned cloud: the connected components of its neighbour graph,
// linking two points only when they are closer than a few times the local sample spacing, and
// the components too small to be part of the scanned object (dust, a glint, a piece of the
// stand seen by one scan), which the preprocessing of raw scans drops.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Options of the stray-cluster search.
struct StrayOptions {
    /// Points i and j (one among the other's neighbours) are linked when their distance is at
    /// most `reach` x the smaller of their spacings (each point's `rank`-th nearest distinct
    /// neighbour in its own scan). A scan's grid has its first ring of 4 samples at 1 spacing,
    /// the diagonal at 1.41, and up to ~3 across a grazing surface. The nearest neighbour alone
    /// varies too much on irregular samplings: 20000 random points on a sphere fall into 615
    /// components at 4 x the nearest, 15 at 4 x the 2nd, 1 at 3 x the 4th. On the dragon's 15
    /// scans, components at 2 / 3 / 4 x the 4th: 11 / 8 / 6 (at 2 a 78-point strip of the
    /// dragon comes apart; at 3 and 4 only clusters of <= 32 points are apart from it).
    double reach = 3.0;
    uint32_t rank = 4;
    /// A component with fewer points than this is stray whatever the cloud's size: fewer points
    /// than one neighbourhood of the normal estimate (32) cannot make a surface of its own.
    uint32_t min_points = 32;
    /// A component with fewer points than this fraction of the cloud is stray too: a piece of a
    /// thousandth of the cloud covers only a few pixels of a view of the whole.
    double fraction = 1e-3;
    int threads = 0;
};

/// What the search found.
struct StrayResult {
    std::vector<uint8_t> stray;   ///< (n,) 1: the point belongs to a stray cluster
    std::vector<uint32_t> label;  ///< (n,) component of each point, numbered by first point
    size_t components = 0;        ///< components of the graph
    size_t points = 0;            ///< stray points
    size_t clusters = 0;          ///< stray components
};

/// Components of `points` ((n, 3)) over their neighbour table `nb` (neighbours of each point in
/// ascending distance, as from knn_all), `group` (n,) optional: the scan of each point (null:
/// one scan). A component is stray when it has fewer than max(min_points, fraction x n)
/// points; the largest component never is (a cloud that is all one cluster keeps every
/// point). Deterministic for any thread count. Polls `progress`; throws Cancelled.
StrayResult find_stray_clusters(const double *points, const NeighbourTable &nb,
                                const int32_t *group, const StrayOptions &opt,
                                Progress *progress = nullptr);

}  // namespace pointviz
