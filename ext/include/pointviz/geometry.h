// pointviz — the geometry interface every renderer backend implements: surfel trees natively,
// triangle meshes through a callback (embreex), so that one shading code serves both.
#pragma once

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

private:
    const SurfelTree *tree_;
    TraceOptions opt_;
    Vec3 offset_;
    const QueryKernels &kernels_;  ///< chosen once, at construction (dispatch.h)
};

}  // namespace pointviz
