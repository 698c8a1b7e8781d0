// pointviz — planes over pixel patches of a depth-camera frame, sized to its depth steps and
// stopped at its depth edges (pointviz/depth_steps.py's module docstring: the method; its
// patch_planes_numpy: the same steps in numpy, the tests' oracle). Per point: the patch's moments
// from summed-area tables (four reads), the 3x3 covariance, its smallest eigenpair in closed
// form and the patch shrinking while its residual says two surfaces, fused and threaded. Depth
// edges split the frame into segments (a union-find over the pixel grid); flying pixels are
// found on the grid. Same arithmetic in the same order as the numpy version, so equal to it
// within the rounding of arccos / cos (libm's against numpy's).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/progress.h"

namespace pointviz {

/// The method's constants (pointviz/depth_steps.py passes its own, so they live in one place;
/// the defaults here are theirs).
struct DepthPlaneOptions {
    double slope_error = 0.03492076949174773;  ///< DEPTH_SLOPE_ERROR (tan 2 degrees)
    int noise_radius = 3;                       ///< NOISE_RADIUS
    int noise_sample = 4;                       ///< NOISE_SAMPLE
    std::vector<int> radii{1, 2, 3, 4, 5, 6, 8, 10, 12, 16};  ///< PATCH_RADII (ascending)
    double residual_steps = 1.5;    ///< PATCH_RESIDUAL_STEPS
    double residual_sigmas = 3.0;   ///< PATCH_RESIDUAL_SIGMAS
    double move_steps = 2.0;        ///< MOVE_STEPS
    double edge_steps = 4.0;        ///< EDGE_STEPS
    double edge_sigmas = 4.0;       ///< EDGE_SIGMAS
    double edge_footprints = 6.0;   ///< EDGE_FOOTPRINTS
    uint32_t small_segment = 64;    ///< SMALL_SEGMENT
    /// Patches stop at depth edges and flying pixels are found; false: square patches across
    /// edges, no pixel flying.
    bool edges = true;
    int threads = 0;                ///< 0: all cores
};

/// What depth_patch_planes gives (the numpy version's four outputs, plus what it measured).
struct DepthPlaneResult {
    std::vector<double> points;   ///< (n, 3) each point moved along its ray onto its plane
    std::vector<float> normals;   ///< (n, 3) facing the camera
    std::vector<int64_t> radius;  ///< (n,) patch half-width in pixels (0: no plane)
    std::vector<uint8_t> flying;  ///< (n,) flying pixels
    double noise = 0;             ///< the frame's noise in steps (median patch residual)
    double angle = 0;             ///< median angle between neighbouring pixels' rays
    size_t segments = 0;          ///< segments between depth edges (with edges)
};

/// The plane of one patch from its moment sums s = (count, sum x, sum y, sum z, sum xx, xy,
/// xz, yy, yz, zz) (coordinates centred on the frame's mean point) and the point's unit ray.
struct PatchPlane {
    double normal[3];   ///< unit normal (-ray when not `fine`)
    double mean[3];     ///< mean point of the patch
    double residual;    ///< RMS residual along the ray (sqrt of the smallest eigenvalue / cos)
    bool fine;          ///< at least 3 points, finite moments, a plane (middle eigenvalue > 0)
};
PatchPlane patch_plane(const double sums[10], const double ray[3]);

/// Smallest and middle eigenvalues of the symmetric 3x3 matrix (a00, a01, a02, a11, a12, a22)
/// and the smallest's unit eigenvector, in closed form (the trigonometric solution of the
/// characteristic cubic; the eigenvector as the longest cross product of two rows of
/// A - lambda I). The vector is NaN when A - lambda I has no two independent rows.
void smallest_eigen(const double a[6], double &smallest, double &middle, double vec[3]);

/// Flying pixels of a range image (h, w; NaN: no point) with each pixel's edge jump (h, w):
/// 1 where the pixel lies between two surfaces along a row, column or diagonal (one or two
/// pixels away), farther than its jump from both and from both extended to it.
std::vector<uint8_t> depth_flying_pixels(const double *ranges, const double *jump, size_t h,
                                         size_t w, int threads = 0);

/// Segments of a range image: pixels joined through row and column neighbours (both `valid`)
/// whose ranges differ by at most the smaller of their jumps. Labels (h * w; -1 where not
/// valid) numbered by each segment's first pixel in row-major order; returns their number.
size_t depth_segment_labels(const double *ranges, const double *jump, const uint8_t *valid,
                            size_t h, size_t w, std::vector<int32_t> &labels);

/// The patch planes of a frame: `points` (n, 3) finite, `grid` (n, 2) each point's row and
/// column (>= 0), `viewpoint` (3) the camera, `step` (n) each point's depth step. Polls
/// `progress` (optional) and throws Cancelled once it is cancelled.
DepthPlaneResult depth_patch_planes(const double *points, size_t n, const int32_t *grid,
                                    const double viewpoint[3], const double *step,
                                    const DepthPlaneOptions &opt, Progress *progress = nullptr);

}  // namespace pointviz
