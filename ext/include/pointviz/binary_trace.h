// pointviz — traversal of the binary surfel hierarchy (paper sections 2.1–2.2.2), and what every
// traversal shares: options, the closest-hit and any-hit policies, statistics hooks, and the
// leaf and level-of-detail disk tests.
//
// One traversal loop serves both queries: a closest-hit policy gathers the disks around the
// nearest hit and interpolates them; an any-hit policy stops at the first disk (shadow rays).
// Statistics are collected by a hook type, so the plain path carries no counters.
#pragma once

#include <algorithm>
#include <cstdint>

#include "pointviz/leaf_simd.h"
#include "pointviz/query.h"
#include "pointviz/tree.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN


/// Whether `nd`, seen at ray parameter t2 along `ray`, is small enough to stop descending.
/// `radius` and `cone` are the node's sphere radius and cone sine (Node::cone()).
inline bool lod_stop(float radius, float cone, const Ray &ray, float t2, const TraceOptions &opt) {
    const float size = 2.f * radius, fp = opt.lod_pixels * ray.footprint(t2);
    if (opt.lod_criterion == LodCriterion::Size) return size <= fp;
    // A node's disk stands in for a curved patch badly in proportion to its normal spread;
    // kFlatFloor keeps a perfectly flat node from counting as zero deviation.
    constexpr float kFlatFloor = 0.05f;
    const float spread = std::min(1.f, std::max(cone, kFlatFloor));
    return size * spread <= fp && size <= opt.lod_max_extent * fp;
}

/// Statistics hook that counts nothing (the fast path).
struct NoStats {
    void node(uint32_t) {}
    void disk() {}
};

/// Statistics hook for the paper's Figure 6: nodes visited, disk tests, deepest level reached.
struct CountStats {
    uint64_t nodes = 0, disks = 0;
    uint32_t max_depth = 0;
    void node(uint32_t depth) {
        ++nodes;
        max_depth = std::max(max_depth, depth);
    }
    void disk() { ++disks; }
};

/// Rays whose cosine with the nearest disk is below this are treated as if it were this large
/// when the depth window is turned into a ray interval: at grazing angles the window would
/// otherwise stretch along the ray without bound and swallow surfaces behind.
constexpr float kWindowMinCos = 0.2f;
/// Most disks gathered around a hit; overlapping disks of a well-sampled surface number 3–6.
constexpr int kGather = 8;
/// Each LoD node is drawn as a disk of the node's sphere radius times this (QSplat's splat size).
constexpr float kLodDiskScale = 1.f;
/// Fixed traversal stack; the median-split tree is at most 32 levels deep (a wide node pushes at
/// most three entries per two levels).
constexpr int kStackSize = 64;

namespace detail {

/// One disk the ray crossed, kept until the traversal ends.
struct Candidate {
    float t, u2, facing, r;
    uint32_t ref;   ///< surfel index, or node index | kNodeFlag for a LoD disk
};
constexpr uint32_t kNodeFlag = 0x80000000u;

/// Closest-hit policy: keeps the disks within the depth window of the nearest one.
struct Gather {
    Candidate c[kGather];
    int n = 0;
    float limit;         ///< current far bound of the search
    float ray_tmax;
    float window;

