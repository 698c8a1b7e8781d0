// pointviz — the wide traversal: the binary traversal's decisions (trace.h) with the bounds of
// two levels tested at once (wide.h). A wide step at interior node P tests the spheres and slabs
// of P's children A, B and grandchildren A1, A2, B1, B2 in one eight-lane pass (AVX2), two
// four-lane passes (SSE, the second skipped when B missed) or six scalar lanes (no SIMD); every
// lane computes exactly what enter_sphere_slab / enter_sphere compute for that node. Then A and
// B are visited as the binary traversal visits them (count, cone test, leaf or level-of-detail
// stop), and the grandchildren under a hit and admitted A or B, with A's and B's leaves, go onto
// the stack nearest first. Levels above the wide nodes (the boxes) take binary steps.
//
// What can differ from the binary traversal is only the order in which disks reach the
// closest-hit policy (near-first by the bounds' entry parameters in both, but over four
// candidates instead of two). The nearest disk does not depend on the order; the disks blended
// around it can, in rare cases, when a nearer disk with a wider depth window arrives after the
// policy already turned a farther disk away (trace.h, Gather). Any-hit results never differ.
#pragma once

#include <cstdint>
#include <cstring>

#include "pointviz/isa.h"
#include "pointviz/simd.h"
#include "pointviz/trace.h"
#include "pointviz/wide.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

namespace detail {

/// What one wide node's lanes tell a ray: bit k of `mask` set when lane k's bound is entered
/// within [ray.tmin, tfar], at t[k] (kInf elsewhere); of `away` when every normal of lane k's
/// subtree faces away from the ray (cone cosine above the cone's sine), of `toward` when every
/// one faces it.
struct WideHits {
    uint32_t mask, away, toward;
    alignas(32) float t[kWideLanes];  ///< lanes 6 and 7 (AVX2: masked off) land here too
};

/// Sphere (cut by its slab with kSlabs) of each lane V: the operations of enter_sphere_slab
/// (kSlabs) or enter_sphere in the same order, so that every lane gives the scalar test's answer
/// bit for bit. A slab half-width of +inf leaves t0 and t1 as they are (no slab). Returns the
/// lanes entered; writes their entry parameter to `t` (kInf elsewhere) and the cosine of their
/// cone axis with the ray to `cosv`.
template <bool kSlabs, class V>
inline auto sphere_slab_lanes(V cx, V cy, V cz, V r, V ax, V ay, V az, V h, const Ray &ray,
                              float tfar, V &t, V &cosv) {
    const V ox(ray.o.x), oy(ray.o.y), oz(ray.o.z);
    const V dx(ray.d.x), dy(ray.d.y), dz(ray.d.z);
    // cone_admits' dot(axis, d), which is also the slab's dot(d, axis) bit for bit
    cosv = ax * dx + ay * dy + az * dz;
    const V ocx = cx - ox, ocy = cy - oy, ocz = cz - oz;
    const V tca = ocx * dx + ocy * dy + ocz * dz;
    const V d2 = (ocx * ocx + ocy * ocy + ocz * ocz) - tca * tca;
    const V r2 = r * r;
    auto ok = d2 <= r2;  // NaN radius (no node): never
    const V thc = vsqrt(r2 - d2);
    if constexpr (kSlabs) {
        V t0 = vmax(tca - thc, V(ray.tmin)), t1 = vmin(tca + thc, V(tfar));
        const V dn = cosv, on = ocx * ax + ocy * ay + ocz * az;
        const V ta = (on - h) / dn, tb = (on + h) / dn;
        const auto slanted = vabs(dn) > V(1e-12f);
        t0 = select(slanted, vmax(t0, vmin(ta, tb)), t0);
        t1 = select(slanted, vmin(t1, vmax(ta, tb)), t1);
        ok = ok & (slanted | (vabs(on) <= h)) & (t0 <= t1);
        t = select(ok, t0, V(kInf));
    } else {
        const V t0 = tca - thc, t1 = tca + thc;
        ok = ok & (t1 >= V(ray.tmin)) & (t0 <= V(tfar));
        t = select(ok, vmax(t0, V(ray.tmin)), V(kInf));
    }
    return ok;
}

inline void store_lanes(float v, float *p) { *p = v; }
template <class V>
inline void store_lanes(V v, float *p) { v.store(p); }

/// The lanes of one wide node test, decoded: the quantised fields with the binary node's own
/// expressions (Node::axis, Node::cone, Node::slab_half_width), in lanes V.
template <bool kSlabs, class V>
inline void wide_lanes(V cx, V cy, V cz, V r, V qx, V qy, V qz, V qcone, V qslab,
                       const Ray &ray, float tfar, uint32_t shift, WideHits &out) {
    const V ka(1.f / kAxisScale);
    const V ax = qx * ka, ay = qy * ka, az = qz * ka;
    const V h = select(qslab >= V(float(kNoSlab)), V(kInf), qslab * V(1.f / 255.f) * r);
    const V s = select(qcone >= V(float(kConeNeverQ)), V(2.f), qcone * V(1.f / kConeScale));
    V t, cosv;
    const auto ok = sphere_slab_lanes<kSlabs>(cx, cy, cz, r, ax, ay, az, h, ray, tfar, t, cosv);
    out.mask |= (movemask(ok) << shift) & kWideMask;
    out.away |= (movemask(cosv > s) << shift) & kWideMask;
    out.toward |= (movemask(cosv < V(0.f) - s) << shift) & kWideMask;
    store_lanes(t, out.t + shift);
}

/// Tests the ray against the six bounds and cones of `w` within [ray.tmin, tfar].
template <bool kSlabs>
inline void enter_wide(const WideNode &w, const Ray &ray, float tfar, WideHits &out) {
    out.mask = out.away = out.toward = 0;
#if defined(POINTVIZ_AVX2)
    auto f32 = [](const float *p) { return F8(_mm256_loadu_ps(p)); };
    auto i16 = [](const int16_t *p) {
        return F8(_mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p)))));
    };
    const F8 qcone(_mm256_cvtepi32_ps(
        _mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i *>(w.cone_q)))));
    const F8 qslab(_mm256_cvtepi32_ps(
        _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i *>(w.slab_q)))));
    wide_lanes<kSlabs>(f32(w.cx), f32(w.cy), f32(w.cz), f32(w.r), i16(w.ax), i16(w.ay), i16(w.az),
                       qcone, qslab, ray, tfar, 0, out);
