// pointviz — the wide traversal: the binary traversal's decisions (trace.h) with the bounds of
// two levels tested at once (wide.h). A wide step at interior node P tests the boxes (box
// levels) or the spheres and slabs (below) of P's children A, B and grandchildren A1, A2, B1, B2,
// and their normal cones, in one eight-lane pass (AVX2), two four-lane passes (SSE, the second
// skipped when B missed) or six scalar lanes (no SIMD); every lane computes exactly what
// enter_box / enter_sphere_slab / enter_sphere and cone_admits compute for that node. Then A and
// B are visited as the binary traversal visits them (count, cone, leaf or level-of-detail stop),
// and the grandchildren under a hit and admitted A or B, with A's and B's leaves, go onto the
// stack nearest first, their wide nodes or surfels prefetched. Only the root may take a binary
// step (when the wide levels start at depth 1), and binary nodes are read only for level of
// detail.
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
/// one faces it (both tested only for a ray still culling there: 0 otherwise).
struct WideHits {
    uint32_t mask, away, toward;
    alignas(32) float t[kWideLanes];  ///< lanes 6 and 7 (AVX2: masked off) land here too
};

// Loading a wide node's fields into lanes: eight at a time (AVX2), four (SSE2), or one (no
// SIMD). A load reads kWideStep values from its pointer: past a field's sixth lane it reads the
// next field (lanes 6 and 7, masked off by kWideMask).
#if defined(POINTVIZ_AVX2)
using WideV = F8;
constexpr uint32_t kWideStep = 8;
inline F8 lanes_f32(const float *p) { return F8(_mm256_loadu_ps(p)); }
inline F8 lanes_i16(const int16_t *p) {
    return F8(_mm256_cvtepi32_ps(_mm256_cvtepi16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p)))));
}
inline F8 lanes_u16(const uint16_t *p) {
    return F8(_mm256_cvtepi32_ps(_mm256_cvtepu16_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i *>(p)))));
}
inline F8 lanes_u8(const uint8_t *p) {
    return F8(_mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i *>(p)))));
}
#elif defined(POINTVIZ_SSE2)
using WideV = F4;
constexpr uint32_t kWideStep = 4;
inline F4 lanes_f32(const float *p) { return F4(_mm_loadu_ps(p)); }
inline F4 lanes_i16(const int16_t *p) {  // sign-extended: the high half of each pair
    const __m128i x = _mm_loadl_epi64(reinterpret_cast<const __m128i *>(p));
    return F4(_mm_cvtepi32_ps(_mm_srai_epi32(_mm_unpacklo_epi16(x, x), 16)));
}
inline F4 lanes_u16(const uint16_t *p) {
    const __m128i x = _mm_loadl_epi64(reinterpret_cast<const __m128i *>(p));
    return F4(_mm_cvtepi32_ps(_mm_unpacklo_epi16(x, _mm_setzero_si128())));
}
inline F4 lanes_u8(const uint8_t *p) {
    int32_t bytes;
    std::memcpy(&bytes, p, 4);
    const __m128i zero = _mm_setzero_si128();
    const __m128i x = _mm_unpacklo_epi8(_mm_cvtsi32_si128(bytes), zero);
    return F4(_mm_cvtepi32_ps(_mm_unpacklo_epi16(x, zero)));
}
#else
using WideV = float;
constexpr uint32_t kWideStep = 1;
inline float lanes_f32(const float *p) { return *p; }
inline float lanes_i16(const int16_t *p) { return float(*p); }
inline float lanes_u16(const uint16_t *p) { return float(*p); }
inline float lanes_u8(const uint8_t *p) { return float(*p); }
#endif

/// std::min and std::max lane by lane, NaN included: (b < a) ? b : a and (a < b) ? b : a.
template <class V>
inline V smin(V a, V b) { return vmin(b, a); }
template <class V>
inline V smax(V a, V b) { return vmax(b, a); }

