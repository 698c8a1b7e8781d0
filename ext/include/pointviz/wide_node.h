// pointviz — the wide tree's node: two levels of the binary QSplat tree collapsed into one node
// whose (up to) four children sit side by side, structure of arrays, tested at once with SIMD.
#pragma once

#include <cstdint>
#include <vector>

#include "pointviz/node.h"
#include "pointviz/simd.h"

namespace pointviz {

/// `lane_count` of an interior lane (its subtree is the wide node `child`).
constexpr uint8_t kInteriorLane = 0;
/// `parent` of a lane that is itself one of the binary node's children (a leaf one level down).
constexpr uint8_t kLaneIsMid = 2;
/// `child` of an unused lane or a leaf mid node.
constexpr uint32_t kNoChild = 0xffffffffu;

/// What the traversal needs of one of the binary node's two children (the "mid" level, which
/// has no lanes): its level-of-detail sphere and its cone. 40 bytes.
struct MidNode {
    Vec3 c;            ///< sphere centre (12 B)
    float r;           ///< sphere radius (4 B)
    Vec3 axis;         ///< cone axis as decoded from int16 (12 B)
    float cone;        ///< cone sine; +inf: no cone (4 B)
    uint32_t child;    ///< binary index of its first child; kNoChild when it is a leaf (4 B)
    uint32_t index;    ///< its own binary index (4 B)
};
static_assert(sizeof(MidNode) == 40, "MidNode is a 40-byte contract");

/// One node of the wide tree. 256 bytes (four cache lines).
///
/// A wide node stands for binary interior node X. Its lanes are X's grandchildren, or X's child
/// itself where that child is a leaf; X's children (the "mid" level) have no lanes: their
/// level of detail and cones are tested one by one from `mids`. Per lane: the bounding sphere,
/// the cone, the slab, and either the wide node of the lane's subtree or its leaf's surfels.
/// Unused lanes are masked out by `valid`.
struct alignas(64) WideNode {
    alignas(16) float cx[kWide], cy[kWide], cz[kWide];  ///< sphere centres (48 B)
    alignas(16) float r[kWide];                       ///< sphere radii (16 B)
    alignas(16) float ax[kWide], ay[kWide], az[kWide];  ///< cone axes as decoded from int16 (48 B)
    alignas(16) float slab[kWide];                    ///< slab half-width; +inf: no slab (16 B)
    alignas(16) float cone[kWide];  ///< cone sine (Node::cone()); +inf: no cone, never culled (16 B)
    uint32_t child[kWide];     ///< interior lane: wide node index; leaf lane: first surfel (16 B)
    MidNode mids[2];           ///< X's two children (80 B)
    uint8_t lane_count[kWide];  ///< leaf lane: surfel count (1..31); kInteriorLane otherwise (4 B)
    uint8_t parent[kWide];     ///< 0 / 1: child of mids[0] / mids[1]; kLaneIsMid: that mid itself (4 B)
    uint8_t depth[kWide];      ///< binary depth of each lane (4 B)
    uint8_t valid;             ///< bit k set when lane k is used (1 B)
    uint8_t pad_[3];
};
static_assert(sizeof(WideNode) == 256, "WideNode is a 256-byte contract");

/// Axis-aligned boxes of the four lanes, for the wide nodes whose lanes lie above the box
/// depth (a prefix of the breadth-first wide node array). 96 bytes.
struct alignas(16) WideBoxes {
    float lox[kWide], loy[kWide], loz[kWide];
    float hix[kWide], hiy[kWide], hiz[kWide];
};
static_assert(sizeof(WideBoxes) == 96, "WideBoxes is a 96-byte contract");

/// Collapses a binary tree (breadth-first, nodes[0] the root) into wide nodes, breadth-first,
/// wide node 0 standing for the root. Empty when the root is a leaf. `boxes` are the binary
/// tree's boxes (a prefix of its levels); `wide_boxes` receives the lanes' boxes for every wide
/// node that has a lane above `box_depth`.
void collapse_tree(const std::vector<Node> &nodes, const std::vector<Box> &boxes,
                   uint32_t box_depth, std::vector<WideNode> &wide,
                   std::vector<WideBoxes> &wide_boxes);

}  // namespace pointviz
