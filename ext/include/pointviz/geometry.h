// pointviz — the geometry interface every renderer backend implements: surfel trees natively,
// triangle meshes through a callback (embreex), so that one shading code serves both.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "pointviz/dispatch.h"
#include "pointviz/trace.h"

namespace pointviz {

/// A batch query interface in the render scene's local frame. Closest-hit and any-hit come in
/// a pair and both honour each ray's [tmin, tmax].
class Geometry {
public:
    virtual ~Geometry() = default;
    /// Closest hits; `hits[i].t == kInf` on a miss.
    virtual void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const = 0;
    /// Any hit; `hit[i]` is 1 when something lies in the ray's interval.
    virtual void occluded(const Ray *rays, size_t n, uint8_t *hit) const = 0;
    /// Whether several threads may query at once (a Python callback may not).
    virtual bool thread_safe() const { return true; }
    /// A box, in the scene's frame, around everything a ray can hit here: rays that miss it
    /// need not be queried (the renderer skips them). False: no such box is known.
    virtual bool bounds(Box &) const { return false; }
};

/// A surfel tree seen from the render scene's frame (`offset` = scene origin - tree origin).
class SurfelGeometry final : public Geometry {
public:
    SurfelGeometry(const SurfelTree *tree, const TraceOptions &opt, Vec3 offset)
        : tree_(tree), opt_(opt), offset_(offset), kernels_(query_kernels(opt.isa)) {}

    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override {
        kernels_.intersect(*tree_, rays, n, offset_, opt_, hits);
    }
    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override {
        kernels_.occlude(*tree_, rays, n, offset_, opt_, hit);
    }
    /// Sets TraceOptions::budget_scale (before a render starts: not while it runs).
    void set_budget_scale(float s) { opt_.budget_scale = s; }
    /// The root's box (where the tree has one) joined with its sphere's: a traversal enters
    /// the root through one of them, so a ray that misses both can hit nothing.
    bool bounds(Box &out) const override {
        if (tree_->nodes().empty()) return false;
        const Node &root = tree_->nodes()[0];
        const Vec3 r{root.radius, root.radius, root.radius};
        Box b{root.c - r, root.c + r};
        if (!tree_->boxes().empty()) {
            const Box &rb = tree_->boxes()[0];
            b.lo = {std::min(b.lo.x, rb.lo.x), std::min(b.lo.y, rb.lo.y), std::min(b.lo.z, rb.lo.z)};
            b.hi = {std::max(b.hi.x, rb.hi.x), std::max(b.hi.y, rb.hi.y), std::max(b.hi.z, rb.hi.z)};
        }
        out = {b.lo - offset_, b.hi - offset_};
        return true;
    }

private:
    const SurfelTree *tree_;
    TraceOptions opt_;
    Vec3 offset_;
    const QueryKernels &kernels_;  ///< chosen once, at construction (dispatch.h)
};

}  // namespace pointviz
