// pointviz — traversal of the 4-wide tree (wide_node.h): the four lanes of a node are entered
// with one SIMD test, then taken near first. Level of detail, cone culling, the box/sphere
// switch and the slabs decide exactly as in the binary traversal (binary_trace.h), whose
// leaf and level-of-detail disk tests it shares, so both traversals find the same disks.
#pragma once

#include "pointviz/isa.h"

#include <cstdint>

#include "pointviz/binary_trace.h"
#include "pointviz/simd.h"
#include "pointviz/wide_node.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace detail {

/// What a pending entry of the wide traversal stands for.
enum class WideKind : uint8_t {
    Node = 0,  ///< `ref` is a wide node
    Leaf = 1,  ///< `ref` is a leaf's first surfel, `count` its surfels
    Lod = 2,   ///< `ref` is the first of two binary nodes to test as level-of-detail disks
};

struct WideEntry {
    uint32_t ref;
    float t;         ///< entry parameter of its bound
    uint8_t depth;   ///< binary depth of the node the entry stands for
    WideKind kind;
    uint8_t cull;    ///< whether the subtree still needs cone tests
    uint8_t count;
};

/// A wide node pushes at most five entries for two binary levels.
constexpr int kWideStackSize = 3 * kStackSize;
/// Rays closer than this to parallel with a slab (|cos|) are tested against its two planes by
/// the origin's side only (as in enter_sphere_slab).
constexpr float kSlabParallel = 1e-12f;

/// Entry parameters of the lanes of wide node `w` (kInf where the ray misses within
/// [ray.tmin, tfar]); returns the mask of lanes entered. Lanes above `box_lim` use the boxes
/// `wb` (non-null then), the rest their sphere, cut by the slab with kSlabs. Every lane gives
/// bit for bit the value of enter_bound on its binary node.
template <bool kSlabs>
inline uint32_t enter_lanes(const WideNode &w, const WideBoxes *wb, uint32_t box_lim,
                            const Ray &ray, Vec3 inv_d, float tfar, float *t_out) {
    const F4 ox(ray.o.x), oy(ray.o.y), oz(ray.o.z);
    const F4 dx(ray.d.x), dy(ray.d.y), dz(ray.d.z);
    const F4 tmin(ray.tmin), tmax(tfar);
    const F4 ocx = F4::load(w.cx) - ox, ocy = F4::load(w.cy) - oy, ocz = F4::load(w.cz) - oz;
    const F4 tca = ocx * dx + ocy * dy + ocz * dz;
    const F4 d2 = (ocx * ocx + ocy * ocy + ocz * ocz) - tca * tca;
    const F4 rr = F4::load(w.r);
    const F4 r2 = rr * rr;
    const F4 thc = vsqrt(r2 - d2);
    F4 t0 = vmax(tca - thc, tmin), t1 = vmin(tca + thc, tmax);
    // (d2 NaN passes this rejection, as in the scalar test; t0 <= t1 then fails.)
    uint32_t pass = ~movemask(d2 > r2);
    if constexpr (kSlabs) {
        const F4 ax = F4::load(w.ax), ay = F4::load(w.ay), az = F4::load(w.az);
        const F4 h = F4::load(w.slab);
        const F4 dn = dx * ax + dy * ay + dz * az;
        const F4 on = ocx * ax + ocy * ay + ocz * az;
        const F4 ta = (on - h) / dn, tb = (on + h) / dn;
        const F4 crossing = vabs(dn) > F4(kSlabParallel);
        t0 = select(crossing, vmax(t0, vmin(ta, tb)), t0);
        t1 = select(crossing, vmin(t1, vmax(ta, tb)), t1);
        // parallel to the slab: in it or not by the origin's side
        pass &= ~(movemask(vabs(on) > h) & ~movemask(crossing));
    }
    uint32_t mask = pass & movemask(t0 <= t1) & w.valid;
    F4 t = t0;
    if (wb) {
        uint32_t box = 0;
        for (int k = 0; k < kWide; ++k) box |= uint32_t(w.depth[k] < box_lim) << k;
        box &= w.valid;
        if (box) {
            const F4 ix(inv_d.x), iy(inv_d.y), iz(inv_d.z);
            const F4 t0x = (F4::load(wb->lox) - ox) * ix, t1x = (F4::load(wb->hix) - ox) * ix;
            const F4 t0y = (F4::load(wb->loy) - oy) * iy, t1y = (F4::load(wb->hiy) - oy) * iy;
            const F4 t0z = (F4::load(wb->loz) - oz) * iz, t1z = (F4::load(wb->hiz) - oz) * iz;
            const F4 tn = vmax(vmax(vmin(t0x, t1x), vmin(t0y, t1y)), vmax(vmin(t0z, t1z), tmin));
            const F4 tf = vmin(vmin(vmax(t0x, t1x), vmax(t0y, t1y)), vmin(vmax(t0z, t1z), tmax));
            const uint32_t bmask = movemask(tn <= tf);
            mask = (mask & ~box) | (bmask & box);
            alignas(16) float tb[kWide], ts[kWide];
            tn.store(tb);
            t.store(ts);
            for (int k = 0; k < kWide; ++k) t_out[k] = (box >> k) & 1u ? tb[k] : ts[k];
            return mask;
        }
    }
    t.store(t_out);
    return mask;
}

}  // namespace detail