/// Box of each lane V: the operations of enter_box in the same order, so that every lane gives
/// the scalar test's answer bit for bit. Returns the lanes entered within [ray.tmin, tfar];
/// writes their entry parameter to `t` (kInf elsewhere). The ray is a Ray (one ray against the
/// lanes' boxes) or a PacketLanes (packet_trace.h: one box, broadcast, against a ray per lane).
template <class V, class R = Ray, class I = Vec3, class T = float>
inline auto box_lanes(V lx, V ly, V lz, V hx, V hy, V hz, const R &ray, I inv_d, T tfar, V &t) {
    const V ox(ray.o.x), oy(ray.o.y), oz(ray.o.z);
    const V ix(inv_d.x), iy(inv_d.y), iz(inv_d.z);
    const V t0x = (lx - ox) * ix, t1x = (hx - ox) * ix;
    const V t0y = (ly - oy) * iy, t1y = (hy - oy) * iy;
    const V t0z = (lz - oz) * iz, t1z = (hz - oz) * iz;
    const V tn = smax(smax(smin(t0x, t1x), smin(t0y, t1y)), smax(smin(t0z, t1z), V(ray.tmin)));
    const V tf = smin(smin(smax(t0x, t1x), smax(t0y, t1y)), smin(smax(t0z, t1z), V(tfar)));
    const auto ok = tn <= tf;
    t = select(ok, tn, V(kInf));
    return ok;
}

/// Sphere (cut by its slab with kSlabs) of each lane V: the operations of enter_sphere_slab
/// (kSlabs) or enter_sphere in the same order, so that every lane gives the scalar test's answer
/// bit for bit. A slab half-width of +inf leaves t0 and t1 as they are (no slab). Returns the
/// lanes entered; writes their entry parameter to `t` (kInf elsewhere) and the cosine of their
/// cone axis with the ray to `cosv`. The ray is a Ray or a PacketLanes, as for box_lanes.
template <bool kSlabs, class V, class R = Ray, class T = float>
inline auto sphere_slab_lanes(V cx, V cy, V cz, V r, V ax, V ay, V az, V h, const R &ray, T tfar,
                              V &t, V &cosv) {
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
        V t0 = smax(tca - thc, V(ray.tmin)), t1 = smin(tca + thc, V(tfar));
        const V dn = cosv, on = ocx * ax + ocy * ay + ocz * az;
        const V ta = (on - h) / dn, tb = (on + h) / dn;
        const auto slanted = vabs(dn) > V(1e-12f);
        t0 = select(slanted, smax(t0, smin(ta, tb)), t0);
        t1 = select(slanted, smin(t1, smax(ta, tb)), t1);
        ok = ok & (slanted | (vabs(on) <= h)) & (t0 <= t1);
        t = select(ok, t0, V(kInf));
    } else {
        const V t0 = tca - thc, t1 = tca + thc;
        ok = ok & (t1 >= V(ray.tmin)) & (t0 <= V(tfar));
        t = select(ok, smax(t0, V(ray.tmin)), V(kInf));
    }
    return ok;
}

inline void store_lanes(float v, float *p) { *p = v; }
template <class V>
inline void store_lanes(V v, float *p) { v.store(p); }

/// Adds lanes [shift, shift + width of V) to `out`: entered and their entry parameter.
template <class V, class M>
inline void report_hits(M ok, V t, uint32_t shift, WideHits &out) {
    out.mask |= (movemask(ok) << shift) & kWideMask;
    store_lanes(t, out.t + shift);
}

/// Adds lanes [shift, shift + width of V) to `out`: cone facing away, cone facing the ray
/// (cone_admits' tests).
template <class V>
inline void report_cones(V cosv, V s, uint32_t shift, WideHits &out) {
    out.away |= (movemask(cosv > s) << shift) & kWideMask;
    out.toward |= (movemask(cosv < V(0.f) - s) << shift) & kWideMask;
}

/// The cone's sine per lane, decoded as Node::cone does.
template <class V>
inline V cone_lanes(V qcone) {
    return select(qcone >= V(float(kConeNeverQ)), V(2.f), qcone * V(1.f / kConeScale));
}

/// The lanes of one wide node test, decoded: the quantised fields with the binary node's own
/// expressions (Node::axis, Node::cone, Node::slab_half_width), in lanes V. The cones only
/// under culling (`cull`): without it the traversal reads no cone bit.
template <bool kSlabs, class V>
inline void wide_lanes(V cx, V cy, V cz, V r, V qx, V qy, V qz, const uint16_t *cone_q, V qslab,
                       const Ray &ray, float tfar, bool cull, uint32_t shift, WideHits &out) {
    const V ka(1.f / kAxisScale);
    const V ax = qx * ka, ay = qy * ka, az = qz * ka;
    const V h = select(qslab >= V(float(kNoSlab)), V(kInf), qslab * V(1.f / 255.f) * r);
    V t, cosv;
    const auto ok = sphere_slab_lanes<kSlabs>(cx, cy, cz, r, ax, ay, az, h, ray, tfar, t, cosv);
    report_hits(ok, t, shift, out);
    if (cull) report_cones(cosv, cone_lanes(lanes_u16(cone_q)), shift, out);
}

