// pointviz — neighbours of each point among the points of its own scan. A range scan is a
// height field seen from one side: within one scan, a neighbourhood never spans both sides of
// a thin part (a claw, a spike, a sheet), while among all registered scans it does wherever
// the part is thinner than the neighbourhood, and its plane then lies across the part.
#pragma once

#include <cstddef>
#include <cstdint>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// The `k` nearest neighbours of every point among the points with the same `group` value,
/// the point excluded; indices into `points` ((n, 3)). A point whose group has at most k points
/// gets its k nearest among all points instead, from `all` (a tree over `points` that answers
/// with their indices; n > k). Deterministic for any thread count. Throws Cancelled.
NeighbourTable knn_within_groups(const double *points, size_t n, const int32_t *group,
                                 uint32_t k, const KnnTree &all, int threads,
                                 Progress *progress = nullptr);

/// Rings of grid cells searched around a point by knn_within_grids: 13 x 13 cells hold the 31
/// nearest samples of a surface seen up to ~70 degrees off head-on (3 x as many samples per
/// unit length along one grid axis as along the other).
constexpr int kGridMaxRing = 6;

/// What knn_within_grids did.
struct GridNeighbourStats {
    size_t from_grid = 0;  ///< points whose neighbours came from their grid cells
    size_t from_tree = 0;  ///< points searched in their scan's KD-tree instead
};

/// knn_within_groups for organised scans: `cell` ((n, 2) int32) holds each point's row and
/// column in its scan's sampling grid (a range scanner's grid of rays; negative: none). A point's
/// neighbours are searched ring by ring of grid cells around its own (Chebyshev distance 1, 2,
/// ...), keeping the k nearest in space, until a ring that holds samples adds none of them to the
/// k (then a farther ring cannot either on a surface the grid samples smoothly). Points without a
/// cell, whose k were still changing at ring kGridMaxRing, or whose scan's cells are not one
/// point per cell, are searched in a KD-tree of their scan as knn_within_groups does; groups of
/// at most k points use `all` as there. On smooth surfaces the result equals knn_within_groups'
/// (same (distance, index) order); across a depth jump the grid's neighbours are kept where the
/// tree would have searched the whole scan. Deterministic for any thread count. Throws Cancelled.
NeighbourTable knn_within_grids(const double *points, size_t n, const int32_t *group,
                                const int32_t *cell, uint32_t k, const KnnTree &all, int threads,
                                Progress *progress = nullptr, GridNeighbourStats *stats = nullptr);

}  // namespace pointviz
