// pointviz — the level-of-detail error predictor: how much image error stopping the traversal at
// a node costs, from what the node stores (benchmarks/README.md, "Issue 18").
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>

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
///
/// Those frames were primary rays on a flat look. Recalibrated on full shaded frames (shadows,
/// sky occlusion, one reflection; what max_error is about), the spread weight fitted there,
/// 0.262, overestimated the error about 8x on the uncoloured models: kSpreadWeight is a
/// quarter of it. With it, E = 0.005, the worst frame of the dragon's raw scans, the
/// Armadillo and the striped torus at 1x, 2.5x and 7.5x measures FLIP 0.0021 (dragon, 2.5x;
/// an eighth gave 0.0046 there, too close to E): benchmarks/README.md, "Issue 18, the floor".
/// Broken down per kind of ray (benchmarks/lod_kinds.py; benchmarks/README.md, "Issue 18, the
/// budget on real scans"): at 2.5x and 7.5x all of the scans' budget-frame error is the camera
/// rays'. An eighth measured again (0.0047 on the dragon at 2.5x, the scans' budget frames
/// 4-16 % faster) was not adopted: no held-out model, and at the frame's own exposure the
/// coarser stops brighten a far object's mean enough to darken the whole frame (the dragon at
/// 7.5x: exposure -13 %, own-exposure FLIP 0.063 -> 0.155).
constexpr float kSpreadWeight = 0.262f / 4.f;
constexpr float kColourWeight = 0.454f;
constexpr float kBudgetScale = 2.16f;
/// Error of a frame in which (almost) nothing stops: single silhouette pixels that change. The
/// budget left for node stops is max_error minus this.
constexpr float kBudgetFloor = 0.0005f;
/// Largest node, in footprints, the budget may stop at: the calibrated range. Beyond it a flat
/// node could hide a silhouette its spread does not predict.
constexpr float kBudgetMaxExtent = 8.f;
/// The colour term's response for nodes no wider than the ray's footprint, relative to
/// kColourWeight (fitted on stops of up to kBudgetMaxExtent footprints). FLIP filters both
/// frames by the eye's contrast sensitivity before it compares colours, and that sensitivity
/// falls steeply with spatial frequency: where a node within a pixel is stopped, full detail
/// shows one sample of its colours (one sample a pixel) and the stopped frame their mean, a
/// difference at the pixel's scale, which FLIP attenuates more than the same spread across
/// several pixels. Nodes wider than a footprint keep the full weight. Calibrated against
/// measured FLIP (benchmarks/lod_budget.py --colour; benchmarks/README.md, "Issue 18, the
/// colour term against what FLIP sees"): on the striped torus (200k at 160x120, 1M and 8M at
/// 480x360; 1x, 2.5x, 7.5x) the smallest response whose frames at E = 0.005 stay within E at
/// full detail's exposure and at their own is 0.375; this is the next value tried above it. What
/// gives first is the automatic exposure: at 0.3 the 200k frame at 7.5x moves by a code value
/// (FLIP 0.036 at its own exposure, 0.0011 at full detail's).
constexpr float kColourPixelResponse = 0.5f;

/// What a ray is for. The budget's error model depends on it: a camera or reflection ray's hit
/// is a colour and a normal (the predictor above), a shadow or sky-visibility ray's hit is one
/// bit of visibility, which a coarser node flips only where its disks stand off the surface.
enum class RayKind : uint8_t {
    Camera = 0,      ///< camera rays, and queries that do not say which kind their rays are
    Shadow = 1,      ///< toward a light's sampled point: visibility of the light
    Sky = 2,         ///< sky visibility (ambient occlusion): visibility of a sampled solid angle
    Reflection = 3,  ///< mirror and glossy reflections: a closest hit seen through the surface
};
constexpr int kRayKinds = 4;