    Gather(float tmax, float window_) : limit(tmax), ray_tmax(tmax), window(window_) {}
    /// Order of the gathered disks: by t, ties by reference, so that the blend does not
    /// depend on the order in which a traversal finds them.
    static bool before(const Candidate &a, const Candidate &b) {
        return a.t < b.t || (a.t == b.t && a.ref < b.ref);
    }
    float tfar() const { return limit; }
    /// Returns true to stop the traversal (never, for closest hit).
    bool add(const Candidate &k) {
        if (k.t > limit) return false;
        int pos = n < kGather ? n : kGather - 1;
        if (n == kGather && !before(k, c[kGather - 1])) return false;
        while (pos > 0 && before(k, c[pos - 1])) {
            c[pos] = c[pos - 1];
            --pos;
        }
        c[pos] = k;
        if (n < kGather) ++n;
        const Candidate &best = c[0];
        float cosv = std::max(std::fabs(best.facing), kWindowMinCos);
        limit = std::min(ray_tmax, best.t + window * best.r / cosv);
        while (n > 0 && c[n - 1].t > limit) --n;
        return false;
    }
};

/// Any-hit policy: the first disk in range ends the search.
struct AnyHit {
    float limit;
    bool hit = false;
    explicit AnyHit(float tmax) : limit(tmax) {}
    float tfar() const { return limit; }
    bool add(const Candidate &) {
        hit = true;
        return true;
    }
};

struct StackEntry {
    uint32_t node;
    float t;           ///< entry parameter of its bound
    uint16_t depth;
    uint16_t cull;     ///< whether the subtree still needs cone tests
};

/// Tests the ray against node `i`'s bound: its box above `box_depth`, below it its sphere (cut
/// by its slab with kSlabs). Returns the entry t or kInf.
template <bool kSlabs>
inline float enter_bound(const SurfelTree &tree, uint32_t i, uint32_t depth, const Ray &ray,
                         Vec3 inv_d, float tfar, uint32_t box_depth) {
    if (depth < box_depth && i < tree.boxes().size())
        return enter_box(tree.boxes()[i], ray.o, inv_d, ray.tmin, tfar);
    if constexpr (kSlabs) return enter_sphere_slab(tree.nodes()[i], ray.o, ray.d, ray.tmin, tfar);
    const Node &nd = tree.nodes()[i];
    return enter_sphere(nd.c, nd.radius, ray.o, ray.d, ray.tmin, tfar);
}

/// Cone test (culling): false when every normal under the node faces away from the ray (skip
/// it); clears `cull` when every normal faces the ray (its subtree needs no more cone tests).
/// `axis` as decoded from the node, `cone` its sine (Node::cone()).
inline bool cone_admits(Vec3 axis, float cone, const Ray &ray, bool &cull) {
    float c = dot(axis, ray.d);
    if (c > cone) return false;
    if (c < -cone) cull = false;
    return true;
}

/// Level of detail at an interior node: whether it is small enough to be drawn as its
/// children's disks. A node whose normals span more than a hemisphere (two sheets of a thin
/// part, a closed piece) has no meaningful mean plane: its disk would face anywhere, so LoD
/// descends until the children face one way.
inline bool lod_here(Vec3 c, float radius, bool has_cone, float cone, const Ray &ray,
                     const TraceOptions &opt) {
    if (!has_cone) return false;
    float t2 = dot(c - ray.o, ray.d);
    return t2 > 0.f && lod_stop(radius, cone, ray, t2, opt);
}

/// Tests the disks of a leaf, surfels [b, b + cnt). Returns true when the policy stops.
template <class Policy, class Stats>
inline bool leaf_disks(const SurfelTree &tree, uint32_t b, uint32_t cnt, const Ray &ray,
                       bool cull, Policy &policy, Stats &stats) {
    const auto &surfels = tree.surfels();
    // Every disk of the leaf is tested against the search bound at the leaf's entry (the
    // policy then drops those beyond its current bound): one disk or eight at a time, the
    // same disks reach the policy.
    const float tfar = policy.tfar();
#if defined(POINTVIZ_LEAF_SIMD)
    if (cnt <= 8) {
        LeafHits lh;
        intersect_leaf8(ray, &surfels[b], cnt, tfar, cull, lh);
        for (uint32_t k = 0; k < cnt; ++k) stats.disk();
        for (uint32_t m = lh.mask; m != 0; m &= m - 1) {
            uint32_t k = uint32_t(__builtin_ctz(m));
            if (policy.add({lh.t[k], lh.u2[k], lh.facing[k], surfels[b + k].r, b + k})) return true;
        }
        return false;
    }
#endif
    for (uint32_t k = b; k < b + cnt; ++k) {
        const Surfel &s = surfels[k];
        stats.disk();
        float facing;
        DiskHit h;
        if (!intersect_disk(ray, s.p, s.n, s.r, tfar, cull, facing, h)) continue;
        if (policy.add({h.t, h.u2, facing, s.r, k})) return true;
    }
    return false;
}

/// Level of detail: the two children c0, c0 + 1 of a node small enough to stop at, tested as
/// disks (centre, mean normal, sphere radius). Returns true when the policy stops.
template <class Policy, class Stats>
inline bool lod_disks(const SurfelTree &tree, uint32_t c0, const Ray &ray, bool cull,
                      Policy &policy, Stats &stats) {
    for (uint32_t ch = c0; ch < c0 + 2; ++ch) {
        const Node &cn = tree.nodes()[ch];
        stats.disk();
        Vec3 cnorm = normalize(cn.axis());
        if (cull && dot(cnorm, ray.d) > cn.cone()) continue;
        float r = cn.radius * kLodDiskScale;
        float facing;
        DiskHit h;
        if (!intersect_disk(ray, cn.c, cnorm, r, policy.tfar(), cull, facing, h)) continue;
        if (policy.add({h.t, h.u2, facing, r, ch | kNodeFlag})) return true;
    }
    return false;
}

}  // namespace detail

