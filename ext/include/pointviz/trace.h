// pointviz — ray traversal of the surfel hierarchy (paper sections 2.1–2.2.2).
//
// One traversal loop serves both queries: a closest-hit policy gathers the disks around the
// nearest hit and interpolates them; an any-hit policy stops at the first disk (shadow rays).
// Statistics are collected by a hook type, so the plain path carries no counters.
#pragma once

#include <algorithm>
#include <cstdint>
#include <type_traits>

#include "pointviz/disk_kernel.h"
#include "pointviz/isa.h"
#include "pointviz/leaf_simd.h"
#include "pointviz/lod.h"
#include "pointviz/tree.h"

/// Inlined whatever the compiler's inlining budget says: steps factored out of the single-ray
/// traversal so that the packet traversal (packet_trace.h) can share them; always inlined, the
/// single-ray traversal compiles as it did with them written in place.
#define POINTVIZ_HOT_INLINE __attribute__((always_inline)) inline

namespace pointviz {

/// How the disks around a hit are combined (section 2.1).
enum class Interpolation : uint8_t {
    None = 0,    ///< the nearest disk alone (the baseline: disks stick out)
    Paper = 1,   ///< weights |I - p_i|, as printed in the paper (Schaufler & Jensen's scheme)
    Smooth = 2,  ///< weights (1 - (|I - p_i| / r_i)^2)^2: full at the centre, zero at the rim
};

/// When a node is small enough to stop descending (paper section 2.2.1 and its open question).
enum class LodCriterion : uint8_t {
    Size = 0,       ///< the paper's: the node's sphere diameter projects below lod_pixels
    Deviation = 1,  ///< the node's deviation from its mean plane (diameter x sin of the normal
                    ///< cone's half-angle) projects below lod_pixels: flat nodes stop earlier
    Budget = 2,     ///< the error budget (lod.h): nodes whose predicted error fits in max_error
                    ///< stop, and so do nodes below lod_pixels footprints (the size rule, which
                    ///< the caller scales with the budget; 0 turns it off)
};

/// Knobs of one traversal; the paper's variants are combinations of these.
struct TraceOptions {
    bool lod = true;          ///< stop at nodes smaller than lod_pixels footprints (needs ray.spread > 0)
    float lod_pixels = 1.f;   ///< LoD threshold: sphere diameter in units of the ray footprint
    bool cull = true;         ///< back-face culling with normal cones (closest-hit queries only)
    uint32_t box_depth = 0;   ///< nodes shallower than this are bounded by boxes, the rest by spheres
    bool slabs = true;        ///< intersect each sphere with its node's mean-plane slab (beyond the paper)
    Interpolation interp = Interpolation::Smooth;
    float window = 1.f;       ///< depth window, in radii of the nearest disk, measured along its normal
    LodCriterion lod_criterion = LodCriterion::Size;
    float lod_max_extent = 8.f;  ///< Deviation only: never stop at nodes wider than this many footprints
    float max_error = 0.f;       ///< Budget only: mean FLIP the frame may lose to LoD (lod.h)
    /// Budget only: factor on the per-pixel budget of primary rays, the inverse of the share of
    /// the frame's pixels that may see the tree at all (the budget bounds the frame's mean, and
    /// pixels that miss the tree cost nothing); 1: every pixel may. Secondary rays keep 1: what
    /// they change (shadows on the ground) is not confined to those pixels.
    float budget_scale = 1.f;
    Isa isa = Isa::Auto;      ///< kernels of the batch queries (dispatch.h); all give the same results
    /// Traverse the wide tree (wide.h, wide_trace.h): two levels' bounds tested at once with
    /// SIMD, the binary traversal's decisions. false: the binary traversal, for comparison.
    bool wide = true;
    /// Closest hits of coherent groups of rays (one origin, close directions: camera rays in
    /// raster order) traverse the wide tree as packets (packet_trace.h); same results as one
    /// ray at a time, bit for bit. false: one ray at a time, for comparison.
    bool packets = true;
    /// Budget only: what the batch's secondary rays (width0 > 0) are for, which picks their
    /// error model (lod.h, RayKind); Camera: not said (the predictor's share, as for any ray).
    RayKind kind = RayKind::Camera;
    /// Budget only: the visibility model's weights of shadow and sky-visibility rays (lod.h;
    /// the defaults are the calibrated ones, benchmarks/lod_budget.py --secondary varies them).
    float shadow_flip_weight = kShadowFlipWeight;
    float sky_flip_weight = kSkyFlipWeight;
    /// Budget only: the colour term's response at one footprint (lod.h, kColourPixelResponse;
    /// benchmarks/lod_budget.py --colour varies it).
    float colour_pixel_response = kColourPixelResponse;
};

POINTVIZ_ISA_BEGIN

/// Budget only: the error a pixel may take above the floor, and the size rule's share, for
/// primary or secondary rays (secondary rays start with a width). Secondary rays skip the share:
/// its nodes may tilt by anything, and one at the ray's origin would shadow the surface it
/// leaves. The budget's own nodes deviate from their plane by under 1 % of their size.
inline float ray_budget(bool secondary, const TraceOptions &opt) {
    return (opt.max_error - kBudgetFloor) * (secondary ? 1.f : opt.budget_scale);
}
inline float ray_size_share(bool secondary, const TraceOptions &opt) {
    return secondary ? 0.f : opt.lod_pixels;
}

/// The gates of lod_stop (lod.h, LodGate) for primary and secondary rays under one set of
/// options, found once per batch: under the budget, the nodes whose colour or cone rule them out
/// at any footprint; otherwise only nodes without a cone.
struct LodGates {
    LodGate primary, secondary;
    const LodGate &of(const Ray &ray) const { return ray.width0 > 0.f ? secondary : primary; }
};
/// Whether the batch's secondary rays take the visibility model (lod.h): shadow and
/// sky-visibility rays.
inline bool visibility_kind(const TraceOptions &opt) {
    return opt.kind == RayKind::Shadow || opt.kind == RayKind::Sky;
}
inline float flip_weight(const TraceOptions &opt) {
    return opt.kind == RayKind::Sky ? opt.sky_flip_weight : opt.shadow_flip_weight;
}
inline LodGates lod_gates(const TraceOptions &opt) {
    LodGates g;
    if (opt.lod_criterion == LodCriterion::Budget) {
        g.primary = budget_gate(ray_budget(false, opt), ray_size_share(false, opt),
                                opt.colour_pixel_response);
        g.secondary = visibility_kind(opt)
                          ? visibility_gate(ray_budget(true, opt), flip_weight(opt))
                          : budget_gate(ray_budget(true, opt), ray_size_share(true, opt),
                                        opt.colour_pixel_response);
    }
    return g;
}

/// Whether `nd`, seen at ray parameter t2 along `ray`, is small enough to stop descending.
inline bool lod_stop(const Node &nd, const Ray &ray, float t2, const TraceOptions &opt) {
    const float size = 2.f * nd.radius;
    if (opt.lod_criterion == LodCriterion::Budget) {
        const bool secondary = ray.width0 > 0.f;
        if (secondary && visibility_kind(opt)) {
            // a sky-visibility ray stands for a solid angle: its cone joins the pixel's beam
            const float fp = ray.footprint(t2) + (opt.kind == RayKind::Sky ? kSkyConeSpread * t2 : 0.f);
            return visibility_allows(nd, fp, length2(nd.c - ray.o), ray_budget(true, opt),
                                     flip_weight(opt));
        }
        return budget_allows(nd, ray.footprint(t2), ray_budget(secondary, opt),
                             ray_size_share(secondary, opt), opt.colour_pixel_response);
    }
    const float fp = opt.lod_pixels * ray.footprint(t2);
    if (opt.lod_criterion == LodCriterion::Size) return size <= fp;
    // A node's disk stands in for a curved patch badly in proportion to its normal spread;
    // kFlatFloor keeps a perfectly flat node from counting as zero deviation.
    constexpr float kFlatFloor = 0.05f;
    const float spread = std::min(1.f, std::max(nd.cone(), kFlatFloor));
    return size * spread <= fp && size <= opt.lod_max_extent * fp;
}

POINTVIZ_ISA_END

/// What a closest-hit query returns.
struct SurfaceHit {
    float t = kInf;        ///< blended ray parameter; kInf on a miss
    Vec3 n;                ///< blended unit normal (as stored: may face away from the ray)
    Vec3 color;            ///< blended colour in [0, 1]
    float radius = 0.f;    ///< blended disk radius (the local sampling scale)
    int32_t index = -1;    ///< nearest surfel (tree order); -2 when it was a LoD node disk; -1 miss
    uint32_t count = 0;    ///< how many disks were blended
};

POINTVIZ_ISA_BEGIN

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
/// Fixed traversal stack; the median-split tree is at most 32 levels deep.
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
    float tfar() const { return limit; }
    /// Returns true to stop the traversal (never, for closest hit).
    bool add(const Candidate &k) {
        if (k.t > limit) return false;
        int pos = n < kGather ? n : kGather - 1;
        if (n == kGather && k.t >= c[kGather - 1].t) return false;
        while (pos > 0 && c[pos - 1].t > k.t) {
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
    uint16_t cull;     ///< kCull: the subtree still needs cone tests; kVisited (wide traversal):
                       ///< the node's cone was tested when it was pushed
    uint32_t ref;      ///< with kVisited: the node's WideNode::ref (leaf range or wide node)
};
// No default member initialisers: a traversal's stack (kStackSize entries) is left
// uninitialised instead of being written on every ray.
static_assert(std::is_trivially_default_constructible<StackEntry>::value,
              "the traversal stack is not initialised per ray");
/// kCounted (wide traversal, with kVisited): counted as well (A and B leaves; the grandchildren
/// it pushes are counted when popped, as the binary traversal counts them).
constexpr uint16_t kCull = 1, kVisited = 2, kCounted = 4;

/// Tests the ray against node `i`'s bound, box or sphere by depth. Returns the entry t or kInf.
inline float enter_node(const SurfelTree &tree, uint32_t i, uint32_t depth, const Ray &ray,
                        Vec3 inv_d, float tfar, uint32_t box_depth) {
    if (depth < box_depth && i < tree.boxes().size())
        return enter_box(tree.boxes()[i], ray.o, inv_d, ray.tmin, tfar);
    const Node &nd = tree.nodes()[i];
    return enter_sphere(nd.c, nd.radius, ray.o, ray.d, ray.tmin, tfar);
}

/// The same with each sphere cut by its node's slab.
template <bool kSlabs>
inline float enter_bound(const SurfelTree &tree, uint32_t i, uint32_t depth, const Ray &ray,
                         Vec3 inv_d, float tfar, uint32_t box_depth) {
    if (depth < box_depth && i < tree.boxes().size())
        return enter_box(tree.boxes()[i], ray.o, inv_d, ray.tmin, tfar);
    if constexpr (kSlabs) return enter_sphere_slab(tree.nodes()[i], ray.o, ray.d, ray.tmin, tfar);
    const Node &nd = tree.nodes()[i];
    return enter_sphere(nd.c, nd.radius, ray.o, ray.d, ray.tmin, tfar);
}

/// A binary step at interior node `nd`: tests both children's bounds within [ray.tmin, tfar],
/// pushes the farther one hit and makes the nearer one `e`, the current node (no push). Returns
/// false when both are missed.
template <bool kSlabs>
inline bool binary_step(const SurfelTree &tree, const Node &nd, const Ray &ray, Vec3 inv_d,
                        float tfar, uint32_t box_depth, bool cull, StackEntry &e,
                        StackEntry *stack, int &sp) {
    const uint32_t c0 = nd.index();
    const uint16_t cd = uint16_t(e.depth + 1);
    const uint16_t cf = uint16_t(cull ? kCull : 0);
    float ta = enter_bound<kSlabs>(tree, c0, cd, ray, inv_d, tfar, box_depth);
    float tb = enter_bound<kSlabs>(tree, c0 + 1, cd, ray, inv_d, tfar, box_depth);
    if (ta == kInf && tb == kInf) return false;
    if (ta <= tb) {
        if (tb != kInf) stack[sp++] = {c0 + 1, tb, cd, cf, 0u};
        e = {c0, ta, cd, cf, 0u};
    } else {
        if (ta != kInf) stack[sp++] = {c0, ta, cd, cf, 0u};
        e = {c0 + 1, tb, cd, cf, 0u};
    }
    return true;
}

/// A node's cone test under culling: false when every normal of its subtree faces away (skip
/// it); clears `cull` when every normal faces the ray (its subtree needs no more cone tests).
inline bool cone_admits(const Node &nd, const Ray &ray, bool &cull) {
    if (cull && nd.has_cone()) {
        float c = dot(nd.axis(), ray.d), s = nd.cone();
        if (c > s) return false;      // every normal faces away
        if (c < -s) cull = false;     // every normal faces the ray
    }
    return true;
}

/// Whether level of detail stops at interior node `nd` (`lod`: the ray takes LoD at all).
/// A node whose normals span more than a hemisphere (two sheets of a thin part, a closed piece)
/// has no meaningful mean plane: its disk would face anywhere, so LoD descends until the
/// children face one way (the gate lets no such node through). The gate first: most nodes fail
/// it, and then need no footprint.
inline bool lod_stops(const Node &nd, const Ray &ray, const TraceOptions &opt,
                      const LodGate &gate, bool lod) {
    if (!lod || !gate.passes(nd)) return false;
    const float t2 = dot(nd.c - ray.o, ray.d);
    return t2 > 0.f && lod_stop(nd, ray, t2, opt);
}

/// The disks of a leaf (`cnt` surfels from `b`), handed to the policy. Returns true when the policy ends the traversal.
template <class Policy, class Stats>
inline bool visit_leaf(const SurfelTree &tree, uint32_t b, uint32_t cnt, const Ray &ray,
                       bool cull, Policy &policy, Stats &stats) {
    const auto &surfels = tree.surfels();
    // Every disk of a leaf is tested against the far bound at the leaf's start, as the
    // eight-lane test does, so that both give the same hits (the closest-hit bound can
    // grow when a nearer disk with a wider window arrives).
    const float leaf_tfar = policy.tfar();
#if defined(POINTVIZ_LEAF_SIMD)
    if (cnt <= 8) {
        LeafHits lh;
        intersect_leaf8(ray, &surfels[b], cnt, leaf_tfar, cull, lh);
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
        if (!intersect_disk(ray, s.p, s.n, s.r, leaf_tfar, cull, facing, h)) continue;
        if (policy.add({h.t, h.u2, facing, s.r, k})) return true;
    }
    return false;
}

/// The two children (from `c0`) of a node where level of detail stopped, intersected as disks
/// and handed to the policy. Returns true when the policy ends the traversal.
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

/// What a traversal finds once per ray: the inverse direction (box tests), whether level of
/// detail applies, its gate, and the entry parameter of the root's bound (kInf: missed).
struct RaySetup {
    Vec3 inv_d;
    bool lod;
    LodGate gate;
    float t_root;

    template <bool kSlabs, class Policy>
    RaySetup(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
             const LodGates &gates, const Policy &policy, std::integral_constant<bool, kSlabs>)
        : inv_d{1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z},
          // A footprint that does not grow (width0 > 0, spread 0: a shadow ray toward a hard
          // light) still takes LoD: what matters is the beam's width where the node is.
          lod(opt.lod && (ray.spread > 0.f || ray.width0 > 0.f)),
          gate(gates.of(ray)),
          t_root(enter_bound<kSlabs>(tree, 0, 0, ray, inv_d, policy.tfar(), opt.box_depth)) {}
};

}  // namespace detail

/// The binary traversal loop (paper Figure 3b): one node at a time, its two children's bounds
/// tested one after the other.
///
/// `cull` asks for back-face culling: disks facing away from the ray are skipped, and so are
/// subtrees whose normal cone faces away entirely; once a cone faces the ray entirely its
/// subtree is not tested again.
template <bool kSlabs, class Policy, class Stats>
void traverse_impl(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                   const LodGates &gates, bool cull, Policy &policy, Stats &stats) {
    using namespace detail;
    const auto &nodes = tree.nodes();
    const RaySetup rs(tree, ray, opt, gates, policy, std::integral_constant<bool, kSlabs>());
    const Vec3 inv_d = rs.inv_d;
    const bool lod = rs.lod;
    const uint32_t box_depth = opt.box_depth;
    const LodGate gate = rs.gate;

    StackEntry stack[kStackSize];
    int sp = 0;
    if (rs.t_root == kInf) return;
    // The current node; the near child of an interior node is taken next without a push.
    StackEntry e{0u, rs.t_root, 0, uint16_t(cull), 0u};

    for (;;) {
        bool descend = false;
        const Node &nd = nodes[e.node];
        stats.node(e.depth);
        bool sub_cull = e.cull != 0;
        if (!cone_admits(nd, ray, sub_cull)) {
        } else if (nd.is_leaf()) {
            if (visit_leaf(tree, nd.index(), nd.count(), ray, sub_cull, policy, stats)) return;
        } else if (lod_stops(nd, ray, opt, gate, lod)) {
            // Small enough: intersect the children as disks and let the policy blend them.
            if (lod_disks(tree, nd.index(), ray, sub_cull, policy, stats)) return;
        } else {
            descend = binary_step<kSlabs>(tree, nd, ray, inv_d, policy.tfar(), box_depth,
                                          sub_cull, e, stack, sp);
        }
        if (descend) continue;
        // Pop the nearest pending subtree that can still hold a closer hit.
        do {
            if (sp == 0) return;
            e = stack[--sp];
        } while (e.t > policy.tfar());
    }
}

/// Where a wide traversal starts: at the root, with an empty stack (a ray that misses the
/// root's bound ends at once).
struct WideRoot {
    static constexpr bool kFromRoot = true;
    void operator()(detail::StackEntry &, detail::StackEntry *, int &) const {}
};

/// The wide traversal (wide_trace.h, which defines it): the same decisions as traverse_impl,
/// with the bounds of two levels tested at once. Callers that instantiate the queries below
/// include wide_trace.h. `start` may replace the root entry and the empty stack before the
/// loop runs: a ray that leaves a packet (packet_trace.h) continues from where the packet was.
template <bool kSlabs, class Policy, class Stats, class Start = WideRoot>
void traverse_wide_impl(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                        const LodGates &gates, bool cull, Policy &policy, Stats &stats,
                        Start start = {});

/// Whether the wide traversal serves `opt` on `tree`: asked for, and the tree's wide nodes
/// were built for the box depth the options use (a different one, e.g. boxes on every level,
/// takes the binary traversal).
inline bool use_wide(const SurfelTree &tree, const TraceOptions &opt) {
    return opt.wide && !tree.wide().empty() &&
           std::min(opt.box_depth, tree.box_depth()) == tree.wide().box_depth();
}

/// `gates` must be lod_gates(opt) (batches find it once).
template <class Policy, class Stats>
void traverse(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
              const LodGates &gates, bool cull, Policy &policy, Stats &stats) {
    if (use_wide(tree, opt)) {
        if (opt.slabs) traverse_wide_impl<true>(tree, ray, opt, gates, cull, policy, stats);
        else traverse_wide_impl<false>(tree, ray, opt, gates, cull, policy, stats);
    } else if (opt.slabs) {
        traverse_impl<true>(tree, ray, opt, gates, cull, policy, stats);
    } else {
        traverse_impl<false>(tree, ray, opt, gates, cull, policy, stats);
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

/// The hit a closest-hit traversal's gathered disks make (`g`): the blend of closest_hit.
POINTVIZ_HOT_INLINE bool finish_closest(const SurfelTree &tree, const TraceOptions &opt,
                                       const detail::Gather &g,
                           SurfaceHit &out) {
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

/// Closest hit with interpolation over the disks facing the same way as the nearest one,
/// within the depth window (paper section 2.1).
template <class Stats>
bool closest_hit(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                 const LodGates &gates, SurfaceHit &out, Stats &stats) {
    detail::Gather g(ray.tmax, opt.window);
    traverse(tree, ray, opt, gates, opt.cull, g, stats);
    return finish_closest(tree, opt, g, out);
}

/// Any hit in [ray.tmin, ray.tmax]: shadow rays. Two-sided unless `cull` is asked for.
template <class Stats>
bool any_hit(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
             const LodGates &gates, bool cull, Stats &stats) {
    detail::AnyHit a(ray.tmax);
    traverse(tree, ray, opt, gates, cull, a, stats);
    return a.hit;
}

POINTVIZ_ISA_END

}  // namespace pointviz
