// pointviz — the hierarchy's node: a QSplat-style bounding sphere with a normal cone and the
// average attributes of its subtree, plus an optional axis-aligned box for the top levels.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>

#include "pointviz/surfel.h"

namespace pointviz {

/// Unit-vector components stored as int16 (x 32767): decoding is three multiplies, and the
/// rounding (under 3e-5 per component) is absorbed by kConeSlack.
constexpr float kAxisScale = 32767.f;

POINTVIZ_ISA_BEGIN

inline int16_t quantize_axis(float v) {
    return int16_t(std::lround(std::clamp(v, -1.f, 1.f) * kAxisScale));
}

POINTVIZ_ISA_END

/// Slack added to every cone's sine so that the 16-bit axis never makes culling unsafe.
constexpr float kConeSlack = 1e-3f;
/// Stored cone value of a node whose normals span more than a hemisphere: never culled.
constexpr uint16_t kConeNeverQ = 0xffffu;
/// Quantisation of a cone's sine: sin = cone_q / kConeScale, rounded up (conservative).
constexpr float kConeScale = 32767.f;

/// Most surfels in a leaf: the count shares a word with the index.
constexpr uint32_t kMaxLeafSize = 31;
/// Most surfels in one tree: 27 bits of index.
constexpr uint32_t kMaxTreeSurfels = 1u << 27;
/// Slab value meaning "no slab": the node is not flat enough for one to help.
constexpr uint32_t kNoSlab = 255;

/// Colour spread (RMS deviation of the subtree's surfel colours from their mean, 0..1 units per
/// channel, summed over RGB) is stored as q = ceil(255 sqrt(spread / kColourSpreadMax)): fine
/// steps near 0, where the error budget decides (spread ~ 0.005), coarse ones where any budget
/// refuses the node anyway. Decoding is (q / 255)^2 kColourSpreadMax, never below the truth.
constexpr float kColourSpreadMax = 1.f;

inline uint32_t quantize_colour_spread(float spread) {
    if (!(spread > 0.f)) return 0;
    const float q = std::ceil(std::sqrt(std::min(spread / kColourSpreadMax, 1.f)) * 255.f);
    return uint32_t(std::min(q, 255.f));
}

/// The radius with its 8 low mantissa bits replaced by `byte`, never smaller than `radius`:
/// the float is rounded up by 256 ulps (3e-5 relative) first, so that reading the stored bits
/// as a plain float stays a conservative bounding radius and the hot path needs no mask.
/// Non-finite radii are kept as they are (the byte reads as whatever their bits hold).
inline float radius_with_byte(float radius, uint32_t byte) {
    if (!std::isfinite(radius) || radius < 0.f) return radius;
    uint32_t bits;
    std::memcpy(&bits, &radius, 4);
    bits = ((bits & ~0xffu) + 0x100u) | (byte & 0xffu);
    float out;
    std::memcpy(&out, &bits, 4);
    return out;
}

/// One node of the tree. 32 bytes: a sibling pair fills one cache line.
///
/// Interior node: `count() == 0`, children are `index()` and `index() + 1`.
/// Leaf: `count()` surfels (1..31) starting at surfel `index()`.
///
/// Besides the paper's sphere, each node bounds its surfels by a slab around its mean plane:
/// every surfel point x satisfies |dot(x - c, axis())| <= slab_half_width(). For the nearly
/// flat patches low in the tree, sphere and slab together are far tighter than the sphere alone.
struct Node {
    Vec3 c;              ///< sphere centre = mean of the subtree's surfel centres (12 B)
    float radius;        ///< bounding-sphere radius: max over the subtree of |p - c| + r, rounded
                         ///< up; its 8 low mantissa bits hold the colour spread (4 B, see
                         ///< radius_with_byte)
    int16_t axis_q[3];   ///< mean normal (cone axis), x kAxisScale (6 B)
    uint16_t cone_q;     ///< sin of the cone's half-angle + slack, x kConeScale; kConeNeverQ if > 90 deg (2 B)
    uint32_t rgb_slab;   ///< mean colour (24 bits, red low) | slab half-width in radius/255 << 24 (4 B)
    uint32_t index_count;  ///< first child or first surfel (27 bits) | count << 27 (4 B)