/// The visibility model (shadow and sky-visibility rays under the budget). A node's two LoD
/// disks stand off the surface they replace by up to its diameter times the sine of its normal
/// cone; a ray's visibility flips only where it passes through that band, so the chance that a
/// ray reaching a stopped node is flipped is proportional to the cone's sine (the band over the
/// node: the footprint does not enter), and what a flip costs the pixel is that ray's share of
/// it. A node stops when kBudgetScale * weight * sine <= the pixel's budget (no budget_scale:
/// shadows fall outside the object's pixels), the weight being the kind's mean FLIP per unit
/// sine. A shadow ray carries the light's whole direct term, a sky-visibility ray one sample's
/// share of the ambient term.
///
/// Calibrated once per kind, each alone (benchmarks/lod_budget.py --secondary; benchmarks/
/// README.md, "Issue 18, secondary rays"): on the studio frames of the striped torus (1M), the
/// dragon's raw scans and the Armadillo (1M) at 1x, 2.5x and 7.5x, E = 0.005, the smallest
/// weight whose added FLIP stays within a quarter of E - floor (0.0011) on every frame. The
/// worst frames are at the framing distance (torus 1x for shadow rays: 0.0009 at 0.03; dragon
/// 1x for sky rays: 0.0006 at 0.015). A model with the band measured in footprints (weight *
/// sine * size / footprint: coarse nodes cheaper in a wide beam) was tried and refused: with
/// the sky rays' wide cone it let nearly every node stop and cost the dragon 0.0037 at 1x at
/// any weight that gave speed.
///
/// Visibility rays see no colour: the colour term does not apply. A node near the ray's origin
/// never stops (kVisibilityClearance): there the ray grazes the surface it leaves, and a disk
/// standing off it would shadow that surface (self-shadowing), which the band model does not
/// describe. On a convex surface of curvature radius R a ray leaving at any angle is
/// (G r)^2 / 2R above it G radii away, and a node's disk stands off by about r^2 / 4R: G = 2
/// leaves a factor 8.
constexpr float kShadowFlipWeight = 0.03f;
constexpr float kSkyFlipWeight = 0.015f;
/// A node stops for a visibility ray only when its sphere is at least this many of its radii
/// from the ray's origin.
constexpr float kVisibilityClearance = 2.f;
/// The sampled solid angle of a sky-visibility ray, as a cone's growth per unit distance: a
/// camera hit samples the cosine-weighted hemisphere with two rays, each standing for half of
/// its projected solid angle pi, i.e. a disk of radius 1/sqrt(2) at unit distance (a
/// reflection's single ray stands for more: this is the narrower of the two).
constexpr float kSkyConeSpread = 1.41421356f;


POINTVIZ_ISA_BEGIN

/// The predictor's colour term for a colour spread, as budget_allows compares it.
inline float colour_term(float colour_spread) {
    return kBudgetScale * kColourWeight * colour_spread;
}
/// The predictor's normal-spread term for a cone's sine (2: no cone).
inline float spread_term(float cone) { return kBudgetScale * kSpreadWeight * std::min(cone, 1.f); }

/// The colour term's response for a node of diameter `size` seen with footprint `fp`, `pixel` the
/// response within one footprint (kColourPixelResponse, or TraceOptions' calibration override).
inline float colour_response(float size, float fp, float pixel) {
    return size <= fp ? std::min(1.f, pixel) : 1.f;
}

/// Predicted error of stopping at `nd` (nodes without a cone never stop: caller's check).
inline float predicted_error(const Node &nd) {
    return kBudgetScale * (kSpreadWeight * std::min(nd.cone(), 1.f) +
                           kColourWeight * nd.colour_spread());
}

/// Whether the budget allows stopping at `nd`, seen with footprint `fp` (ray width at its
/// centre), `budget` the error the pixel may take above the floor (max_error - kBudgetFloor,
/// times TraceOptions::budget_scale for primary rays), `size_pixels` being the size rule's share (nodes below that many footprints stop
/// on their colour term alone; 0: none), `pixel_response` the colour term's response within
/// one footprint (kColourPixelResponse):
/// * never above kBudgetMaxExtent footprints (the calibrated range);
/// * never when the colour term alone, times its response at the node's projected size,
///   exceeds the budget: averaging a node's colours is what a 1-spp frame sees as error even
///   below a pixel, if attenuated there (a striped torus 300k at 7.5x: FLIP 0.035 under the
///   plain 1 px size rule);
/// * below `size_pixels` footprints the normal spread is not counted: the pixel averages it
///   (the 1 px size rule costs at most 0.0026 on uncoloured scenes, SIZE_RULE_ERROR in Python);
/// * above, the whole predicted error must fit.
inline bool budget_allows(const Node &nd, float fp, float budget, float size_pixels,
                          float pixel_response = kColourPixelResponse) {
    const float size = 2.f * nd.radius;
    if (!(size <= kBudgetMaxExtent * fp)) return false;
    const float colour =
        colour_term(nd.colour_spread()) * colour_response(size, fp, pixel_response);
    if (colour > budget) return false;
    return size <= size_pixels * fp || colour + spread_term(nd.cone()) <= budget;
}


/// The visibility model's predicted error for a cone's sine (2: no cone), `weight` the kind's
/// (kShadowFlipWeight, kSkyFlipWeight, or TraceOptions' calibration override).
inline float flip_term(float weight, float cone) { return kBudgetScale * weight * std::min(cone, 1.f); }

