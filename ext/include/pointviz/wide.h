// pointviz — the wide tree: two levels of the binary hierarchy (node.h) collapsed into one node
// whose six bounds sit side by side in structure-of-arrays form, so that the traversal
// (wide_trace.h) tests them with one eight-lane (or two four-lane) SIMD pass instead of six
// scalar ones.
//
// A wide node stands for an interior binary node P and holds the bounds of its children A, B and
// of their children A1, A2, B1, B2. Keeping A and B, instead of jumping from P to its
// grandchildren, is what makes the wide traversal take the binary traversal's decisions exactly:
// level of detail stops at a node and intersects that node's children as disks, and normal-cone
// culling skips a node's subtree, so both need every binary node on the way down. Each lane
// carries its node's cone and leaf range or wide node, so that rays without level of detail
// never read a binary node below the boxes; the binary nodes stay in memory for the rays with
// level of detail (its footprint rule and gate read them, and the children of a node where it
// stops become disks) and for candidate_attributes. A grandchild lane counts only if its
// parent's lane hit and admitted it.
//
// Bounds are spheres cut by their node's mean-plane slab: the wide levels start where the boxes
// (SurfelTree::box_depth) end, and the levels above keep the binary traversal's box tests.
//
// Memory: one 192-byte WideNode per interior binary node at depth first_level() + 2k, plus a
// 4-byte index per binary node. With the default 8-surfel leaves that is about 0.07 wide nodes
// per surfel: ~ 14 bytes per surfel on top of the binary tree's (SurfelTree::memory_bytes
// counts both; BuildOptions::wide = false builds none).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/node.h"

namespace pointviz {

/// Lanes of a wide node: A, B (P's children), A1, A2, B1, B2 (their children).
constexpr int kWideUsed = 6;
/// Lanes the SIMD tests compute: eight (or two fours); lanes 6 and 7 read the next field's
/// first values and are masked off (kWideMask).
constexpr int kWideLanes = 8;
constexpr uint32_t kWideMask = (1u << kWideUsed) - 1u;
/// Index of "no wide node".
constexpr uint32_t kNoWide = 0xffffffffu;

/// Six nodes, lane by lane, as the binary nodes store them: what the traversal needs of each
/// without reading its binary node (unless level of detail is on): the bound (sphere centre and
/// radius; the slab's quantised axis and width), the cone (the same axis and the quantised
/// sine) and where to go next (`ref`). The traversal decodes the quantised fields with the
/// binary node's own expressions (Node::axis, Node::cone, Node::slab_half_width), so every lane
/// gives the scalar tests' answers bit for bit. Absent lanes (children of a leaf) have a NaN
/// radius: every ordered comparison with it fails, so they never hit.
///
/// 192 bytes, three cache lines: 29 bytes per lane (12 centre, 4 radius, 6 axis, 2 cone,
/// 1 slab, 4 ref) and 18 bytes of padding. The SIMD loads of a field read up to 8 bytes past
/// its sixth lane: into the next field, or into the padding for `slab_q`.
struct alignas(64) WideNode {
    float cx[kWideUsed], cy[kWideUsed], cz[kWideUsed];  ///< Node::c
    float r[kWideUsed];                                  ///< Node::radius; NaN: no node
    int16_t ax[kWideUsed], ay[kWideUsed], az[kWideUsed]; ///< Node::axis_q
    uint16_t cone_q[kWideUsed];                          ///< Node::cone_q
    uint8_t slab_q[kWideUsed];                           ///< Node::slab_q (kNoSlab: none)
    uint8_t pad_[2];
    /// A leaf: its Node::index_count (first surfel | count << 27). An interior grandchild
    /// (lanes 2-5): its wide node's index (count 0). Interior A and B: unused (their children
    /// are lanes 2-5).
    uint32_t ref[kWideUsed];
};
static_assert(sizeof(WideNode) == 192, "WideNode is a 192-byte contract");
static_assert(offsetof(WideNode, ref) >= offsetof(WideNode, slab_q) + 8,
              "the eight-byte load of slab_q stays inside the node");

/// The wide nodes of one binary tree, built from it (collapse) and read-only afterwards.
class WideTree {
public:
    WideTree() = default;
    /// Collapses `nodes` (breadth-first, levels starting at `level_start`) into wide nodes for
    /// the interior nodes at depths first_level(box_depth) + 2k.
    WideTree(const std::vector<Node> &nodes, const std::vector<uint32_t> &level_start,
             uint32_t box_depth);

    /// Depth of the shallowest binary nodes that get a wide node: the one just above the first
    /// sphere level (its children are spheres), or the root when there are no boxes.
    static uint32_t first_level(uint32_t box_depth) { return box_depth > 0 ? box_depth - 1 : 0; }

    /// The box depth the wide nodes were built for (the binary levels above use boxes).
    uint32_t box_depth() const { return box_depth_; }
    /// Whether binary node `i` has a wide node.
    bool has(uint32_t i) const { return i < of_.size() && of_[i] != kNoWide; }
    /// The wide node of binary node `i` (has(i) must hold).
    const WideNode &of(uint32_t i) const { return nodes_[of_[i]]; }
    /// Wide node `k` (a grandchild lane's ref).
    const WideNode &node(uint32_t k) const { return nodes_[k]; }
    const std::vector<WideNode> &nodes() const { return nodes_; }
    bool empty() const { return nodes_.empty(); }
    size_t memory_bytes() const {
        return nodes_.size() * sizeof(WideNode) + of_.size() * sizeof(uint32_t);
    }

private:
    std::vector<WideNode> nodes_;
    std::vector<uint32_t> of_;   ///< binary node -> wide node, kNoWide where none
    uint32_t box_depth_ = 0;
};

}  // namespace pointviz
