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
    /// The same queries for a batch of one kind of ray (lod.h, RayKind): a backend with a
    /// level of detail may choose it by what the rays are for; the others ignore the kind.
    virtual void intersect_as(const Ray *rays, size_t n, SurfaceHit *hits, RayKind) const {
        intersect(rays, n, hits);
    }
    virtual void occluded_as(const Ray *rays, size_t n, uint8_t *hit, RayKind) const {
        occluded(rays, n, hit);
    }
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
        : tree_(tree), offset_(offset), kernels_(query_kernels(opt.isa)) {
        for (int k = 0; k < kRayKinds; ++k) {
            opts_[k] = opt;
            opts_[k].kind = RayKind(k);
        }
    }

    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override {
        intersect_as(rays, n, hits, RayKind::Camera);
    }
    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override {
        occluded_as(rays, n, hit, RayKind::Camera);
    }
    void intersect_as(const Ray *rays, size_t n, SurfaceHit *hits, RayKind kind) const override {
        kernels_.intersect(*tree_, rays, n, offset_, opts_[int(kind)], hits);
    }
    void occluded_as(const Ray *rays, size_t n, uint8_t *hit, RayKind kind) const override {
        kernels_.occlude(*tree_, rays, n, offset_, opts_[int(kind)], hit);
    }
    /// Sets TraceOptions::budget_scale (before a render starts: not while it runs).
    void set_budget_scale(float s) {
        for (TraceOptions &o : opts_) o.budget_scale = s;
    }
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
    TraceOptions opts_[kRayKinds];   ///< the options, with each kind of ray (TraceOptions::kind)
    Vec3 offset_;
    const QueryKernels &kernels_;  ///< chosen once, at construction (dispatch.h)
};

}  // namespace pointviz
