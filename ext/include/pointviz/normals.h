// pointviz — normals of raw points: weighted PCA over a neighbourhood whose size is chosen per
// point, from the local noise and sampling, by the intersection-of-confidence-intervals rule.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// How normals are estimated. Neighbourhood sizes count the point itself.
struct NormalOptions {
    /// Smallest neighbourhood: a plane through fewer than 8 samples of a noisy scan tilts by
    /// tens of degrees; the first ring around a point has 6-8 samples.
    uint32_t k_min = 8;
    /// Largest neighbourhood (needs a NeighbourTable of at least k_max - 1 columns). k_max ==
    /// k_min estimates with that one size everywhere.
    uint32_t k_max = 32;
    /// The rule grows the neighbourhood (by `growth` x per step, then k_max) while its normal
    /// stays within `confidence` standard errors of every smaller one's (standard errors from
    /// the local noise level: the median residual variance of the first ring); a larger value
    /// lets curvature and edges tilt normals further, a smaller one stops early in noise.
    double confidence = 3.0;
    /// Factor between consecutive sizes tried (> 1): 1.5 tries 8, 12, 18, 27, 32 for k 8-32.
    double growth = 1.5;
    int threads = 0;   ///< 0: all cores
};

/// Unoriented normals and what they were estimated from.
struct NormalResult {
    std::vector<float> normals;     ///< (n, 3) unit, sign arbitrary
    std::vector<uint32_t> support;  ///< (n,) neighbourhood size chosen, the point included
    std::vector<float> spread;      ///< (n,) RMS distance of the neighbourhood from its plane
    size_t borrowed = 0;   ///< points on a line or stack of duplicates: normal of a neighbour
    size_t arbitrary = 0;  ///< such points with no usable neighbour: any normal of the line
};

/// Smallest (l1 - l0) / l2 of a neighbourhood for its plane to be defined: below it the
/// samples lie on a line (or coincide) to within 1e-3 of their extent. The closed-form
/// eigenvalues of an exact line come out ~1e-8 x l2 apart (acos near 1 amplifies rounding), so
/// the threshold must stay well above that.
constexpr double kPlanarMinGap = 1e-6;

/// Normals of `points` ((n, 3), those of the tree `nb` was computed on). `count` (n,) optional:
/// row i holds only its first count[i] entries (at least k_min - 1), and the largest size
/// tried there is count[i] + 1. Deterministic for any thread count. Throws Cancelled.
NormalResult estimate_normals(const double *points, const NeighbourTable &nb,
                              const NormalOptions &opt, Progress *progress = nullptr,
                              const uint32_t *count = nullptr);

}  // namespace pointviz
