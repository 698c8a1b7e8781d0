// pointviz — the level-of-detail error predictor: how much image error stopping the traversal at
// a node costs, from what the node stores (benchmarks/README.md, "Issue 18").
#pragma once

#include <algorithm>

#include "pointviz/isa.h"
#include "pointviz/node.h"

namespace pointviz {

/// Predicted mean FLIP of the pixels whose rays stop at a node:
///   kBudgetScale * (kSpreadWeight * spread + kColourWeight * colour)
/// where spread is the sine of the normal cone's half-angle (the children's disks tilt by up to
/// it) and colour the RMS colour deviation of the subtree. The weights are the non-negative
/// least-squares fit of frame FLIP against the mean features of the stopped nodes
/// (benchmarks/lod_budget.py: 30 calibration frames, a striped torus and the Armadillo, 1x to
/// 7.5x the framing distance, 0.5 to 8 px); kBudgetScale makes the fit a bound on every
/// calibration frame and on the held-out dragon scans.
constexpr float kSpreadWeight = 0.262f;
constexpr float kColourWeight = 0.454f;
constexpr float kBudgetScale = 2.16f;
/// Error of a frame in which (almost) nothing stops: single silhouette pixels that change. The
/// budget left for node stops is max_error minus this.
constexpr float kBudgetFloor = 0.0005f;
/// Largest node, in footprints, the budget may stop at: the calibrated range. Beyond it a flat
/// node could hide a silhouette its spread does not predict.
constexpr float kBudgetMaxExtent = 8.f;

POINTVIZ_ISA_BEGIN

/// Predicted error of stopping at `nd` (nodes without a cone never stop: caller's check).
inline float predicted_error(const Node &nd) {
    return kBudgetScale * (kSpreadWeight * std::min(nd.cone(), 1.f) +
                           kColourWeight * nd.colour_spread());
}

/// Whether the budget allows stopping at `nd`, seen with footprint `fp` (ray width at its
/// centre), `budget` the error the pixel may take above the floor (max_error - kBudgetFloor,
/// times TraceOptions::budget_scale for primary rays), `size_pixels` being the size rule's share (nodes below that many footprints stop
/// on their colour term alone; 0: none):
/// * never above kBudgetMaxExtent footprints (the calibrated range);
/// * never when the colour term alone exceeds the budget: averaging
///   a node's colours is what a 1-spp frame sees as error even below a pixel (a striped torus
///   at 7.5x: FLIP 0.035 under the plain 1 px size rule);
/// * below `size_pixels` footprints the normal spread is not counted: the pixel averages it
///   (the 1 px size rule costs at most 0.0026 on uncoloured scenes, SIZE_RULE_ERROR in Python);
/// * above, the whole predicted error must fit.
inline bool budget_allows(const Node &nd, float fp, float budget, float size_pixels) {
    const float size = 2.f * nd.radius;
    if (!(size <= kBudgetMaxExtent * fp)) return false;
    const float colour = kBudgetScale * kColourWeight * nd.colour_spread();
    if (colour > budget) return false;
    return size <= size_pixels * fp ||
           colour + kBudgetScale * kSpreadWeight * std::min(nd.cone(), 1.f) <= budget;
}

POINTVIZ_ISA_END

}  // namespace pointviz