/// The traversal loop shared by every query (paper Figure 3b).
///
/// `cull` asks for back-face culling: disks facing away from the ray are skipped, and so are
/// subtrees whose normal cone faces away entirely; once a cone faces the ray entirely its
/// subtree is not tested again.
template <bool kSlabs, class Policy, class Stats>
void traverse_binary(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt, bool cull,
                   Policy &policy, Stats &stats) {
    using namespace detail;
    const auto &nodes = tree.nodes();
    const Vec3 inv_d{1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z};
    const bool lod = opt.lod && ray.spread > 0.f;
    const uint32_t box_depth = opt.box_depth;

    StackEntry stack[kStackSize];
    int sp = 0;
    auto enter = enter_bound<kSlabs>;
    float t_root = enter(tree, 0, 0, ray, inv_d, policy.tfar(), box_depth);
    if (t_root == kInf) return;
    // The current node; the near child of an interior node is taken next without a push.
    StackEntry e{0u, t_root, 0, uint16_t(cull)};

    for (;;) {
        bool descend = false;
        const Node &nd = nodes[e.node];
        stats.node(e.depth);
        bool sub_cull = e.cull != 0;
        if (sub_cull && nd.has_cone() && !cone_admits(nd.axis(), nd.cone(), ray, sub_cull)) {
        } else if (nd.is_leaf()) {
            if (leaf_disks(tree, nd.index(), nd.count(), ray, sub_cull, policy, stats)) return;
        } else {
            const uint32_t c0 = nd.index();
            if (lod && lod_here(nd.c, nd.radius, nd.has_cone(), nd.cone(), ray, opt)) {
                // Small enough: intersect the children as disks and let the policy blend them.
                if (lod_disks(tree, c0, ray, sub_cull, policy, stats)) return;
            } else {
                const uint16_t cd = uint16_t(e.depth + 1);
                const uint16_t cf = uint16_t(sub_cull);
                float ta = enter(tree, c0, cd, ray, inv_d, policy.tfar(), box_depth);
                float tb = enter(tree, c0 + 1, cd, ray, inv_d, policy.tfar(), box_depth);
                if (ta != kInf || tb != kInf) {
                    descend = true;
                    if (ta <= tb) {
                        if (tb != kInf) stack[sp++] = {c0 + 1, tb, cd, cf};
                        e = {c0, ta, cd, cf};
                    } else {
                        if (ta != kInf) stack[sp++] = {c0, ta, cd, cf};
                        e = {c0 + 1, tb, cd, cf};
                    }
                }
            }
        }
        if (descend) continue;
        // Pop the nearest pending subtree that can still hold a closer hit.
        do {
            if (sp == 0) return;
            e = stack[--sp];
        } while (e.t > policy.tfar());
    }
}

POINTVIZ_ISA_END
}  // namespace pointviz
