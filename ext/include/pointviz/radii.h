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
    /// Points whose neighbourhood is not a surface (canopies, shrubs: LiDAR's volumetric
    /// returns) have no tangent plane whose cell a disk could cover: their radius is bounded
    /// by their 3-D spacing instead. f = the fraction of the k neighbours within the point's
    /// tangent plane's band (|height| <= volume_band x the distance along the plane): about 1
    /// on a sampled surface, noisy or curved, and beside a crease (a roof's ridge: one face
    /// holds most neighbours), ~0.2-0.4 among scattered returns. From f = volume_surface down to
    /// volume_volume the radius goes geometrically from the cell's to
    /// min(cell's, volume_factor x the nearest neighbour's distance); then a point taken for a
    /// surface whose k neighbours are mostly not is bounded fully (a second pass over the rows:
    /// the tree-searching overload stores its table then). volume_factor 0: off.
    double volume_band = 0.2, volume_surface = 0.6, volume_volume = 0.4, volume_factor = 0;
    /// With the volume bound on (volume_factor > 0), a one-sided point (some sampled direction
    /// meets no bisector: its neighbours lie to one side) leaves out of its cell the directions
    /// whose nearest bisector lies farther than the neighbour that makes it (that neighbour more
    /// than acos(open_cos) = 60 degrees off the direction: a grazing bisector). A canopy's
    /// returns that lie in a plane all to one side (its "petals") have grazing bisectors along
    /// their open side, which put the cell's far end up to the cap away. The cell is the
    /// largest extent over the other directions (all of them when every one is grazing).
    /// Uniform random planes stay hole-free (tests/test_lidar.py; applied to every point, not
    /// the one-sided only, it left 1-2 of 20,000 vertical rays missing on some seeds).
    double open_cos = 0.5;
    /// Sparse returns (water, dark roofs) are not blown up to cover what they did not sample: a
    /// point whose cell is wide in most directions (its median extent over the sampled
    /// directions beyond typical_cap x the median of the surface points', those the bound above
    /// leaves alone) gets at most typical_cap x their median radius. An elongated cell (scan
    /// lines far apart) keeps its radius. Clouds of >= 100 points with >= 100 surface points;
    /// 0: off.
    double typical_cap = 0;
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

/// Radii of a subset of a cloud from a neighbour table of the whole cloud.
struct RowRadii {
    std::vector<float> radii;  ///< one per member, in ascending index order
    size_t searched = 0;       ///< members whose row held fewer than k members: searched
};

/// The coverage radii of the points with member[i] != 0 (of `n` points with unit `normals`),
/// as coverage_radii of the members alone with their `k` nearest members, taken from `rows`:
/// a table of every point's nearest points (itself excluded) on other positions (e.g. the
/// points before a surface fit moved them). Each member's neighbours are the k nearest on
/// `points` (ties by index) among the members in its row, re-ranked there; a row holding fewer
/// than k members is searched on a KD-tree of the members instead (built only then). Where the
/// table's positions differ from `points` a member outside the row can be nearer than the k-th
/// taken: the row stands in for the search. Deterministic. Throws Cancelled.
RowRadii coverage_radii_from_rows(const double *points, const float *normals, size_t n,
                                  const uint8_t *member, const NeighbourTable &rows, uint32_t k,
                                  const CoverOptions &opt, Progress *progress = nullptr);

}  // namespace pointviz