/// Whether a visibility ray may stop at `nd`, seen with footprint `fp` at its centre, `dist2`
/// the squared distance of its centre from the ray's origin, `budget` the pixel's error above
/// the floor, `weight` its kind's:
/// * never above kBudgetMaxExtent footprints (the calibrated range);
/// * never within kVisibilityClearance radii of the origin (self-shadowing);
/// * the visibility model's predicted error must fit (no colour term).
inline bool visibility_allows(const Node &nd, float fp, float dist2, float budget, float weight) {
    const float size = 2.f * nd.radius;
    if (!(size <= kBudgetMaxExtent * fp)) return false;
    const float clear = (1.f + kVisibilityClearance) * nd.radius;
    if (!(dist2 >= clear * clear)) return false;
    return flip_term(weight, nd.cone()) <= budget;
}

/// Largest q in [0, hi] with fits(q), fits non-increasing in q (true up to some q, false after);
/// -1 when none. Starts from the estimate `guess`, so that it takes a step or two.
template <class Fits>
inline int32_t largest_fitting(int32_t guess, int32_t hi, Fits fits) {
    int32_t q = std::clamp(guess, int32_t(-1), hi);
    while (q >= 0 && !fits(q)) --q;
    while (q < hi && fits(q + 1)) ++q;
    return q;
}

/// What a node must store for a ray to stop at it whatever the footprint it is seen with: an
/// upper bound on its colour byte and one on its cone value. Found once per batch for each kind
/// of ray (trace.h, lod_gates), it turns the footprint-independent part of the stopping rule
/// into two integer compares on bytes the traversal has already loaded, so that nodes that can
/// never stop (most of them, where the budget refuses curved or coloured detail) cost no
/// footprint and no decoding. A necessary condition only: the nodes it lets through still face
/// the whole rule (lod_stop).
struct LodGate {
    int32_t colour_max = 255;             ///< largest colour byte that may stop (-1: none)
    int32_t cone_max = kConeNeverQ - 1;   ///< largest cone_q that may stop (never kConeNeverQ)

    bool passes(const Node &nd) const {
        return int32_t(nd.colour_byte()) <= colour_max && int32_t(nd.cone_q) <= cone_max;
    }
};

/// The gate of budget_allows for `budget`, `size_pixels` and `pixel_response`: the colour term
/// alone at its smallest response (within one footprint) must fit; without a size share
/// (size_pixels 0), so must the spread term (the sum of the two non-negative terms is at least
/// either).
inline LodGate budget_gate(float budget, float size_pixels,
                           float pixel_response = kColourPixelResponse) {
    LodGate g;
    const float least = std::min(1.f, pixel_response);
    const auto colour_fits = [budget, least](int32_t q) {
        return colour_term(Node::decode_colour_spread(uint32_t(q))) * least <= budget;
    };
    const float k = colour_term(Node::decode_colour_spread(255)) * least;
    const float guess = budget > 0.f && k > 0.f ? 255.f * std::sqrt(std::min(budget / k, 1.f))
                                                : budget > 0.f ? 255.f : -1.f;
    g.colour_max = largest_fitting(int32_t(guess), 255, colour_fits);
    if (!(size_pixels > 0.f)) {
        const auto cone_fits = [budget](int32_t q) {
            return spread_term(Node::decode_cone(uint32_t(q))) <= budget;
        };
        const float s = spread_term(1.f);
        const float cguess = budget > 0.f ? kConeScale * std::min(budget / s, 2.f) : -1.f;
        g.cone_max = largest_fitting(int32_t(cguess), int32_t(kConeNeverQ) - 1, cone_fits);
    }
    return g;
}

/// The gate of visibility_allows for `budget` and `weight`: no colour bound (a visibility ray
/// sees none); the cone bound of the flip term.
inline LodGate visibility_gate(float budget, float weight) {
    LodGate g;
    const auto cone_fits = [budget, weight](int32_t q) {
        return flip_term(weight, Node::decode_cone(uint32_t(q))) <= budget;
    };
    const float s = flip_term(weight, 1.f);
    const float cguess = budget > 0.f && s > 0.f ? kConeScale * std::min(budget / s, 2.f)
                                                 : budget > 0.f ? 2.f * kConeScale : -1.f;
    g.cone_max = largest_fitting(int32_t(cguess), int32_t(kConeNeverQ) - 1, cone_fits);
    return g;
}

POINTVIZ_ISA_END

}  // namespace pointviz