/// The lanes of one wide box node test, decoded; the cones only under culling.
template <class V>
inline void wide_box_lanes(V lx, V ly, V lz, V hx, V hy, V hz, const WideBoxNode &w, uint32_t g,
                           const Ray &ray, Vec3 inv_d, float tfar, bool cull, WideHits &out) {
    V t;
    const auto ok = box_lanes(lx, ly, lz, hx, hy, hz, ray, inv_d, tfar, t);
    report_hits(ok, t, g, out);
    if (!cull) return;
    const V ka(1.f / kAxisScale);
    const V cosv = lanes_i16(w.ax + g) * ka * V(ray.d.x) + lanes_i16(w.ay + g) * ka * V(ray.d.y) +
                   lanes_i16(w.az + g) * ka * V(ray.d.z);
    report_cones(cosv, cone_lanes(lanes_u16(w.cone_q + g)), g, out);
}


/// Tests the ray against the six bounds of `w` within [ray.tmin, tfar], and their cones
/// under culling (`cull`; away and toward stay 0 without).
template <bool kSlabs>
inline void enter_wide(const WideNode &w, const Ray &ray, float tfar, bool cull, WideHits &out) {
    out.mask = out.away = out.toward = 0;
    for (uint32_t g = 0; g < uint32_t(kWideUsed); g += kWideStep) {
        if (g == 4 && !(out.mask & 2u)) break;  // B missed: its children do not count
        wide_lanes<kSlabs, WideV>(lanes_f32(w.cx + g), lanes_f32(w.cy + g), lanes_f32(w.cz + g),
                                  lanes_f32(w.r + g), lanes_i16(w.ax + g), lanes_i16(w.ay + g),
                                  lanes_i16(w.az + g), w.cone_q + g, lanes_u8(w.slab_q + g),
                                  ray, tfar, cull, g, out);
    }
}

/// Tests the ray against the six boxes of `w` within [ray.tmin, tfar], and their cones under
/// culling. Lanes of a leaf's children hold no box: the caller ignores them.
inline void enter_wide_box(const WideBoxNode &w, const Ray &ray, Vec3 inv_d, float tfar,
                           bool cull, WideHits &out) {
    out.mask = out.away = out.toward = 0;
    for (uint32_t g = 0; g < uint32_t(kWideUsed); g += kWideStep) {
        if (g == 4 && !(out.mask & 2u)) break;  // B missed: its children do not count
        wide_box_lanes<WideV>(lanes_f32(w.lx + g), lanes_f32(w.ly + g), lanes_f32(w.lz + g),
                              lanes_f32(w.hx + g), lanes_f32(w.hy + g), lanes_f32(w.hz + g),
                              w, g, ray, inv_d, tfar, cull, out);
    }
}

/// Asks for the cache lines a pushed entry at `depth` will read: those of its wide node, or
/// the first four of its leaf's surfels (eight surfels). A hint only: no effect on results.
inline void prefetch_entry(const SurfelTree &tree, uint32_t ref, uint32_t depth) {
    const WideTree &wide = tree.wide();
    const char *p;
    size_t bytes = 256;
    if (ref >> 27) {
        p = reinterpret_cast<const char *>(tree.surfels().data() + (ref & (kMaxTreeSurfels - 1)));
    } else if (wide.box_level(depth)) {
        p = reinterpret_cast<const char *>(&wide.box_node(ref));
    } else {
        p = reinterpret_cast<const char *>(&wide.node(ref));
        bytes = sizeof(WideNode);
    }
    for (size_t b = 0; b < bytes; b += 64) __builtin_prefetch(p + b);
}

}  // namespace detail

