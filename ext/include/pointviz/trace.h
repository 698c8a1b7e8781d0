// pointviz — the two ray queries on a surfel tree (paper sections 2.1–2.2.2): the closest hit,
// with the disks around it interpolated, and any hit (shadow rays). Both run the wide traversal
// (wide_trace.h) or, with TraceOptions::wide off, the binary one (binary_trace.h).
#pragma once

#include "pointviz/wide_trace.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

template <class Policy, class Stats>
void traverse(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt, bool cull,
              Policy &policy, Stats &stats) {
    if (opt.wide) {
        if (opt.slabs) traverse_wide<true>(tree, ray, opt, cull, policy, stats);
        else traverse_wide<false>(tree, ray, opt, cull, policy, stats);
    } else {
        if (opt.slabs) traverse_binary<true>(tree, ray, opt, cull, policy, stats);
        else traverse_binary<false>(tree, ray, opt, cull, policy, stats);
    }
}

/// Attributes of a gathered disk: surfel or LoD node.
inline void candidate_attributes(const SurfelTree &tree, uint32_t ref, Vec3 &n, Vec3 &color) {
    if (ref & detail::kNodeFlag) {
        const Node &nd = tree.nodes()[ref & ~detail::kNodeFlag];
        n = normalize(nd.axis());
        uint32_t c = nd.rgba();
        color = {channel(c, 0), channel(c, 1), channel(c, 2)};
    } else {
        const Surfel &s = tree.surfels()[ref];
        n = s.n;
        color = {channel(s.rgba, 0), channel(s.rgba, 1), channel(s.rgba, 2)};
    }
}

/// Closest hit with interpolation over the disks facing the same way as the nearest one,
/// within the depth window (paper section 2.1).
template <class Stats>
bool closest_hit(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                 SurfaceHit &out, Stats &stats) {
    detail::Gather g(ray.tmax, opt.window);
    traverse(tree, ray, opt, opt.cull, g, stats);
    out = SurfaceHit{};
    if (g.n == 0) return false;
    const detail::Candidate &best = g.c[0];
    const bool front = best.facing < 0.f;
    float wsum = 0.f, tsum = 0.f, rsum = 0.f;
    Vec3 nsum{0, 0, 0}, csum{0, 0, 0};
    uint32_t used = 0;
    const int m = opt.interp == Interpolation::None ? 1 : g.n;
    for (int k = 0; k < m; ++k) {
        const detail::Candidate &c = g.c[k];
        if ((c.facing < 0.f) != front) continue;
        float w;
        switch (opt.interp) {
            case Interpolation::Paper: w = std::sqrt(c.u2) * c.r; break;
            case Interpolation::Smooth: w = (1.f - c.u2) * (1.f - c.u2); break;
            default: w = 1.f; break;
        }
        // Keeps a disk hit exactly at its rim (or, for Paper, at its centre) from vanishing
        // entirely when it is the only one.
        w += 1e-6f;
        Vec3 n, col;
        candidate_attributes(tree, c.ref, n, col);
        wsum += w;
        tsum += w * c.t;
        rsum += w * c.r;
        nsum += n * w;
        csum += col * w;
        ++used;
    }
    out.t = tsum / wsum;
    out.n = normalize(nsum);
    if (!(length2(out.n) > 0.5f)) {  // blended normals cancelled out: keep the nearest
        Vec3 unused;
        candidate_attributes(tree, best.ref, out.n, unused);
    }
    out.color = csum / wsum;
    out.radius = rsum / wsum;
    out.index = (best.ref & detail::kNodeFlag) ? -2 : int32_t(best.ref);
    out.count = used;
    return true;
}

/// Any hit in [ray.tmin, ray.tmax]: shadow rays. Two-sided unless `cull` is asked for.
template <class Stats>
bool any_hit(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt, bool cull,
             Stats &stats) {
    detail::AnyHit a(ray.tmax);
    traverse(tree, ray, opt, cull, a, stats);
    return a.hit;
}

POINTVIZ_ISA_END
}  // namespace pointviz
