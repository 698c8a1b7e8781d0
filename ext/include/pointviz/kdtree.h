// pointviz — the conventional KD-tree the paper compares its hierarchy against (section 3):
// split planes only, no bounding volume per node, each surfel referenced from every leaf cell
// its disk overlaps, traversed front to back with the ray interval as in pbrt's KdTreeAccel.
//
// Splits: binned surface-area heuristic (SAH) with pbrt's empty-space bonus and bad-refine
// budget. The SAH tree is the conventional ray-tracing KD-tree (Havran; pbrt), and the strongest
// split-plane baseline: a spatial-median tree would walk more empty cells and flatter the paper's
// claim. Binning (kSahBins candidate planes per axis) makes the build O(references) per level.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include "pointviz/cast.h"
#include "pointviz/geometry.h"
#include "pointviz/progress.h"
#include "pointviz/tree.h"

namespace pointviz {

/// How to build a KD-tree (pbrt's KdTreeAccel parameters; costs in units of one node step).
struct KdBuildOptions {
    float intersect_cost = 2.f;   ///< cost of one ray-disk test, relative to one node step
    float empty_bonus = 0.5f;     ///< SAH discount for a split that leaves one side empty
    uint32_t max_leaf = 8;        ///< a node with at most this many references becomes a leaf
    uint32_t max_depth = 0;       ///< 0: pbrt's 8 + 1.3 log2(n)
};

/// One node of the KD-tree. 8 bytes (pbrt's KdAccelNode): four fit in half a cache line.
///
/// Interior: `axis()` 0..2, `split` the plane's coordinate; the child below the plane is the next
/// node, the one above is `above()`. Leaf: `count()` references starting at slot `first`.
struct KdNode {
    union {
        float split;      ///< interior: position of the splitting plane along axis()
        uint32_t first;   ///< leaf: first slot in KdTree::slots()
    };
    uint32_t bits;        ///< low 2 bits: axis (0..2) or 3 for a leaf; high 30: above child or count

    bool is_leaf() const { return (bits & 3u) == 3u; }
    uint32_t axis() const { return bits & 3u; }
    uint32_t above() const { return bits >> 2; }
    uint32_t count() const { return bits >> 2; }
};
static_assert(sizeof(KdNode) == 8, "KdNode is an 8-byte contract");

/// Most references in one leaf or node index: 30 bits.
constexpr uint32_t kKdMaxIndex = (1u << 30) - 1;
/// Fixed traversal stack; the depth limit (8 + 1.3 log2 n, at most 2^27 surfels) stays below it.
constexpr int kKdStackSize = 64;

/// Immutable KD-tree over surfels. Positions are stored in float relative to `origin`, like
/// SurfelTree. Each leaf's referenced surfels are copied into consecutive slots, so that a leaf
/// is tested with the same eight-wide disk test as the hierarchy's leaves.
class KdTree {
public:
    /// Builds the tree; polls `progress` (may be null): `total` grows with the references each
    /// split duplicates, `done` counts the references placed in leaves. Throws Cancelled.
    KdTree(const SurfelArrays &in, const double origin[3], const KdBuildOptions &opt,
           Progress *progress = nullptr);

    const std::vector<KdNode> &nodes() const { return nodes_; }
    /// Surfel copies in leaf order (a surfel appears once per leaf that references it).
    const std::vector<Surfel> &slots() const { return slots_; }
    /// slot_index()[k]: input index of the surfel in slot k.
    const std::vector<uint32_t> &slot_index() const { return slot_index_; }
    /// Bounds of all disks, in the local frame.
    const Box &bounds() const { return bounds_; }
    const double *origin() const { return origin_; }
    size_t n_surfels() const { return n_surfels_; }
    /// Deepest level of a leaf (the root is level 0).
    uint32_t depth() const { return depth_; }
    size_t memory_bytes() const;
    double build_seconds() const { return build_seconds_; }

private:
    std::vector<KdNode> nodes_;
    std::vector<Surfel> slots_;
    std::vector<uint32_t> slot_index_;
    Box bounds_{};
    double origin_[3];
    size_t n_surfels_ = 0;
    uint32_t depth_ = 0;
    double build_seconds_ = 0.0;
};

/// The traversal loop (pbrt's KdTreeAccel::Intersect): cells front to back, each with its ray
/// interval; stops once the policy's far bound lies before the next cell's entry. For the
/// closest-hit policy that bound is the end of the interpolation's depth window, so the search
/// goes on until every disk of the window has been found.
template <class Policy, class Stats>
void traverse(const KdTree &tree, const Ray &ray, bool cull, Policy &policy, Stats &stats);
// (traverse is defined in kdtree.cpp; closest_hit and any_hit below are instantiated there for
// the NoStats and CountStats hooks.)

/// Closest hit with the same interpolation as the hierarchy's (TraceOptions: cull, interp,
/// window; the KD-tree has no level of detail, the other fields are ignored).
template <class Stats>
bool closest_hit(const KdTree &tree, const Ray &ray, const TraceOptions &opt, SurfaceHit &out,
                 Stats &stats);

/// Any hit in [ray.tmin, ray.tmax]: shadow rays. Two-sided unless `cull` is asked for.
template <class Stats>
bool any_hit(const KdTree &tree, const Ray &ray, const TraceOptions &opt, bool cull, Stats &stats);

/// Batched queries in world coordinates, as cast_rays / occluded on a SurfelTree (cast.h);
/// `pixel_angle` is accepted for the same signature and unused (no level of detail).
template <class T>
void cast_rays(const KdTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats);
template <class T>
void occluded(const KdTree &tree, const T *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float pixel_angle, int threads, uint8_t *hit,
              bool count, BatchStats &stats);

/// A KD-tree seen from the render scene's frame (`offset` = scene origin - tree origin).
class KdGeometry final : public Geometry {
public:
    KdGeometry(const KdTree *tree, const TraceOptions &opt, Vec3 offset)
        : tree_(tree), opt_(opt), offset_(offset) {}
    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override;
    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override;

private:
    const KdTree *tree_;
    TraceOptions opt_;
    Vec3 offset_;
};

}  // namespace pointviz
