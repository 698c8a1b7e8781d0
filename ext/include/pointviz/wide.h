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
// Bounds are boxes above SurfelTree::box_depth and spheres cut by their node's mean-plane slab
// below, as in the binary traversal. The wide levels are every other level, aligned so that no
// wide node mixes the two: box nodes (WideBoxNode) for the interior nodes at depths
// first_level() - 2k, sphere nodes (WideNode) at first_level() + 2k. When first_level() is odd
// the root takes one binary step.
//
// Memory: one 192-byte WideNode or 256-byte WideBoxNode per interior binary node at a wide level
// (about a third of the interior nodes), plus a 4-byte index per binary node: 12-17 bytes per
// surfel on top of the binary tree's 46-47 with the default 8-surfel leaves (measured: 12.3 on
// 400k-surfel sphere and torus samplings, 16.5 on the dragon's raw scans, whose leaves are
// fuller of small subtrees). SurfelTree::memory_bytes counts both; BuildOptions::wide = false
// builds none.
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

/// Six box-bounded nodes, lane by lane (the levels above SurfelTree::box_depth): the binary
/// tree's boxes (Box), and cones and refs as in WideNode. Children of a leaf are absent lanes
/// (the traversal masks them: A's or B's ref says it is a leaf). 256 bytes, four cache lines:
/// 24 box, 6 axis, 2 cone, 4 ref per lane and 40 bytes of padding.
struct alignas(64) WideBoxNode {
    float lx[kWideUsed], ly[kWideUsed], lz[kWideUsed];   ///< Box::lo
    float hx[kWideUsed], hy[kWideUsed], hz[kWideUsed];   ///< Box::hi
    int16_t ax[kWideUsed], ay[kWideUsed], az[kWideUsed]; ///< Node::axis_q
    uint16_t cone_q[kWideUsed];                          ///< Node::cone_q
    uint32_t pad_;
    uint32_t ref[kWideUsed];                             ///< as WideNode::ref (box or sphere node)
};
static_assert(sizeof(WideBoxNode) == 256, "WideBoxNode is a 256-byte contract");
static_assert(offsetof(WideBoxNode, ref) >= offsetof(WideBoxNode, cone_q) + 16,
              "the sixteen-byte load of cone_q stays inside the node");

/// The wide nodes of one binary tree, built from it (collapse) and read-only afterwards.
class WideTree {
public:
    WideTree() = default;
    /// Collapses `nodes` (breadth-first, levels starting at `level_start`; `boxes` those of the
    /// levels above `box_depth`) into wide nodes for the interior nodes at the wide levels.
    WideTree(const std::vector<Node> &nodes, const std::vector<Box> &boxes,
             const std::vector<uint32_t> &level_start, uint32_t box_depth);

    /// Depth of the shallowest binary nodes that get a sphere node: the one just above the
    /// first sphere level (its children are spheres), or the root when there are no boxes.
    static uint32_t first_level(uint32_t box_depth) { return box_depth > 0 ? box_depth - 1 : 0; }

    /// The box depth the wide nodes were built for.
    uint32_t box_depth() const { return box_depth_; }
    /// Whether the wide node of a node at `depth` (a wide level) is a box node.
    bool box_level(uint32_t depth) const { return depth < first_level(box_depth_); }
    /// Whether binary node `i` has a wide node.
    bool has(uint32_t i) const { return i < of_.size() && of_[i] != kNoWide; }
    /// The index of binary node `i`'s wide node (has(i) must hold) in box_nodes() or nodes(),
    /// as box_level says.
    uint32_t index_of(uint32_t i) const { return of_[i]; }
    /// Sphere node `k`.
    const WideNode &node(uint32_t k) const { return nodes_[k]; }
    /// Box node `k`.
    const WideBoxNode &box_node(uint32_t k) const { return box_nodes_[k]; }
    const std::vector<WideNode> &nodes() const { return nodes_; }
    const std::vector<WideBoxNode> &box_nodes() const { return box_nodes_; }
    bool empty() const { return nodes_.empty() && box_nodes_.empty(); }
    size_t memory_bytes() const {
        return nodes_.size() * sizeof(WideNode) + box_nodes_.size() * sizeof(WideBoxNode) +
               of_.size() * sizeof(uint32_t);
    }

private:
    std::vector<WideNode> nodes_;
    std::vector<WideBoxNode> box_nodes_;
    std::vector<uint32_t> of_;   ///< binary node -> wide node, kNoWide where none
    uint32_t box_depth_ = 0;
};

}  // namespace pointviz
