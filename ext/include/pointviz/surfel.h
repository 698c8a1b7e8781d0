// pointviz — the surfel (an oriented disk). The ray–disk test is disk_kernel.h.
#pragma once

#include <cstdint>

#include "pointviz/isa.h"
#include "pointviz/ray.h"

namespace pointviz {

/// One point of the cloud as an oriented disk. 32 bytes: two per cache line.
struct Surfel {
    Vec3 p;            ///< centre, in the tree's local frame (12 B)
    float r;           ///< radius (4 B)
    Vec3 n;            ///< unit normal (12 B)
    uint32_t rgba;     ///< colour, 8 bits per channel, red in the low byte (4 B)
};
static_assert(sizeof(Surfel) == 32, "Surfel is a 32-byte contract");

/// Rays closer than this to parallel with a disk's plane (|cos| of the angle between ray and
/// normal) miss it: such a hit would be a sliver at the disk's edge with an unstable t, and the
/// neighbouring disks of a surface seen edge-on cover that spot better.
constexpr float kParallelCos = 1e-6f;

/// Result of one ray–disk test.
struct DiskHit {
    float t;       ///< ray parameter of the hit on the disk's plane
    float u2;      ///< (distance from the centre / radius)^2, in [0, 1]
};

POINTVIZ_ISA_BEGIN

/// 8-bit colour channel `c` (0..2) of a packed RGBA value, as a float in [0, 1].
inline float channel(uint32_t rgba, int c) { return float((rgba >> (8 * c)) & 0xffu) * (1.f / 255.f); }

/// Pack three floats in [0, 1] into RGBA8 (alpha 255).
inline uint32_t pack_rgb(float r, float g, float b) {
    auto q = [](float v) {
        v = v < 0.f ? 0.f : (v > 1.f ? 1.f : v);
        return uint32_t(v * 255.f + 0.5f);
    };
    return q(r) | (q(g) << 8) | (q(b) << 16) | (0xffu << 24);
}

POINTVIZ_ISA_END

}  // namespace pointviz
