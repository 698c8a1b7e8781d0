// pointviz — raw points to surfels in one call each: the spatial index, normals and their
// orientation, the surface fit and radii composed for the binding layer (one call per step, each
// taking the Progress of the caller).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/components.h"
#include "pointviz/knn.h"
#include "pointviz/normals.h"
#include "pointviz/orient.h"
#include "pointviz/progress.h"
#include "pointviz/radii.h"
#include "pointviz/scan_neighbours.h"
#include "pointviz/surface_fit.h"

namespace pointviz {

/// A cloud's points and what is known about where they were seen from.
struct PointsView {
    const double *points = nullptr;      ///< (n, 3)
    size_t n = 0;
    const double *viewpoints = nullptr;  ///< (1 or n, 3) scanner positions, or null
    size_t n_viewpoints = 0;
    const int32_t *group = nullptr;      ///< (n,) scan of each point, or null
    /// (n, 2) row and column of each point in its scan's sampling grid (negative: none), or
    /// null; with `group`, neighbours within a scan come from the grid (scan_neighbours.h)
    const int32_t *cell = nullptr;
};

/// k nearest neighbours of every point (itself excluded) and their distances.
struct KnnOutput {
    NeighbourTable table;
    std::vector<double> dist;   ///< (n, k)
};
KnnOutput knn_points(const PointsView &in, uint32_t k, int threads, Progress &progress);

/// The nearest point of a cloud to each of `m` query positions (ties by lower index).
struct NearestOutput {
    std::vector<uint32_t> index;  ///< (m,) index into the cloud
    std::vector<double> dist;     ///< (m,) Euclidean distance
};
/// `queries` (m, 3), finite; the cloud `in` needs at least one point.
NearestOutput nearest_points(const PointsView &in, const double *queries, size_t m, int threads,
                             Progress &progress);

/// Oriented normals: toward the viewpoints when given, else along a spanning tree.
struct NormalsOutput {
    NormalResult est;
    OrientResult orient;
    size_t toward_viewpoint_flips = 0;
    GridNeighbourStats grid;  ///< how the neighbours within scans were found (with cells)
    /// With `cover` (and neighbours across all points, i.e. no viewpoints): the coverage radii
    /// of the oriented normals from the first cover_k columns of the normals' own table, equal
    /// to radii_points' (the same tree, the same rows): the radii need no search of their own.
    std::vector<float> radii;
};
NormalsOutput normals_points(const PointsView &in, const NormalOptions &nopt,
                             const OrientOptions &oopt, Progress &progress,
                             const CoverOptions *cover = nullptr, uint32_t cover_k = 0);

/// Orientation of given unoriented normals (in place) over `k` neighbours or toward viewpoints.
OrientResult orient_points(const PointsView &in, float *normals, const OrientOptions &oopt,
                           int threads, Progress &progress);

/// Coverage radii of points with normals, over `k` neighbours.
std::vector<float> radii_points(const PointsView &in, const float *normals, uint32_t k,
                                const CoverOptions &opt, Progress &progress);

/// Stray clusters over `k` neighbours (see components.h).
StrayResult stray_points(const PointsView &in, uint32_t k, const StrayOptions &opt,
                         Progress &progress);

/// Normals (estimated and oriented if `normals` is null), then the surface fit and thinning;
/// with `sopt` (non-null), points of stray clusters are not kept either. With `copt`
/// (non-null), also the coverage radii of the kept points on their fitted positions and
/// normals, over their `cover_k` nearest kept points taken from the fit's neighbour rows
/// (coverage_radii_from_rows): the radii the fitted cloud would otherwise search for.
struct FitOutput {
    NormalsOutput normals;     ///< empty when normals were given
    FitResult fit;
    StrayResult stray;         ///< empty without `sopt`
    std::vector<float> radii;  ///< (n,) with `copt`: the kept points' radii, 0 elsewhere
    size_t radii_searched = 0; ///< kept points whose radius needed a search (see above)
    double median_spacing = 0; ///< median of fit.spacing (numpy's median)
};
FitOutput fit_points(const PointsView &in, const float *normals, const NormalOptions &nopt,
                     const OrientOptions &oopt, const FitOptions &fopt, Progress &progress,
                     const StrayOptions *sopt = nullptr, const CoverOptions *copt = nullptr,
                     uint32_t cover_k = 0);

}  // namespace pointviz