#elif defined(POINTVIZ_SSE2)
    const __m128i zero = _mm_setzero_si128();
    for (uint32_t g = 0; g < uint32_t(kWideUsed); g += 4) {
        if (g == 4 && !(out.mask & 2u)) break;  // B missed: its children do not count
        auto f32 = [g](const float *p) { return F4(_mm_loadu_ps(p + g)); };
        auto i16 = [g](const int16_t *p) {  // sign-extended: the high half of each pair
            const __m128i x = _mm_loadl_epi64(reinterpret_cast<const __m128i *>(p + g));
            return F4(_mm_cvtepi32_ps(_mm_srai_epi32(_mm_unpacklo_epi16(x, x), 16)));
        };
        const __m128i c = _mm_loadl_epi64(reinterpret_cast<const __m128i *>(w.cone_q + g));
        const F4 qcone(_mm_cvtepi32_ps(_mm_unpacklo_epi16(c, zero)));
        int32_t bytes;
        std::memcpy(&bytes, w.slab_q + g, 4);
        const __m128i b = _mm_unpacklo_epi8(_mm_cvtsi32_si128(bytes), zero);
        const F4 qslab(_mm_cvtepi32_ps(_mm_unpacklo_epi16(b, zero)));
        wide_lanes<kSlabs>(f32(w.cx), f32(w.cy), f32(w.cz), f32(w.r), i16(w.ax), i16(w.ay),
                           i16(w.az), qcone, qslab, ray, tfar, g, out);
    }
#else
    for (uint32_t k = 0; k < uint32_t(kWideUsed); ++k)
        wide_lanes<kSlabs, float>(w.cx[k], w.cy[k], w.cz[k], w.r[k], float(w.ax[k]),
                                  float(w.ay[k]), float(w.az[k]), float(w.cone_q[k]),
                                  float(w.slab_q[k]), ray, tfar, k, out);
#endif
}

}  // namespace detail

