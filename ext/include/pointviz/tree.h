// pointviz — the surfel hierarchy (paper section 2.2): a KD-tree built by axis-aligned
// bisection, stored breadth-first so that the top levels, which carry boxes, are one prefix.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/node.h"
#include "pointviz/wide.h"

namespace pointviz {

/// How to build a tree.
struct BuildOptions {
    uint32_t leaf_size = 8;   ///< most surfels in a leaf (1..31)
    uint32_t box_depth = 0;   ///< nodes shallower than this get an axis-aligned box
    int threads = 0;          ///< 0: all cores
    bool wide = true;         ///< also collapse the tree into wide nodes (wide.h) for the wide traversal
};

/// Input arrays of a build, all of length n (colors may be null: white).
struct SurfelArrays {
    const double *points = nullptr;   ///< (n, 3) world positions
    const float *normals = nullptr;   ///< (n, 3) unit normals
    const float *radii = nullptr;     ///< (n,) positive radii
    const float *colors = nullptr;    ///< (n, 3) in [0, 1], or null
    size_t n = 0;
};

class SurfelTreeBuild;

/// Immutable surfel hierarchy. Positions are stored in float relative to `origin` (double), so
/// that georeferenced clouds far from the world origin keep their precision.
class SurfelTree {
public:
    /// The whole build at once (the three stages of SurfelTreeBuild in a row).
    SurfelTree(const SurfelArrays &in, const double origin[3], const BuildOptions &opt);

    const std::vector<Surfel> &surfels() const { return surfels_; }
    const std::vector<Node> &nodes() const { return nodes_; }
    /// Boxes of the nodes [0, boxes().size()): every node shallower than box_depth.
    const std::vector<Box> &boxes() const { return boxes_; }
    /// The wide nodes collapsed from nodes() (wide.h), for the wide traversal (wide_trace.h).
    const WideTree &wide() const { return wide_; }
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
    friend class SurfelTreeBuild;
    SurfelTree() = default;

    std::vector<Surfel> surfels_;
    std::vector<Node> nodes_;
    std::vector<Box> boxes_;
    WideTree wide_;
    std::vector<uint32_t> order_;
    std::vector<uint32_t> level_start_;
    double origin_[3];
    uint32_t box_depth_ = 0;
    double build_seconds_ = 0.0;
};

/// A tree build in three stages, each reading one part of the input, so that a caller can free
/// every input array as soon as the build has copied it: the peak memory of a build from a cloud
/// that is handed over then stays near the tree's own size instead of the cloud's plus the tree's.
/// The stages run the same code as the one-call constructor: the trees are identical.
class SurfelTreeBuild {
public:
    /// Stage 1: positions in the local frame and the topology (in leaf order). `points` (n, 3)
    /// is not read after this returns.
    SurfelTreeBuild(const double *points, size_t n, const double origin[3], const BuildOptions &opt);
    /// Stage 2: the surfels in leaf order, from (n, 3) normals, (n,) radii and (n, 3) colours
    /// (null: white); none of them is read after this returns. Call once, before finish().
    void add_surfels(const float *normals, const float *radii, const float *colors);
    /// Stage 3: the nodes' spheres, cones, slabs, mean attributes and boxes. The build is spent.
    SurfelTree finish();

    size_t size() const { return n_; }
    /// Which stage is next: 2 (add_surfels), 3 (finish) or 4 (spent).
    int next_stage() const { return stage_; }

private:
    /// Local float position and input index: partitioning these 16-byte items in place keeps the
    /// topology's memory access sequential.
    struct Item {
        Vec3 p;
        uint32_t i;
    };
    /// Half-open range of the leaf order that a node owns.
    struct Range {
        uint32_t b, e;
        uint32_t size() const { return e - b; }
    };
    void check_stage(int stage) const;

    SurfelTree tree_;
    size_t n_ = 0;
    uint32_t leaf_ = 8, box_depth_ = 0;
    int threads_ = 1;
    bool wide_ = true;
    int stage_ = 2;
    std::vector<Item> items_;
    std::vector<Range> ranges_;
    std::vector<uint32_t> first_child_;
};

}  // namespace pointviz