template <bool kSlabs, class Policy, class Stats, class Start>
void traverse_wide_impl(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                        const LodGates &gates, bool cull, Policy &policy, Stats &stats,
                        Start start) {
    using namespace detail;
    const RaySetup rs(tree, ray, opt, gates, policy, std::integral_constant<bool, kSlabs>());
    if (Start::kFromRoot && rs.t_root == kInf) return;
    const auto &nodes = tree.nodes();
    const WideTree &wide = tree.wide();
    const bool lod = rs.lod;
    const LodGate &gate = rs.gate;

    // A wide step leaves at most three entries behind per two levels (a binary step one per
    // level): 48 for the deepest tree.
    StackEntry stack[kStackSize];
    int sp = 0;
    StackEntry e{0u, rs.t_root, 0, uint16_t(cull ? kCull : 0), 0u};
    start(e, stack, sp);

    for (;;) {
        bool descend = false;
        bool sub_cull = (e.cull & kCull) != 0;
        uint32_t wi = kNoWide;  // the wide node of a node that takes a wide step
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
                wi = e.ref;
            }
        } else {
            // The root (and its children when the wide levels start at depth 1): the binary
            // traversal's visit.
            const Node &nd = nodes[e.node];
            stats.node(e.depth);
            if (!cone_admits(nd, ray, sub_cull)) {
            } else if (nd.is_leaf()) {
                if (visit_leaf(tree, nd.index(), nd.count(), ray, sub_cull, policy, stats)) return;
            } else if (lod_stops(nd, ray, opt, gate, lod)) {
                if (lod_disks(tree, nd.index(), ray, sub_cull, policy, stats)) return;
            } else if (wide.has(e.node)) {
                wi = wide.index_of(e.node);
            } else {
                descend = binary_step<kSlabs>(tree, nd, ray, rs.inv_d, policy.tfar(),
                                              opt.box_depth, sub_cull, e, stack, sp);
            }
        }
        if (wi != kNoWide) {
            WideHits wh;
            const uint32_t *refs;
            if (wide.box_level(e.depth)) {
                const WideBoxNode &w = wide.box_node(wi);
                enter_wide_box(w, ray, rs.inv_d, policy.tfar(), sub_cull, wh);
                refs = w.ref;
            } else {
                const WideNode &w = wide.node(wi);
                enter_wide<kSlabs>(w, ray, policy.tfar(), sub_cull, wh);
                refs = w.ref;
            }
            // Entries to push, as lanes (their t and ref are the lane's) with node and flags.
            uint32_t lane_of[4], node_of[4];
            uint16_t flags_of[4];
            int ni = 0;
            // Binary indices of A and B: needed for level of detail only.
            const uint32_t a = lod ? nodes[e.node].index() : 0u;
            const uint16_t d1 = uint16_t(e.depth + 1);
            for (uint32_t j = 0; j < 2; ++j) {
                if (!((wh.mask >> j) & 1u)) continue;
                // A and B are visited here, as the binary traversal visits them.
                stats.node(d1);
                bool xc = sub_cull;
                if (xc && ((wh.away >> j) & 1u)) continue;
                if (xc && ((wh.toward >> j) & 1u)) xc = false;
                if (refs[j] >> 27) {
                    lane_of[ni] = j;
                    node_of[ni] = a + j;
                    flags_of[ni++] = uint16_t((xc ? kCull : 0) | kVisited | kCounted);
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
                        stats.node(uint16_t(e.depth + 2));
                        continue;
                    }
                    if (yc && ((wh.toward >> lane) & 1u)) yc = false;
                    lane_of[ni] = lane;
                    node_of[ni] = g + k;
                    flags_of[ni++] = uint16_t((yc ? kCull : 0) | kVisited);
                }
            }
            if (ni > 0) {
                // Nearest first: sort by entry parameter (a permutation of at most four), push
                // all but the nearest, take it. Start loading what each entry leads to (its
                // wide node, or its leaf's first surfels) now: the loads overlap instead of
                // waiting one after another.
                int order[4];
                for (int i = 0; i < ni; ++i) {
                    const float t = wh.t[lane_of[i]];
                    int k = i;
                    for (; k > 0 && wh.t[lane_of[order[k - 1]]] > t; --k) order[k] = order[k - 1];
                    order[k] = i;
                    prefetch_entry(tree, refs[lane_of[i]], e.depth + 1 + (lane_of[i] >= 2));
                }
                const uint16_t depth = e.depth;
                for (int i = ni - 1; i >= 0; --i) {
                    const int m = order[i];
                    const uint32_t lane = lane_of[m];
                    const StackEntry x{node_of[m], wh.t[lane], uint16_t(depth + 1 + (lane >= 2)),
                                       flags_of[m], refs[lane]};
                    if (i > 0) stack[sp++] = x;
                    else e = x;
                }
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
