// pointviz — neighbours of each point among the points of its own scan. A range scan is a
// height field seen from one side: within one scan, a neighbourhood never spans both sides of
// a thin part (a claw, a spike, a sheet), while among all registered scans it does wherever
// the part is thinner than the neighbourhood, and its plane then lies across the part.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

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

/// Rings of cells searched around a point by knn_within_grids in a grid of directions derived
/// from its scan's viewpoint before the point is searched in its scan's KD-tree instead. Far
/// more than a stored grid's: the search stops only where it is exact, which on a surface seen
/// obliquely takes more rings, and a few points left over would cost their scan a KD-tree
/// (6 rings left 0.7 % of the sphere scans' points over, and took 20 % more time).
constexpr int kViewMaxRing = 16;

/// What knn_within_grids did.
struct GridNeighbourStats {
    size_t from_grid = 0;  ///< points whose neighbours came from their stored grid cells
    size_t from_view = 0;  ///< points whose neighbours came from a grid derived from a viewpoint
    size_t from_tree = 0;  ///< points searched in their scan's KD-tree instead
    size_t from_across = 0;  ///< rows taken from a table across scans (knn_within_grids_reusing)
};

/// knn_within_groups for range scans: searched in a grid over each scan instead of a KD-tree.
///
/// Stored grids: `cell` ((n, 2) int32, or null) holds each point's row and column in its scan's
/// sampling grid (a range scanner's grid of rays; negative: none). A point's neighbours are
/// searched ring by ring of grid cells around its own (Chebyshev distance 1, 2, ...), keeping the
/// k nearest in space, until a ring that holds samples adds none of them to the k (then a farther
/// ring cannot either on a surface the grid samples smoothly). On smooth surfaces the result
/// equals knn_within_groups'; across a depth jump the grid's neighbours are kept where the tree
/// would have searched the whole scan.
///
/// Derived grids: a scan without stored cells (or whose cells are not one point per cell) whose
/// points share one viewpoint (`viewpoints`, 1 or n rows, or null) and lie within 60 degrees of
/// their mean direction from it is binned by direction: each point's image on the plane one unit
/// in front of the viewpoint (a pinhole), in square cells of about 1.5 samples each (the size
/// from the scan's occupied area). Cells may hold any number of points. The ring search there
/// stops only when it is exact: a point outside the rings searched is at least the point's range
/// x sin(angle) away, and the angle is bounded below by the image's distance to the rings' edge x
/// cos^2 of the scan's widest angle off its mean direction (the plane stretches directions by at
/// most sec^2 of that angle). The result equals knn_within_groups' for any surface, depth jumps
/// included. Points still open at ring kViewMaxRing (seen edge-on) are searched in the scan's
/// KD-tree; a scan where an even sample of its points needs many rings on average (seen mostly
/// edge-on, or sampled far from evenly) is searched there whole.
/// Speed: on 8 noisy scans of 125k points of a sphere, 15 nearest, 75 % of the CPU time of the
/// scans' KD-trees; on the dragon's 15 scans 80 % (their stored grids, one point per cell and
/// stopping at the first ring that adds nothing: 55 %).
///
/// Anything else (no cells and no single viewpoint, points behind or beside the viewpoint) is
/// searched in a KD-tree of its scan as knn_within_groups does; groups of at most k points use
/// `all` as there. `need` (n,) optional: only the rows of points with need[i] != 0 are searched
/// (those of groups of at most k points are always filled); the others are left to the caller.
/// Deterministic for any thread count. Throws Cancelled.
NeighbourTable knn_within_grids(const double *points, size_t n, const int32_t *group,
                                const int32_t *cell, const double *viewpoints,
                                size_t n_viewpoints, uint32_t k, const KnnTree &all, int threads,
                                Progress *progress = nullptr, GridNeighbourStats *stats = nullptr,
                                const uint8_t *need = nullptr);

/// The fewest entries of a point's own scan a row of the table across scans must hold for
/// the fit's normals to take them instead of searching the scan (knn_within_grids_reusing's
/// k_least, of 15). The 1M-point sphere scans (8 scans, 31 neighbours across them): 42 % of the
/// rows hold 15, 56 % at least 11, 80 % at least 7. Shorter rows cap the normal's neighbourhood
/// where scans overlap, where the fit's plane pass then takes over: virtual scans of a torus
/// (holes_over_seeds.py, seeds 1-3, 0.4 % noise, without reweighting) normal error 2.878
/// degrees with every row searched, 2.893 at 11, 2.941 at 7 (0.1 % noise: 0.869 at all three);
/// the sphere scans' fit 0.2 / 0.4 s of CPU less at 11 / 7. With the fit's starting normals
/// tried at 8 and 16 points only (estimation.FIT_NORMAL_GROWTH), 10 instead of 11 (seeds 1-3,
/// 0.1 % / 0.4 % noise): normal error 0.8692 / 2.909 -> 0.8693 / 2.918 degrees, holes 0.1033 /
/// 0.0409 % -> 0.1033 / 0.0406 %, depth 5.668e-4 / 1.047e-3 -> 5.668e-4 / 1.046e-3 (9: 2.927
/// degrees at 0.4 %); the sphere scans' rows taken 56.0 -> 60.3 %, about 0.1 s of CPU less.
constexpr uint32_t kScanRowsLeast = 10;

/// Neighbours within scans, and how many of each row hold.
struct ScanRows {
    NeighbourTable table;         ///< (n, k); row i valid in its first count[i] entries
                                  ///< (the rest kNoIndex)
    std::vector<uint32_t> count;  ///< (n,) k, or fewer (at least k_least) for reused rows
    size_t reused = 0;            ///< rows taken from the table across scans
};

/// knn_within_grids with the rows taken, where it can, from `across`, the sorted neighbours of
/// every point among all points (knn_all): its entries of the point's own scan are the point's
/// nearest within the scan, in the order the search within the scan gives them. A point with
/// at least `k_least` such entries gets them (up to k; fewer than k: a shorter row), the
/// others (and the points of scans of at most k points) are searched with knn_within_grids'
/// `need`. With k_least == k the table equals knn_within_grids' wherever that search is exact
/// (derived grids and trees everywhere; stored grids except across a depth jump, where their
/// search keeps the grid's neighbours and a reused row has the nearest in space: the dragon's
/// fit output was the same either way). Deterministic for any thread count. Throws Cancelled.
ScanRows knn_within_grids_reusing(const double *points, size_t n, const int32_t *group,
                                  const int32_t *cell, const double *viewpoints,
                                  size_t n_viewpoints, uint32_t k, uint32_t k_least,
                                  const NeighbourTable &across, const KnnTree &all, int threads,
                                  Progress *progress = nullptr,
                                  GridNeighbourStats *stats = nullptr);

}  // namespace pointviz
