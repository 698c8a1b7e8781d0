// pointviz — the surfel hierarchy (paper section 2.2): a KD-tree built by axis-aligned
// bisection, stored breadth-first so that the top levels, which carry boxes, are one prefix.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/node.h"
#include "pointviz/wide_node.h"

namespace pointviz {

/// How to build a tree.
struct BuildOptions {
    uint32_t leaf_size = 8;   ///< most surfels in a leaf (1..31)
    uint32_t box_depth = 0;   ///< nodes shallower than this get an axis-aligned box
    int threads = 0;          ///< 0: all cores
};

/// Input arrays of a build, all of length n (colors may be null: white).
struct SurfelArrays {
    const double *points = nullptr;   ///< (n, 3) world positions
    const float *normals = nullptr;   ///< (n, 3) unit normals
    const float *radii = nullptr;     ///< (n,) positive radii
    const float *colors = nullptr;    ///< (n, 3) in [0, 1], or null
    size_t n = 0;
};

/// Immutable surfel hierarchy. Positions are stored in float relative to `origin` (double), so
/// that georeferenced clouds far from the world origin keep their precision.
class SurfelTree {
public:
    SurfelTree(const SurfelArrays &in, const double origin[3], const BuildOptions &opt);

    const std::vector<Surfel> &surfels() const { return surfels_; }
    const std::vector<Node> &nodes() const { return nodes_; }
    /// Boxes of the nodes [0, boxes().size()): every node shallower than box_depth.
    const std::vector<Box> &boxes() const { return boxes_; }
    /// The same hierarchy collapsed into 4-wide nodes (wide_node.h); empty when the root is a leaf.
    const std::vector<WideNode> &wide() const { return wide_; }
    /// Lane boxes of the wide nodes [0, wide_boxes().size()).
    const std::vector<WideBoxes> &wide_boxes() const { return wide_boxes_; }
    /// order()[k] is the input index of the surfel stored at position k.
    const std::vector<uint32_t> &order() const { return order_; }
    /// First node index of each level; level_start().back() == nodes().size().
    const std::vector<uint32_t> &level_start() const { return level_start_; }
    const double *origin() const { return origin_; }
    uint32_t depth() const { return uint32_t(level_start_.size() - 1); }
    uint32_t box_depth() const { return box_depth_; }
    size_t memory_bytes() const;
    double build_seconds() const { return build_seconds_; }

private:
    std::vector<Surfel> surfels_;
    std::vector<Node> nodes_;
    std::vector<Box> boxes_;
    std::vector<WideNode> wide_;
    std::vector<WideBoxes> wide_boxes_;
    std::vector<uint32_t> order_;
    std::vector<uint32_t> level_start_;
    double origin_[3];
    uint32_t box_depth_ = 0;
    double build_seconds_ = 0.0;
};

}  // namespace pointviz
