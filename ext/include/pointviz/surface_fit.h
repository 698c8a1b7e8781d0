// pointviz — surfels from noisy, overlapping scans: each point moves onto a robust local fit of
// the surface across every scan that saw it (a weighted quadric height field in the frame of its
// normal, the one-step moving-least-squares projection), and points that add nothing where
// scans overlap are dropped (greedy thinning against the kept points, best-seen points first).
// With more than one fit pass a first, narrower thinning runs before the last pass, which then
// fits only the points it keeps (over every point's previous fit): where scans overlap it has a
// third of the work.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/knn.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Options of the surface fit.
struct FitOptions {
    /// Fewest points in a fit (the point included), even where the normal's neighbourhood was
    /// smaller: a quadric has 6 unknowns, and noise averages down as 1/sqrt(points).
    uint32_t min_support = 16;
    /// The last pass fits z = a + b x + c y + d x^2 + e xy + f y^2 (true) or a plane (false),
    /// earlier passes a plane. A plane pulls curved surfaces inward by ~ curvature x support^2
    /// / 4, the quadric does not; but on raw points a quadric's normals are noisier (6
    /// unknowns), so it only fits points the planes have denoised. Measured on virtual scans
    /// of a torus at 0.1 % noise: mean distance to the surface 0.69e-3 (quadric last) vs
    /// 0.90e-3 (planes only), normal error 0.58 vs 0.67 degrees. The quadric pass also gives
    /// back the planes' pull (each point's estimate, from the quadric's second-order part,
    /// averaged over its neighbours): over 5 draws of those scans the fitted points' mean
    /// signed distance to the torus went from 0.36e-3 / 0.42e-3 inside the raw points' to
    /// 0.01e-3 / 0.06e-3 inside (0.1 % / 0.4 % noise).
    bool quadric = true;
    /// Reweighting passes after the last pass's first fit (Welsch weights on the residuals),
    /// so that a stray point or a misregistered layer pulls the fit less; each costs a second
    /// fit. None by default: the passes before the last fit once (their output only feeds the
    /// last pass), and the last pass's reweighting made the virtual scans of a torus no better
    /// (holes_over_seeds.py, seeds 1-3, 0.1 % / 0.4 % noise, one reweighting / none: normal
    /// error 0.878 / 0.869 and 2.907 / 2.878 degrees, depth error 5.66e-4 / 5.67e-4 and
    /// 1.038e-3 / 1.044e-3, holes 0.104 / 0.103 % and 0.042 / 0.045 %) while it took 0.3-0.4 s
    /// of the 1M-point sphere scans' 4.7 s of CPU; the dragon's render moved by 1 level of 255
    /// on average, at its silhouettes. The plane pass's reweighting was measured the same way
    /// before (seed 11: normal error 0.850 / 0.841 and 3.111 / 3.083 degrees with / without).
    int robust_passes = 0;
    /// Fits in turn, each on the previous one's positions and normals. One pass leaves the
    /// normal error of the neighbourhood's PCA (5.2 degrees on the torus at 0.4 % noise), two
    /// 2.7, three 1.8 but with twice the inward pull of two on curved parts.
    int passes = 2;
    /// Width of the Welsch weight in units of the weighted RMS residual.
    double robust_width = 2.0;
    /// Drop a point when a kept point lies within `thin` x its spacing in its own scan (0: keep
    /// all). 0.75 keeps a single scan intact (its samples are >= 1 spacing apart) and keeps
    /// about one layer where scans overlap (a second layer's samples lie within 0.71 spacing of
    /// the first's on a square grid). With passes > 1 a thinning at 0.8 x this radius on the
    /// positions of the pass before the last picks the points the last pass fits (the dragon's
    /// 15 scans: about 40 % of them); the pull given back is averaged over those among each
    /// point's neighbours, and the thinning proper runs among them on their final positions.
    double thin = 0.75;
    int threads = 0;
};

/// The fitted surfels.
struct FitResult {
    std::vector<double> points;   ///< (n, 3) projected positions
    std::vector<float> normals;   ///< (n, 3) normals of the fit (sign of the input normals)
    std::vector<uint8_t> keep;    ///< (n,) 1: the surfel adds to the surface
    std::vector<float> shift;     ///< (n,) distance moved (a point the last pass skipped: by
                                  ///< the passes before it)
    std::vector<double> spacing;  ///< (n,) distance to the nearest point of the same scan
    size_t kept = 0;              ///< points kept
    size_t unmoved = 0;           ///< fits that failed or asked for too large a move: not moved
};

/// Fits every point of `points` (oriented unit `normals`, chosen neighbourhood sizes `support`
/// from estimate_normals, neighbours `nb`). `group` (n,) optional: the scan of each point (for
/// its spacing within its own scan; null: one scan). `viewpoints` (1 or n rows) optional: points
/// seen more head-on are kept first. Deterministic for any thread count. Throws Cancelled.
FitResult fit_surface(const double *points, const float *normals, const uint32_t *support,
                      const NeighbourTable &nb, const int32_t *group, const double *viewpoints,
                      size_t n_viewpoints, const FitOptions &opt, Progress *progress = nullptr);

/// The greedy thinning of fit_surface: visiting the points by descending `priority` (null: all
/// equal), then ascending index, a point is dropped when a kept point of its row of `nb` lies
/// within `thin` x its `spacing` of it (or at its position). `among` (n_among indices; null:
/// every point): only these points are visited, the others are dropped. Returns keep (n,): 1
/// for the kept points. Decided in parallel rounds (a point is decided once the neighbours it
/// depends on are), the same answer as the serial visit for any thread count. Throws
/// Cancelled.
std::vector<uint8_t> thin_greedy(const double *points, const NeighbourTable &nb,
                                 const double *spacing, double thin, const double *priority,
                                 const uint32_t *among, size_t n_among, int threads,
                                 Progress *progress = nullptr);

}  // namespace pointviz
