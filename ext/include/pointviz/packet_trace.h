// pointviz — packets of coherent rays traversing the wide tree together, for closest and any hits.
//
// Up to kPacket rays (camera rays of neighbouring pixels: one origin, directions within
// kPacketMinCos of the first) walk the wide tree (wide.h) as one, with the rays in the SIMD
// lanes: a node is visited once for the packet, each of its six bounds is decoded once and
// broadcast, and tested against all the packet's rays in one pass (eight rays per AVX2 register,
// four per SSE register, one at a time without SIMD) with the single-ray tests' arithmetic
// (wide_trace.h: box_lanes, sphere_slab_lanes), so each ray gets the single-ray answer bit for
// bit. The children are then taken, sorted and pushed once, as masks of the rays that take them,
// with one entry parameter per ray. Each ray keeps its own closest-hit policy (trace.h, Gather),
// so far entries are culled per ray on pop; leaves run the leaf kernel once per active ray.
//
// Bit-identical to the single-ray traversal: a ray's gathered disks can depend on the order in
// which they reach its policy (wide_trace.h), so a ray stays in the packet only while the
// packet's order of children, restricted to the children it hits, is its own near-first order
// (ties by the single traversal's order of creation). A ray whose order differs at some node
// leaves the packet there and finishes alone in the single-ray traversal (wide_trace.h,
// traverse_wide_impl, started from the packet's state: PacketResume),
// from its own stack: the packet's pending entries it takes, and that node's children in its
// own order. Either way a ray sees exactly the single-ray sequence of nodes, leaves and
// far-bound tests.
//
// Any hits take the same packet traversal (any_hits_packet): the answer of a ray does not depend
// on the order of the leaves (its far bound never moves), so no ray leaves the packet; a ray
// that finds a disk drops out of the packet's masks (early exit per ray), and the packet ends
// when every ray has its answer.
//
// Not covered (the caller takes the single-ray path): level of detail (rays with a footprint
// under TraceOptions::lod), statistics, the binary traversal (TraceOptions::wide false or a box
// depth the wide nodes were not built for), and groups that are not coherent (different
// origins, or tmin for closest hits; directions spread beyond kPacketMinCos).
#pragma once

#include <cstdint>
#include <cstring>
#include <type_traits>

#include "pointviz/isa.h"
#include "pointviz/trace.h"
#include "pointviz/wide_trace.h"

namespace pointviz {

/// Rays per packet (one bit each in the masks below).
constexpr int kPacket = 8;
/// The middle rays of a packet (packet_key_ray): rays 3 and 4 of eight pixels in a row; rays
/// 1, 2, 5 and 6 of a 2x4 block (the top row's four pixels, then the bottom row's).
constexpr uint32_t kRowCentre = 0x18u, kBlockCentre = 0x66u;
/// Least cosine between a packet's first direction and any other: about 2.6 degrees, some
/// 40 pixels of a 60-degree, 640-pixel camera. Wider groups diverge too often to gain.
constexpr float kPacketMinCos = 0.999f;

POINTVIZ_ISA_BEGIN

namespace detail {

/// One pending entry of a packet: what a StackEntry holds, for a set of rays.
struct PacketEntry {
    uint32_t node, ref;   ///< as StackEntry
    uint16_t depth, flags;
    uint8_t active;       ///< rays that take the entry
    uint8_t cull;         ///< those of them whose subtree still needs cone tests
    alignas(32) float t[kPacket];  ///< entry parameter per active ray
};

/// The packet's rays field by field, one lane per ray (lanes past the packet's rays repeat its
/// first ray; their answers are masked off).
struct PacketRays {
    alignas(32) float ox[kPacket], oy[kPacket], oz[kPacket];
    alignas(32) float dx[kPacket], dy[kPacket], dz[kPacket];
    alignas(32) float ix[kPacket], iy[kPacket], iz[kPacket];  ///< inverse direction
    alignas(32) float tmin[kPacket], tfar[kPacket];  ///< tfar: the ray's policy's far bound
};

/// What one wide node's six lanes tell the packet: per lane, the rays (bit r: ray r) that
/// enter its bound, at t[lane][r]; those for which its cone faces away, and those for which it
/// faces them (only for rays still culling; 0 otherwise).
struct PacketHits {
    uint32_t hit[kWideUsed], away[kWideUsed], toward[kWideUsed];
    alignas(32) float t[kWideUsed][kPacket];
};

/// The entries one step creates, in the single traversal's order of creation (`slot`).
struct PacketChildren {
    PacketEntry c[kWideUsed];
    uint32_t used = 0;  ///< slots taken by any ray

