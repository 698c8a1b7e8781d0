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

}  // namespace pointviz