    /// Cone axis (unit to within 3e-5).
    Vec3 axis() const {
        return {float(axis_q[0]) * (1.f / kAxisScale), float(axis_q[1]) * (1.f / kAxisScale),
                float(axis_q[2]) * (1.f / kAxisScale)};
    }
    /// Whether the cone is narrower than a hemisphere (culling can apply).
    bool has_cone() const { return cone_q != kConeNeverQ; }
    /// Sine of the cone's half-angle, slack included; 2 when it spans more than a hemisphere.
    float cone() const { return has_cone() ? decode_cone(cone_q) : 2.f; }
    /// The sine a stored cone value below kConeNeverQ stands for (non-decreasing in it).
    static float decode_cone(uint32_t q) { return float(q) * (1.f / kConeScale); }
    uint32_t index() const { return index_count & (kMaxTreeSurfels - 1); }
    uint32_t count() const { return index_count >> 27; }
    bool is_leaf() const { return count() != 0; }
    uint32_t rgba() const { return (rgb_slab & 0xffffffu) | 0xff000000u; }
    uint32_t slab_q() const { return rgb_slab >> 24; }
    /// The stored colour-spread byte (the radius's 8 low mantissa bits).
    uint32_t colour_byte() const {
        uint32_t bits;
        std::memcpy(&bits, &radius, 4);
        return bits & 0xffu;
    }
    /// Upper bound of the RMS colour deviation of the subtree (0..1 per channel, RGB summed).
    float colour_spread() const { return decode_colour_spread(colour_byte()); }
    /// The colour spread a stored byte stands for (non-decreasing in the byte).
    static float decode_colour_spread(uint32_t byte) {
        const float q = float(byte) * (1.f / 255.f);
        return q * q * kColourSpreadMax;
    }
    /// Half-width of the slab around the mean plane (along axis()).
    float slab_half_width() const { return float(slab_q()) * (1.f / 255.f) * radius; }
};
static_assert(sizeof(Node) == 32, "Node is a 32-byte contract");

/// Axis-aligned box; kept only for the top levels of the tree. 24 bytes.
struct Box {
    Vec3 lo, hi;
};
static_assert(sizeof(Box) == 24, "Box is a 24-byte contract");

POINTVIZ_ISA_BEGIN

/// Slab test. Returns the entry parameter, or +inf if the ray misses [tmin, tmax].
inline float enter_box(const Box &b, Vec3 o, Vec3 inv_d, float tmin, float tmax) {
    float t0x = (b.lo.x - o.x) * inv_d.x, t1x = (b.hi.x - o.x) * inv_d.x;
    float t0y = (b.lo.y - o.y) * inv_d.y, t1y = (b.hi.y - o.y) * inv_d.y;
    float t0z = (b.lo.z - o.z) * inv_d.z, t1z = (b.hi.z - o.z) * inv_d.z;
    float tn = std::max(std::max(std::min(t0x, t1x), std::min(t0y, t1y)),
                        std::max(std::min(t0z, t1z), tmin));
    float tf = std::min(std::min(std::max(t0x, t1x), std::max(t0y, t1y)),
                        std::min(std::max(t0z, t1z), tmax));
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

/// Sphere-and-slab test of a node: the ray must cross both. Returns the entry parameter, or
/// +inf if the ray misses [tmin, tmax]. `d` must be unit length.
inline float enter_sphere_slab(const Node &nd, Vec3 o, Vec3 d, float tmin, float tmax) {
    Vec3 oc = nd.c - o;
    float tca = dot(oc, d);
    float d2 = length2(oc) - tca * tca;
    float r2 = nd.radius * nd.radius;
    if (d2 > r2) return kInf;
    float thc = std::sqrt(r2 - d2);
    float t0 = std::max(tca - thc, tmin), t1 = std::min(tca + thc, tmax);
    if (nd.slab_q() < kNoSlab) {
        // points o + t d with |t dn - on| <= h lie in the slab
        Vec3 a = nd.axis();
        float h = nd.slab_half_width(), dn = dot(d, a), on = dot(oc, a);
        if (std::fabs(dn) > 1e-12f) {
            float ta = (on - h) / dn, tb = (on + h) / dn;
            t0 = std::max(t0, std::min(ta, tb));
            t1 = std::min(t1, std::max(ta, tb));
        } else if (std::fabs(on) > h) {
            return kInf;
        }
    }
    return t0 <= t1 ? t0 : kInf;
}

POINTVIZ_ISA_END

}  // namespace pointviz
