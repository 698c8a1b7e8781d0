// pointviz — what a ray query is asked and what it answers: the traversal options and the
// closest-hit record (the same in every instruction set's kernels, see isa.h).
#pragma once

#include <cstdint>

#include "pointviz/ray.h"

namespace pointviz {

/// How the disks around a hit are combined (section 2.1).
enum class Interpolation : uint8_t {
    None = 0,    ///< the nearest disk alone (the baseline: disks stick out)
    Paper = 1,   ///< weights |I - p_i|, as printed in the paper (Schaufler & Jensen's scheme)
    Smooth = 2,  ///< weights (1 - (|I - p_i| / r_i)^2)^2: full at the centre, zero at the rim
};

/// When a node is small enough to stop descending (paper section 2.2.1 and its open question).
enum class LodCriterion : uint8_t {
    Size = 0,       ///< the paper's: the node's sphere diameter projects below lod_pixels
    Deviation = 1,  ///< the node's deviation from its mean plane (diameter x sin of the normal
                    ///< cone's half-angle) projects below lod_pixels: flat nodes stop earlier
};

/// Instruction set of the traversal kernels (dispatch.h).
enum class Isa : uint8_t {
    Auto = 0,    ///< the best one this CPU runs
    Base = 1,    ///< the portable build (SSE2 on x86-64: four-lane node tests, scalar disk tests)
    Sse42 = 2,   ///< SSE4.2 and POPCNT
    Avx2 = 3,    ///< AVX2 and FMA: eight disks at a time
    Avx512 = 4,  ///< AVX-512 F/VL/BW/DQ on top of AVX2
};

/// Knobs of one traversal; the paper's variants are combinations of these.
struct TraceOptions {
    bool lod = true;          ///< stop at nodes smaller than lod_pixels footprints (needs ray.spread > 0)
    float lod_pixels = 1.f;   ///< LoD threshold: sphere diameter in units of the ray footprint
    bool cull = true;         ///< back-face culling with normal cones (closest-hit queries only)
    uint32_t box_depth = 0;   ///< nodes shallower than this are bounded by boxes, the rest by spheres
    bool slabs = true;        ///< intersect each sphere with its node's mean-plane slab (beyond the paper)
    Interpolation interp = Interpolation::Smooth;
    float window = 1.f;       ///< depth window, in radii of the nearest disk, measured along its normal
    LodCriterion lod_criterion = LodCriterion::Size;
    float lod_max_extent = 8.f;  ///< Deviation only: never stop at nodes wider than this many footprints
    bool wide = true;         ///< traverse the 4-wide tree (false: the binary tree it was collapsed from)
    Isa isa = Isa::Auto;      ///< kernels to run; every one gives the same results, bit for bit
};

/// What a closest-hit query returns.
struct SurfaceHit {
    float t = kInf;        ///< blended ray parameter; kInf on a miss
    Vec3 n;                ///< blended unit normal (as stored: may face away from the ray)
    Vec3 color;            ///< blended colour in [0, 1]
    float radius = 0.f;    ///< blended disk radius (the local sampling scale)
    int32_t index = -1;    ///< nearest surfel (tree order); -2 when it was a LoD node disk; -1 miss
    uint32_t count = 0;    ///< how many disks were blended
};

}  // namespace pointviz