    /// Ray r takes slot `slot` at entry parameter t (the packet's binary steps).
    void add(uint32_t slot, int r, float t, bool cull) {
        PacketEntry &x = c[slot];
        const uint8_t bit = uint8_t(1u << r);
        if (!((used >> slot) & 1u)) {
            used |= 1u << slot;
            x.active = x.cull = 0;
            for (float &v : x.t) v = kInf;
        }
        x.active |= bit;
        if (cull) x.cull |= bit;
        x.t[r] = t;
    }
};

/// Whether slot a comes before slot b for ray r in the single traversal (near first, ties in
/// order of creation).
inline bool packet_before(const PacketChildren &ch, int r, uint32_t a, uint32_t b) {
    const float ta = ch.c[a].t[r], tb = ch.c[b].t[r];
    return ta < tb || (!(tb < ta) && a < b);
}

/// The ray whose entry parameter stands for a slot's in the packet order: one of the slot's
/// rays in `centre` (the middle of the packet's pixels) if any, else the slot's ray nearest the
/// middle of the packet in ray order.
inline int packet_key_ray(uint32_t active, uint32_t centre) {
    const uint32_t mid = active & centre;
    if (mid) return __builtin_ctz(mid);
    const uint32_t upper = active & ~((1u << (kPacket / 2 - 1)) - 1u);
    return upper ? __builtin_ctz(upper) : 31 - __builtin_clz(active);
}

/// Sorts the used slots near first by the entry parameter of each slot's key ray (a guess at
/// the shared order) and adds to `leave` the rays of `act` whose own order differs. Writes the
/// order to `order`; returns how many slots.
inline int packet_order(const PacketChildren &ch, uint32_t act, uint32_t centre, uint32_t &leave,
                        uint32_t *order) {
    int n = 0;
    float key[kWideUsed];
    for (uint32_t m = ch.used; m != 0; m &= m - 1) {
        const uint32_t s = uint32_t(__builtin_ctz(m));
        const float ts = ch.c[s].t[packet_key_ray(ch.c[s].active, centre)];
        int k = n;
        for (; k > 0 && key[k - 1] > ts; --k) {
            order[k] = order[k - 1];
            key[k] = key[k - 1];
        }
        order[k] = s;
        key[k] = ts;
        ++n;
    }
    if (n < 2) return n;
    for (uint32_t m = act; m != 0; m &= m - 1) {
        const int r = __builtin_ctz(m);
        int prev = -1;
        for (int i = 0; i < n; ++i) {
            const uint32_t s = order[i];
            if (!((ch.c[s].active >> r) & 1u)) continue;
            if (prev >= 0 && !packet_before(ch, r, uint32_t(prev), s)) {
                leave |= 1u << r;
                break;
            }
            prev = int(s);
        }
    }
    return n;
}

/// Three lanes V: a vector field of the packet's rays.
template <class V>
struct Lanes3 {
    V x, y, z;
};

/// Some of the packet's rays, one per lane, as the lane tests of wide_trace.h read a Ray.
template <class V>
struct PacketLanes {
    Lanes3<V> o, d;
    V tmin;
};

/// The rays [q, q + width of V) of `pr`.
inline PacketLanes<WideV> packet_lanes(const PacketRays &pr, uint32_t q) {
    return {{lanes_f32(pr.ox + q), lanes_f32(pr.oy + q), lanes_f32(pr.oz + q)},
            {lanes_f32(pr.dx + q), lanes_f32(pr.dy + q), lanes_f32(pr.dz + q)},
            lanes_f32(pr.tmin + q)};
}

/// Reports one lane's test over the packet's rays: entered, entry parameter, cones.
template <class V, class M>
inline void report_rays(M ok, V t, V cosv, float s, bool cull, uint32_t q, uint32_t lane,
                        PacketHits &out) {
    out.hit[lane] |= movemask(ok) << q;
    store_lanes(t, out.t[lane] + q);
    if (cull) {
        out.away[lane] |= movemask(cosv > V(s)) << q;
        out.toward[lane] |= movemask(cosv < V(0.f) - V(s)) << q;
    }
}

/// The cone's sine of one lane, decoded as cone_lanes does.
inline float cone_sine(uint16_t q) {
    return float(q) >= float(kConeNeverQ) ? 2.f : float(q) * (1.f / kConeScale);
}

/// Lane `lane` of sphere node `w` (its fields decoded as wide_lanes decodes them) against the
/// packet's rays, its cone under culling.
template <bool kSlabs>
inline void packet_sphere_lane(const WideNode &w, uint32_t lane, const PacketRays &pr, bool cull,
                               PacketHits &out) {
    using V = WideV;
    const float ka = 1.f / kAxisScale;
    const float r = w.r[lane];
    const float qslab = float(w.slab_q[lane]);
    const V cx(w.cx[lane]), cy(w.cy[lane]), cz(w.cz[lane]), rv(r);
    const V ax(float(w.ax[lane]) * ka), ay(float(w.ay[lane]) * ka), az(float(w.az[lane]) * ka);
    const V h(qslab >= float(kNoSlab) ? kInf : qslab * (1.f / 255.f) * r);
    const float s = cull ? cone_sine(w.cone_q[lane]) : 0.f;
    out.hit[lane] = out.away[lane] = out.toward[lane] = 0;
    for (uint32_t q = 0; q < uint32_t(kPacket); q += kWideStep) {
        V t, cosv;
        const auto ok = sphere_slab_lanes<kSlabs>(cx, cy, cz, rv, ax, ay, az, h, packet_lanes(pr, q),
                                                  lanes_f32(pr.tfar + q), t, cosv);
        report_rays(ok, t, cosv, s, cull, q, lane, out);
    }
}

/// Lane `lane` of box node `w` against the packet's rays, its cone under culling.
inline void packet_box_lane(const WideBoxNode &w, uint32_t lane, const PacketRays &pr, bool cull,
                            PacketHits &out) {
    using V = WideV;
    const float ka = 1.f / kAxisScale;
    const V lx(w.lx[lane]), ly(w.ly[lane]), lz(w.lz[lane]);
    const V hx(w.hx[lane]), hy(w.hy[lane]), hz(w.hz[lane]);
    const V ax(float(w.ax[lane]) * ka), ay(float(w.ay[lane]) * ka), az(float(w.az[lane]) * ka);
    const float s = cull ? cone_sine(w.cone_q[lane]) : 0.f;
    out.hit[lane] = out.away[lane] = out.toward[lane] = 0;
    for (uint32_t q = 0; q < uint32_t(kPacket); q += kWideStep) {
        V t;
        const PacketLanes<V> rays = packet_lanes(pr, q);
        const Lanes3<V> inv_d{lanes_f32(pr.ix + q), lanes_f32(pr.iy + q), lanes_f32(pr.iz + q)};
        const auto ok = box_lanes(lx, ly, lz, hx, hy, hz, rays, inv_d, lanes_f32(pr.tfar + q), t);
        // wide_box_lanes' cone cosine: the decoded axis times the direction
        const V cosv = cull ? ax * rays.d.x + ay * rays.d.y + az * rays.d.z : V(0.f);
        report_rays(ok, t, cosv, s, cull, q, lane, out);
    }
}

/// Tests the packet's rays `act` against the bounds of one wide node (`test(lane)`): A and B,
/// then the children of those of A and B that are interior and entered by some ray.
template <class Test>
inline void packet_node(const uint32_t *refs, uint32_t act, PacketHits &out, Test test) {
    for (uint32_t j = 0; j < 2; ++j) {
        test(j);
        const bool inner = !(refs[j] >> 27);
        for (uint32_t k = 0; k < 2; ++k) {
            const uint32_t lane = 2 + 2 * j + k;
            if (inner && (out.hit[j] & act)) test(lane);
            else out.hit[lane] = 0;
        }
    }
}

/// The state a ray that leaves a packet resumes from in the single-ray traversal
/// (traverse_wide_impl's `start`): its current entry and its pending entries, bottom first.
struct PacketResume {
    static constexpr bool kFromRoot = false;
    const StackEntry *pending;
    int n;
    StackEntry next;
    void operator()(StackEntry &e, StackEntry *stack, int &sp) const {
        for (int i = 0; i < n; ++i) stack[i] = pending[i];
        sp = n;
        e = next;
    }
};

/// Ray r leaves the packet at a step whose children (`ch`) it would order otherwise: its own
/// stack is the packet's entries it takes (`sp` on `pstack`, bottom first) and its children in
/// its own order, from which the single-ray traversal finishes it.
template <bool kSlabs>
inline void leave_packet(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                         const LodGates &gates, bool cull, Gather &pol, int r,
                         const PacketEntry *pstack, int sp, const PacketChildren &ch) {
    StackEntry stack[kStackSize];
    int n = 0;
    const uint32_t bit = 1u << r;
    auto entry = [&](const PacketEntry &x) {
        return StackEntry{x.node, x.t[r], x.depth,
                          uint16_t(x.flags | ((x.cull & bit) ? kCull : 0)), x.ref};
    };
    for (int i = 0; i < sp; ++i)
        if (pstack[i].active & bit) stack[n++] = entry(pstack[i]);
    uint32_t order[kWideUsed];
    int k = 0;
    for (uint32_t m = ch.used; m != 0; m &= m - 1) {
        const uint32_t s = uint32_t(__builtin_ctz(m));
        if (!(ch.c[s].active & bit)) continue;
        int j = k;
        for (; j > 0 && !packet_before(ch, r, order[j - 1], s); --j) order[j] = order[j - 1];
        order[j] = s;
        ++k;
    }
    for (int i = k - 1; i > 0; --i) stack[n++] = entry(ch.c[order[i]]);
    NoStats ns;
    traverse_wide_impl<kSlabs>(tree, ray, opt, gates, cull, pol, ns,
                               PacketResume{stack, n, entry(ch.c[order[0]])});
}

/// Whether a policy's answer is the same in any order of the leaves (any hit: its far bound
/// never moves, so a ray reaches the same leaves whatever the order, and the answer is whether
/// one of them holds a disk in range). Such rays never leave their packet.
template <class Policy>
constexpr bool kOrderFree = std::is_same<Policy, AnyHit>::value;

/// The packet traversal of rays [0, n) with one policy per ray (`pol`, kPacket of them: those
/// past n repeat ray 0's and are ignored), back-face culling when `cull`. Closest hits (Gather):
/// a ray whose order of children differs from the packet's leaves it there and finishes alone
/// (leave_packet). Any hits (kOrderFree): a ray leaves the packet's masks once its policy ends
/// its search (early exit), and the packet ends when every ray has its answer. Returns the mask
/// of the rays that neither left nor ended.
template <bool kSlabs, class Policy>
uint32_t packet_traverse(const SurfelTree &tree, const Ray *rays, int n, const TraceOptions &opt,
                         const LodGates &gates, bool cull, Policy *pol, uint32_t centre) {
    const auto &nodes = tree.nodes();
    const WideTree &wide = tree.wide();
    PacketRays pr;
    Vec3 inv_d[kPacket];
    PacketEntry e;
    e.node = 0;
    e.ref = 0;
    e.depth = 0;
    e.flags = 0;
    e.active = 0;
    for (int r = 0; r < kPacket; ++r) {
        const Ray &ray = rays[r < n ? r : 0];
        inv_d[r] = {1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z};
        pr.ox[r] = ray.o.x, pr.oy[r] = ray.o.y, pr.oz[r] = ray.o.z;
        pr.dx[r] = ray.d.x, pr.dy[r] = ray.d.y, pr.dz[r] = ray.d.z;
        pr.ix[r] = inv_d[r].x, pr.iy[r] = inv_d[r].y, pr.iz[r] = inv_d[r].z;
        pr.tmin[r] = ray.tmin;
        pr.tfar[r] = pol[r < n ? r : 0].tfar();
        e.t[r] = kInf;
        if (r >= n) continue;
        e.t[r] = enter_bound<kSlabs>(tree, 0, 0, ray, inv_d[r], pol[r].tfar(), opt.box_depth);
        if (e.t[r] != kInf) e.active |= uint8_t(1u << r);
    }
    e.cull = cull ? e.active : 0;
    uint32_t alive = (1u << n) - 1u;
    NoStats ns;

    PacketEntry stack[kStackSize];
    int sp = 0;
    bool have = e.active != 0;
    while (have) {
        uint32_t act = e.active, cullm = e.cull;
        uint32_t wi = kNoWide;
        PacketChildren ch;
        if (e.flags & kVisited) {
            if (e.ref >> 27) {
                for (uint32_t m = act; m != 0; m &= m - 1) {
                    const int r = __builtin_ctz(m);
                    const bool ends = visit_leaf(tree, e.ref & (kMaxTreeSurfels - 1), e.ref >> 27,
                                                 rays[r], ((cullm >> r) & 1u) != 0, pol[r], ns);
                    if constexpr (kOrderFree<Policy>) alive &= ends ? ~(1u << r) : ~0u;
                    pr.tfar[r] = pol[r].tfar();
                }
            } else {
                wi = e.ref;
            }
        } else {
            // The root (and its children when the wide levels start at depth 1).
            const Node &nd = nodes[e.node];
            for (uint32_t m = act; m != 0; m &= m - 1) {
                const int r = __builtin_ctz(m);
                bool c = ((cullm >> r) & 1u) != 0;
                if (!cone_admits(nd, rays[r], c)) act &= ~(1u << r);
                else if (!c) cullm &= ~(1u << r);
            }
            cullm &= act;
            if (act == 0) {
            } else if (nd.is_leaf()) {
                for (uint32_t m = act; m != 0; m &= m - 1) {
                    const int r = __builtin_ctz(m);
                    const bool ends = visit_leaf(tree, nd.index(), nd.count(), rays[r],
                                                 ((cullm >> r) & 1u) != 0, pol[r], ns);
                    if constexpr (kOrderFree<Policy>) alive &= ends ? ~(1u << r) : ~0u;
                    pr.tfar[r] = pol[r].tfar();
                }
            } else if (wide.has(e.node)) {
                wi = wide.index_of(e.node);
            } else {
                const uint32_t c0 = nd.index();
                const uint16_t cd = uint16_t(e.depth + 1);
                for (uint32_t m = act; m != 0; m &= m - 1) {
                    const int r = __builtin_ctz(m);
                    const float tf = pol[r].tfar();
                    const float ta = enter_bound<kSlabs>(tree, c0, cd, rays[r], inv_d[r], tf, opt.box_depth);
                    const float tb = enter_bound<kSlabs>(tree, c0 + 1, cd, rays[r], inv_d[r], tf, opt.box_depth);
                    const bool c = ((cullm >> r) & 1u) != 0;
                    if (ta != kInf) ch.add(0, r, ta, c);
                    if (tb != kInf) ch.add(1, r, tb, c);
                }
                for (uint32_t s = 0; s < 2; ++s) {
                    ch.c[s].node = c0 + s;
                    ch.c[s].ref = 0;
                    ch.c[s].depth = cd;
                    ch.c[s].flags = 0;
                }
            }
        }
        if (wi != kNoWide) {
            alignas(32) PacketHits ph;
            const uint32_t *refs;
            const bool cull = cullm != 0;
            if (wide.box_level(e.depth)) {
                const WideBoxNode &w = wide.box_node(wi);
                refs = w.ref;
                packet_node(refs, act, ph, [&](uint32_t lane) { packet_box_lane(w, lane, pr, cull, ph); });
            } else {
                const WideNode &w = wide.node(wi);
                refs = w.ref;
                packet_node(refs, act, ph, [&](uint32_t lane) {
                    packet_sphere_lane<kSlabs>(w, lane, pr, cull, ph);
                });
            }
            // Each ray's entries as the single traversal makes them, as masks of rays; slots
            // in its order of creation: A (leaf), A1, A2, B (leaf), B1, B2.
            static constexpr uint32_t kSlotOfLane[kWideUsed] = {0, 3, 1, 2, 4, 5};
            auto take = [&](uint32_t lane, uint32_t in, uint32_t cin) {
                if (!in) return;
                const uint32_t s = kSlotOfLane[lane];
                PacketEntry &x = ch.c[s];
                x.node = 0;
                x.ref = refs[lane];
                x.depth = uint16_t(e.depth + 1 + (lane >= 2));
                x.flags = kVisited;
                x.active = uint8_t(in);
                x.cull = uint8_t(cin);
                std::memcpy(x.t, ph.t[lane], sizeof x.t);
                ch.used |= 1u << s;
                prefetch_entry(tree, x.ref, x.depth);
            };
            for (uint32_t j = 0; j < 2; ++j) {
                // A or B: entered and not turned away by its cone; still culling below where
                // its cone does not face every ray.
                const uint32_t in = ph.hit[j] & act & ~(cullm & ph.away[j]);
                const uint32_t xc = in & cullm & ~ph.toward[j];
                if (refs[j] >> 27) {
                    take(j, in, xc);
                    continue;
                }
                for (uint32_t k = 0; k < 2; ++k) {
                    const uint32_t lane = 2 + 2 * j + k;
                    const uint32_t gin = ph.hit[lane] & in & ~(xc & ph.away[lane]);
                    take(lane, gin, gin & xc & ~ph.toward[lane]);
                }
            }
        }
        have = false;
        if (ch.used) {
            uint32_t order[kWideUsed];
            uint32_t leave = 0;
            // Any hits: near first for an early exit, the order any; no ray leaves.
            const int k = packet_order(ch, kOrderFree<Policy> ? 0u : act, centre, leave, order);
            if constexpr (!kOrderFree<Policy>) {
                for (uint32_t m = leave; m != 0; m &= m - 1) {
                    const int r = __builtin_ctz(m);
                    leave_packet<kSlabs>(tree, rays[r], opt, gates, cull, pol[r], r, stack, sp, ch);
                }
                alive &= ~leave;
            }
            for (int i = k - 1; i >= 0; --i) {
                PacketEntry &x = ch.c[order[i]];
                x.active &= uint8_t(alive);
                x.cull &= x.active;
                if (!x.active) continue;
                if (have) stack[sp++] = e;
                e = x;
                have = true;
            }
        }
        if (have) continue;
        // Pop the nearest pending entry that can still hold a closer hit for some ray.
        while (sp > 0 && (!kOrderFree<Policy> || alive)) {
            e = stack[--sp];
            uint32_t far = 0;
            for (uint32_t q = 0; q < uint32_t(kPacket); q += kWideStep)
                far |= movemask(lanes_f32(e.t + q) > lanes_f32(pr.tfar + q)) << q;
            const uint32_t a = e.active & alive & ~far;
            if (a) {
                e.active = uint8_t(a);
                e.cull &= e.active;
                have = true;
                break;
            }
        }
    }
    return alive;
}

}  // namespace detail

/// Closest hits of `n` <= kPacket rays traversed as one packet (no level of detail, no
/// statistics; use_wide(tree, opt) must hold); `centre`: the packet's middle rays. A ray whose
/// order of children differs from the packet's leaves it there and finishes alone
/// (leave_packet). Returns the mask of the rays that stayed in the packet to the end.
template <bool kSlabs>
uint32_t closest_hits_packet_impl(const SurfelTree &tree, const Ray *rays, int n,
                                  const TraceOptions &opt, const LodGates &gates, SurfaceHit *out,
                                  uint32_t centre = kRowCentre) {
    using namespace detail;
    alignas(64) Gather pol[kPacket] = {
        {rays[0].tmax, opt.window}, {n > 1 ? rays[1].tmax : 0.f, opt.window},
        {n > 2 ? rays[2].tmax : 0.f, opt.window}, {n > 3 ? rays[3].tmax : 0.f, opt.window},
        {n > 4 ? rays[4].tmax : 0.f, opt.window}, {n > 5 ? rays[5].tmax : 0.f, opt.window},
        {n > 6 ? rays[6].tmax : 0.f, opt.window}, {n > 7 ? rays[7].tmax : 0.f, opt.window}};
    const uint32_t alive = packet_traverse<kSlabs>(tree, rays, n, opt, gates, opt.cull, pol, centre);
    for (int r = 0; r < n; ++r) finish_closest(tree, opt, pol[r], out[r]);
    return alive;
}

/// Any hits in [tmin, tmax] of `n` <= kPacket rays traversed as one packet (no level of
/// detail, no statistics; use_wide(tree, opt) must hold), back-face culling when `cull`:
/// hit[r] as any_hit's for ray r. No ray leaves the packet. Returns the mask of the rays hit.
template <bool kSlabs>
uint32_t any_hits_packet_impl(const SurfelTree &tree, const Ray *rays, int n,
                              const TraceOptions &opt, const LodGates &gates, bool cull,
                              uint8_t *hit, uint32_t centre = kRowCentre) {
    using namespace detail;
    AnyHit pol[kPacket] = {AnyHit(rays[0].tmax),      AnyHit(n > 1 ? rays[1].tmax : 0.f),
                           AnyHit(n > 2 ? rays[2].tmax : 0.f), AnyHit(n > 3 ? rays[3].tmax : 0.f),
                           AnyHit(n > 4 ? rays[4].tmax : 0.f), AnyHit(n > 5 ? rays[5].tmax : 0.f),
                           AnyHit(n > 6 ? rays[6].tmax : 0.f), AnyHit(n > 7 ? rays[7].tmax : 0.f)};
    packet_traverse<kSlabs>(tree, rays, n, opt, gates, cull, pol, centre);
    uint32_t mask = 0;
    for (int r = 0; r < n; ++r) {
        hit[r] = pol[r].hit;
        mask |= uint32_t(pol[r].hit) << r;
    }
    return mask;
}

/// Whether rays [0, n) may take closest_hits_packet: the options are covered (wide traversal,
/// no level of detail for these rays) and the rays are coherent (one origin and tmin,
/// directions within kPacketMinCos of the first). `one_tmin` false: any_hits_packet's rays,
/// whose tmin may differ (occluded scales one t_min by each ray's direction length).
inline bool packet_covers(const SurfelTree &tree, const Ray *rays, int n, const TraceOptions &opt,
                          bool one_tmin = true) {
    if (n < 2 || !use_wide(tree, opt)) return false;
    const Ray &f = rays[0];
    for (int r = 0; r < n; ++r) {
        const Ray &x = rays[r];
        if (opt.lod && (x.spread > 0.f || x.width0 > 0.f)) return false;
        if (!(x.o.x == f.o.x && x.o.y == f.o.y && x.o.z == f.o.z)) return false;
        if (one_tmin && !(x.tmin == f.tmin)) return false;
        if (!(dot(x.d, f.d) >= kPacketMinCos)) return false;
    }
    return true;
}

/// Closest hits of `n` <= kPacket rays that packet_covers: traversed as one packet, the rays
/// that leave it finished alone. Results equal closest_hit's for every ray, bit for bit.
inline void closest_hits_packet(const SurfelTree &tree, const Ray *rays, int n,
                                const TraceOptions &opt, const LodGates &gates, SurfaceHit *out,
                                uint32_t centre = kRowCentre) {
    if (opt.slabs) closest_hits_packet_impl<true>(tree, rays, n, opt, gates, out, centre);
    else closest_hits_packet_impl<false>(tree, rays, n, opt, gates, out, centre);
}

/// Any hits of `n` <= kPacket rays that packet_covers (one_tmin false), two-sided unless
/// `cull`: traversed as one packet. hit[r] equals any_hit's for every ray.
inline void any_hits_packet(const SurfelTree &tree, const Ray *rays, int n,
                            const TraceOptions &opt, const LodGates &gates, bool cull,
                            uint8_t *hit, uint32_t centre = kRowCentre) {
    if (opt.slabs) any_hits_packet_impl<true>(tree, rays, n, opt, gates, cull, hit, centre);
    else any_hits_packet_impl<false>(tree, rays, n, opt, gates, cull, hit, centre);
}

POINTVIZ_ISA_END
}  // namespace pointviz