/// The wide traversal: the same queries as traverse_binary, four lanes at a time.
template <bool kSlabs, class Policy, class Stats>
void traverse_wide(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt, bool cull,
                   Policy &policy, Stats &stats) {
    using namespace detail;
    const auto &nodes = tree.nodes();
    const auto &wide = tree.wide();
    if (wide.empty()) {  // the root is a leaf
        traverse_binary<kSlabs>(tree, ray, opt, cull, policy, stats);
        return;
    }
    const Vec3 inv_d{1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z};
    const bool lod = opt.lod && ray.spread > 0.f;
    const uint32_t box_lim = std::min(opt.box_depth, tree.box_depth());
    const uint32_t n_wide_boxes = uint32_t(tree.wide_boxes().size());

    // The root, as the binary traversal visits it.
    const Node &root = nodes[0];
    const float t_root = enter_bound<kSlabs>(tree, 0, 0, ray, inv_d, policy.tfar(), opt.box_depth);
    if (t_root == kInf) return;
    bool root_cull = cull;
    if (root_cull && root.has_cone() && !cone_admits(root.axis(), root.cone(), ray, root_cull)) return;
    if (lod && lod_here(root.c, root.radius, root.has_cone(), root.cone(), ray, opt)) {
        stats.node(0);
        lod_disks(tree, root.index(), ray, root_cull, policy, stats);
        return;
    }

    WideEntry stack[kWideStackSize];
    int sp = 0;
    WideEntry e{0u, t_root, 0, WideKind::Node, uint8_t(root_cull), 0};
    for (;;) {
        stats.node(e.depth);  // every entry taken: a wide node, a leaf or a LoD node's disks
        if (e.kind == WideKind::Leaf) {
            if (leaf_disks(tree, e.ref, e.count, ray, e.cull != 0, policy, stats)) return;
        } else if (e.kind == WideKind::Lod) {
            if (lod_disks(tree, e.ref, ray, e.cull != 0, policy, stats)) return;
        } else {
            const WideNode &w = wide[e.ref];
            const bool node_cull = e.cull != 0;
            WideEntry next[kWide + 2];
            int nn = 0;
            // The mid level matters only to level of detail: a mid node small enough is drawn
            // as its children's disks, and its cone can hide them. (Without LoD its cone test
            // would only prune what the lanes' own cone tests prune, and its bound what the
            // lanes' bounds prune.) A LoD node's disks reach outside its bound, so, as in the
            // binary traversal, they are drawn only where the ray enters that bound.
            uint32_t mid_skip = 0, mid_nocull = 0;
            if (lod) {
                for (uint32_t m = 0; m < 2; ++m) {
                    const MidNode &a = w.mids[m];
                    if (a.child == kNoChild || a.cone == kInf) continue;
                    bool mc = node_cull;
                    if (mc && !cone_admits(a.axis, a.cone, ray, mc)) {
                        mid_skip |= 1u << m;
                        continue;
                    }
                    if (!mc) mid_nocull |= 1u << m;
                    if (!lod_here(a.c, a.r, true, a.cone, ray, opt)) continue;
                    mid_skip |= 1u << m;  // its lanes are drawn as its disks instead
                    const uint8_t md = uint8_t(e.depth + 1);
                    const float ta = enter_bound<kSlabs>(tree, a.index, md, ray, inv_d,
                                                         policy.tfar(), opt.box_depth);
                    if (ta != kInf) next[nn++] = {a.child, ta, md, WideKind::Lod, uint8_t(mc), 0};
                }
            }
            alignas(16) float tl[kWide];
            const WideBoxes *wb = e.ref < n_wide_boxes ? &tree.wide_boxes()[e.ref] : nullptr;
            uint32_t mask = enter_lanes<kSlabs>(w, wb, box_lim, ray, inv_d, policy.tfar(), tl);
            for (; mask != 0; mask &= mask - 1) {
                const int k = __builtin_ctz(mask);
                const uint32_t p = w.parent[k];
                bool lane_cull = node_cull;
                if (p != kLaneIsMid) {
                    if ((mid_skip >> p) & 1u) continue;
                    lane_cull = lane_cull && !((mid_nocull >> p) & 1u);
                }
                const float s = w.cone[k];
                if (lane_cull && s != kInf &&
                    !cone_admits({w.ax[k], w.ay[k], w.az[k]}, s, ray, lane_cull))
                    continue;
                WideEntry x{w.child[k], tl[k], w.depth[k], WideKind::Node, uint8_t(lane_cull), 0};
                if (w.lane_count[k] != kInteriorLane) {
                    x.kind = WideKind::Leaf;
                    x.count = w.lane_count[k];
                } else if (lod && lod_here({w.cx[k], w.cy[k], w.cz[k]}, w.r[k], s != kInf, s, ray, opt)) {
                    x.kind = WideKind::Lod;
                    x.ref = wide[w.child[k]].mids[0].index;
                }
                next[nn++] = x;
            }
            if (nn > 0) {
                // Nearest first: sort by entry t descending, push all but the last.
                for (int i = 1; i < nn; ++i)
                    for (int j = i; j > 0 && next[j - 1].t < next[j].t; --j) std::swap(next[j - 1], next[j]);
                for (int i = 0; i < nn - 1; ++i) stack[sp++] = next[i];
                e = next[nn - 1];
                continue;
            }
        }
        do {
            if (sp == 0) return;
            e = stack[--sp];
        } while (e.t > policy.tfar());
    }
}

POINTVIZ_ISA_END

}  // namespace pointviz
