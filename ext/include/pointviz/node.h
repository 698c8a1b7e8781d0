// pointviz — the hierarchy's node: a QSplat-style bounding sphere with a normal cone and the
// average attributes of its subtree, plus an optional axis-aligned box for the top levels.
#pragma once

#include <algorithm>
#include <cstdint>

#include "pointviz/surfel.h"

namespace pointviz {

/// Octahedral encoding of a unit vector in 2 x 16 bits (max error about 0.003 degrees).
inline uint32_t oct_encode(Vec3 n) {
    float s = std::fabs(n.x) + std::fabs(n.y) + std::fabs(n.z);
    if (!(s > 0.f)) return 0x7fff7fffu;  // zero vector: encodes +z-ish, only used for full cones
    float x = n.x / s, y = n.y / s;
    if (n.z < 0.f) {
        float ox = (1.f - std::fabs(y)) * std::copysign(1.f, x);
        float oy = (1.f - std::fabs(x)) * std::copysign(1.f, y);
        x = ox;
        y = oy;
    }
    auto q = [](float v) {
        int i = int(std::lround(std::clamp(v, -1.f, 1.f) * 32767.f));
        return uint32_t(uint16_t(int16_t(i)));
    };
    return q(x) | (q(y) << 16);
}

/// Inverse of oct_encode.
inline Vec3 oct_decode(uint32_t e) {
    float x = float(int16_t(uint16_t(e & 0xffffu))) * (1.f / 32767.f);
    float y = float(int16_t(uint16_t(e >> 16))) * (1.f / 32767.f);
    float z = 1.f - std::fabs(x) - std::fabs(y);
    if (z < 0.f) {
        float ox = (1.f - std::fabs(y)) * std::copysign(1.f, x);
        float oy = (1.f - std::fabs(x)) * std::copysign(1.f, y);
        x = ox;
        y = oy;
    }
    return normalize(Vec3{x, y, z});
}

/// Slack added to every cone's sine so that the 16-bit axis never makes culling unsafe.
constexpr float kConeSlack = 1e-3f;
/// Cone value of a node whose normals span more than a hemisphere: never culled.
constexpr float kConeNever = 2.f;

/// One node of the tree. 32 bytes: a sibling pair fills one cache line.
///
/// Interior node: `count == 0`, children are `index` and `index + 1`.
/// Leaf: `count` surfels (1..255) starting at surfel `index`.
struct Node {
    Vec3 c;              ///< sphere centre = mean of the subtree's surfel centres (12 B)
    float radius;        ///< bounding-sphere radius: max over the subtree of |p - c| + r (4 B)
    uint32_t normal;     ///< mean normal (cone axis), octahedral (4 B)
    float cone;          ///< sin of the cone's half-angle plus slack; kConeNever if > 90 deg (4 B)
    uint32_t rgb_count;  ///< mean colour (24 bits, red low) | count << 24 (4 B)
    uint32_t index;      ///< first child (interior) or first surfel (leaf) (4 B)

    bool is_leaf() const { return (rgb_count >> 24) != 0; }
    uint32_t count() const { return rgb_count >> 24; }
    uint32_t rgba() const { return (rgb_count & 0xffffffu) | 0xff000000u; }
};
static_assert(sizeof(Node) == 32, "Node is a 32-byte contract");

/// Axis-aligned box; kept only for the top levels of the tree. 24 bytes.
struct Box {
    Vec3 lo, hi;
};
static_assert(sizeof(Box) == 24, "Box is a 24-byte contract");

/// Slab test. Returns the entry parameter, or +inf if the ray misses [tmin, tmax].
inline float enter_box(const Box &b, Vec3 o, Vec3 inv_d, float tmin, float tmax) {
    float t0x = (b.lo.x - o.x) * inv_d.x, t1x = (b.hi.x - o.x) * inv_d.x;
    float t0y = (b.lo.y - o.y) * inv_d.y, t1y = (b.hi.y - o.y) * inv_d.y;
    float t0z = (b.lo.z - o.z) * inv_d.z, t1z = (b.hi.z - o.z) * inv_d.z;
    float tn = std::max({std::min(t0x, t1x), std::min(t0y, t1y), std::min(t0z, t1z), tmin});
    float tf = std::min({std::max(t0x, t1x), std::max(t0y, t1y), std::max(t0z, t1z), tmax});
    return tn <= tf ? tn : kInf;
}

/// Sphere test. Returns the entry parameter, or +inf if the ray misses [tmin, tmax].
/// `d` must be unit length.
inline float enter_sphere(Vec3 c, float radius, Vec3 o, Vec3 d, float tmin, float tmax) {
    Vec3 oc = c - o;
    float tca = dot(oc, d);
    float d2 = length2(oc) - tca * tca;
    float r2 = radius * radius;
    if (d2 > r2) return kInf;
    float thc = std::sqrt(r2 - d2);
    float t0 = tca - thc, t1 = tca + thc;
    if (t1 < tmin || t0 > tmax) return kInf;
    return std::max(t0, tmin);
}

}  // namespace pointviz