template <bool kSlabs, class Policy, class Stats>
void traverse_wide_impl(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                        const LodGates &gates, bool cull, Policy &policy, Stats &stats) {
    using namespace detail;
    const RaySetup rs(tree, ray, opt, gates, policy, std::integral_constant<bool, kSlabs>());
    if (rs.t_root == kInf) return;
    const auto &nodes = tree.nodes();
    const WideTree &wide = tree.wide();
    const bool lod = rs.lod;
    const LodGate &gate = rs.gate;

    // A wide step leaves at most three entries behind per two levels (a binary step one per
    // level): 48 for the deepest tree.
    StackEntry stack[kStackSize];
    int sp = 0;
    StackEntry e{0u, rs.t_root, 0, uint16_t(cull ? kCull : 0)};

    for (;;) {
        bool descend = false;
        bool sub_cull = (e.cull & kCull) != 0;
        const WideNode *w = nullptr;  // set when the node takes a wide step
        if (e.cull & kVisited) {
            // Pushed by a wide step: cone-tested there; its lane said where to go. Its binary
            // node is read only for level of detail.
            if (!(e.cull & kCounted)) stats.node(e.depth);
            if (e.ref >> 27) {
                if (visit_leaf(tree, e.ref & (kMaxTreeSurfels - 1), e.ref >> 27, ray, sub_cull,
                               policy, stats))
                    return;
            } else if (lod && lod_stops(nodes[e.node], ray, opt, gate, lod)) {
                if (lod_disks(tree, nodes[e.node].index(), ray, sub_cull, policy, stats)) return;
            } else {
                w = &wide.node(e.ref);
            }
        } else {
            // The root and the box levels: the binary traversal's visit.
            const Node &nd = nodes[e.node];
            stats.node(e.depth);
            if (!cone_admits(nd, ray, sub_cull)) {
            } else if (nd.is_leaf()) {
                if (visit_leaf(tree, nd.index(), nd.count(), ray, sub_cull, policy, stats)) return;
            } else if (lod_stops(nd, ray, opt, gate, lod)) {
                if (lod_disks(tree, nd.index(), ray, sub_cull, policy, stats)) return;
            } else if (wide.has(e.node)) {
                w = &wide.of(e.node);
            } else {
                descend = binary_step<kSlabs>(tree, nd, ray, rs.inv_d, policy.tfar(),
                                              opt.box_depth, sub_cull, e, stack, sp);
            }
        }
        if (w) {
            WideHits wh;
            enter_wide<kSlabs>(*w, ray, policy.tfar(), wh);
            StackEntry items[4];
            int ni = 0;
            // Binary indices of A and B: needed for level of detail only.
            const uint32_t a = lod ? nodes[e.node].index() : 0u;
            const uint16_t d1 = uint16_t(e.depth + 1), d2 = uint16_t(e.depth + 2);
            for (uint32_t j = 0; j < 2; ++j) {
                if (!((wh.mask >> j) & 1u)) continue;
                // A and B are visited here, as the binary traversal visits them.
                stats.node(d1);
                bool xc = sub_cull;
                if (xc && ((wh.away >> j) & 1u)) continue;
                if (xc && ((wh.toward >> j) & 1u)) xc = false;
                if (w->ref[j] >> 27) {
                    items[ni++] = {a + j, wh.t[j], d1, uint16_t((xc ? kCull : 0) | kVisited | kCounted),
                                   w->ref[j]};
                    continue;
                }
                uint32_t g = 0;
                if (lod) {
                    const Node &xn = nodes[a + j];
                    if (lod_stops(xn, ray, opt, gate, lod)) {
                        if (lod_disks(tree, xn.index(), ray, xc, policy, stats)) return;
                        continue;
                    }
                    g = xn.index();
                }
                // The grandchildren: cone-tested now, counted and visited when popped (those
                // the cone test skips are counted now: the binary traversal counts them too).
                for (uint32_t k = 0; k < 2; ++k) {
                    const uint32_t lane = 2 + 2 * j + k;
                    if (!((wh.mask >> lane) & 1u)) continue;
                    bool yc = xc;
                    if (yc && ((wh.away >> lane) & 1u)) {
                        stats.node(d2);
                        continue;
                    }
                    if (yc && ((wh.toward >> lane) & 1u)) yc = false;
                    items[ni++] = {g + k, wh.t[lane], d2, uint16_t((yc ? kCull : 0) | kVisited),
                                   w->ref[lane]};
                }
            }
            if (ni > 0) {
                // Nearest first: sort by entry parameter, push all but the nearest, take it.
                for (int i = 1; i < ni; ++i) {
                    const StackEntry x = items[i];
                    int k = i;
                    for (; k > 0 && items[k - 1].t > x.t; --k) items[k] = items[k - 1];
                    items[k] = x;
                }
                for (int i = ni - 1; i > 0; --i) stack[sp++] = items[i];
                e = items[0];
                descend = true;
            }
        }
        if (descend) continue;
        do {
            if (sp == 0) return;
            e = stack[--sp];
        } while (e.t > policy.tfar());
    }
}

POINTVIZ_ISA_END
}  // namespace pointviz
