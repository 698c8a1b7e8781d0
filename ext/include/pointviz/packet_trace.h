// pointviz — packets of coherent rays traversing the wide tree together, for closest hits.
//
// Up to kPacket rays (camera rays of neighbouring pixels: one origin, directions within
// kPacketMinCos of the first) walk the wide tree (wide.h) as one: a node is visited once for the
// packet, its fields are loaded and decoded once (the quantised axes, cones and slabs) and its
// lanes tested against every active ray with the single-ray lane tests (wide_trace.h), so each
// ray gets the single-ray answer bit for bit; the children are sorted and pushed once, with the
// mask of the rays that take them, their cone state and one entry parameter per ray. Each ray
// keeps its own closest-hit policy (trace.h, Gather), so far entries are culled per ray on pop;
// leaves run the leaf kernel once per active ray.
//
// Bit-identical to the single-ray traversal: a ray's gathered disks can depend on the order in
// which they reach its policy (wide_trace.h), so a ray stays in the packet only while the
// packet's order of children, restricted to the children it hits, is its own near-first order
// (ties by the single traversal's order of creation). A ray whose order differs at some node
// leaves the packet there and finishes alone in the single-ray loop (wide_trace.h, wide_loop),
// from its own stack: the packet's pending entries it takes, and that node's children in its
// own order. Either way a ray sees exactly the single-ray sequence of nodes, leaves and
// far-bound tests.
//
// Not covered (the caller takes the single-ray path): level of detail (rays with a footprint
// under TraceOptions::lod), statistics, the binary traversal (TraceOptions::wide false or a box
// depth the wide nodes were not built for), any hit, and groups that are not coherent (different
// origins or tmin, directions spread beyond kPacketMinCos).
#pragma once

#include <cstdint>

#include "pointviz/isa.h"
#include "pointviz/trace.h"
#include "pointviz/wide_trace.h"

namespace pointviz {

/// Rays per packet (one bit each in the masks below).
constexpr int kPacket = 8;
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
    float t[kPacket];     ///< entry parameter per active ray
};

/// The entries one step creates, in the single traversal's order of creation (`slot`).
struct PacketChildren {
    PacketEntry c[kWideUsed];
    uint8_t lanes[kPacket];  ///< per ray: slots it takes
    uint32_t used = 0;       ///< slots taken by any ray

    void add(uint32_t slot, int r, float t, bool cull) {
        PacketEntry &x = c[slot];
        const uint8_t bit = uint8_t(1u << r);
        if (!((used >> slot) & 1u)) {
            used |= 1u << slot;
            x.active = x.cull = 0;
        }
        x.active |= bit;
        if (cull) x.cull |= bit;
        x.t[r] = t;
        lanes[r] |= uint8_t(1u << slot);
    }
};

/// Whether slot a comes before slot b for ray r in the single traversal (near first, ties in
/// order of creation).
inline bool packet_before(const PacketChildren &ch, int r, uint32_t a, uint32_t b) {
    const float ta = ch.c[a].t[r], tb = ch.c[b].t[r];
    return ta < tb || (!(tb < ta) && a < b);
}

/// The ray whose entry parameter stands for a slot's in the packet order: the slot's ray
/// nearest the middle of the packet (rays in raster order diverge at both ends).
inline int packet_key_ray(uint32_t active) {
    const uint32_t upper = active & ~((1u << (kPacket / 2 - 1)) - 1u);
    return upper ? __builtin_ctz(upper) : 31 - __builtin_clz(active);
}

/// Sorts the used slots near first by the entry parameter of each slot's middle ray (a guess
/// at the shared order) and adds to `leave` the rays of `act` whose own order differs. Writes
/// the order to `order`; returns how many slots.
inline int packet_order(const PacketChildren &ch, uint32_t act, uint32_t &leave, uint32_t *order) {
    int n = 0;
    for (uint32_t m = ch.used; m != 0; m &= m - 1) {
        const uint32_t s = uint32_t(__builtin_ctz(m));
        const int r = packet_key_ray(ch.c[s].active);
        int k = n;
        for (; k > 0; --k) {
            const uint32_t p = order[k - 1];
            const float tp = ch.c[p].t[packet_key_ray(ch.c[p].active)], ts = ch.c[s].t[r];
            if (!(tp > ts)) break;
            order[k] = p;
        }
        order[k] = s;
        ++n;
    }
    for (uint32_t m = act; m != 0; m &= m - 1) {
        const int r = __builtin_ctz(m);
        int prev = -1;
        for (int i = 0; i < n; ++i) {
            const uint32_t s = order[i];
            if (!((ch.lanes[r] >> s) & 1u)) continue;
            if (prev >= 0 && !packet_before(ch, r, uint32_t(prev), s)) {
                leave |= 1u << r;
                break;
            }
            prev = int(s);
        }
    }
    return n;
}

/// Clears the lane masks of the rays in `act`.
inline void clear_hits(uint32_t act, WideHits *wh) {
    for (uint32_t m = act; m != 0; m &= m - 1) {
        WideHits &o = wh[__builtin_ctz(m)];
        o.mask = o.away = o.toward = 0;
    }
}

/// Tests the active rays against the six spheres (and slabs) of `w`: the fields decoded once,
/// then each ray through sphere_slab_lanes (the single-ray test), its cones under culling.
template <bool kSlabs>
inline void packet_enter_wide(const WideNode &w, const Ray *rays, const Gather *pol,
                              uint32_t act, uint32_t cullm, WideHits *wh) {
    using V = WideV;
    clear_hits(act, wh);
    for (uint32_t g = 0; g < uint32_t(kWideUsed); g += kWideStep) {
        const V cx = lanes_f32(w.cx + g), cy = lanes_f32(w.cy + g), cz = lanes_f32(w.cz + g);
        const V r = lanes_f32(w.r + g);
        const V ka(1.f / kAxisScale);
        const V ax = lanes_i16(w.ax + g) * ka, ay = lanes_i16(w.ay + g) * ka,
                az = lanes_i16(w.az + g) * ka;
        const V qslab = lanes_u8(w.slab_q + g);
        const V h = select(qslab >= V(float(kNoSlab)), V(kInf), qslab * V(1.f / 255.f) * r);
        const V s = cullm ? cone_lanes(lanes_u16(w.cone_q + g)) : V(0.f);
        for (uint32_t m = act; m != 0; m &= m - 1) {
            const int k = __builtin_ctz(m);
            WideHits &o = wh[k];
            if (g >= 4 && !(o.mask & 2u)) continue;  // B missed: its children do not count
            V t, cosv;
            const auto ok = sphere_slab_lanes<kSlabs>(cx, cy, cz, r, ax, ay, az, h, rays[k],
                                                      pol[k].tfar(), t, cosv);
            report_hits(ok, t, g, o);
            if ((cullm >> k) & 1u) report_cones(cosv, s, g, o);
        }
    }
}

/// The same for the six boxes of `w`.
inline void packet_enter_wide_box(const WideBoxNode &w, const Ray *rays, const Vec3 *inv_d,
                                  const Gather *pol, uint32_t act, uint32_t cullm, WideHits *wh) {
    using V = WideV;
    clear_hits(act, wh);
    for (uint32_t g = 0; g < uint32_t(kWideUsed); g += kWideStep) {
        const V lx = lanes_f32(w.lx + g), ly = lanes_f32(w.ly + g), lz = lanes_f32(w.lz + g);
        const V hx = lanes_f32(w.hx + g), hy = lanes_f32(w.hy + g), hz = lanes_f32(w.hz + g);
        const V ka(1.f / kAxisScale);
        V ax(0.f), ay(0.f), az(0.f), s(0.f);
        if (cullm) {
            ax = lanes_i16(w.ax + g) * ka;
            ay = lanes_i16(w.ay + g) * ka;
            az = lanes_i16(w.az + g) * ka;
            s = cone_lanes(lanes_u16(w.cone_q + g));
        }
        for (uint32_t m = act; m != 0; m &= m - 1) {
            const int k = __builtin_ctz(m);
            WideHits &o = wh[k];
            if (g >= 4 && !(o.mask & 2u)) continue;
            const Ray &ray = rays[k];
            V t;
            const auto ok = box_lanes(lx, ly, lz, hx, hy, hz, ray, inv_d[k], pol[k].tfar(), t);
            report_hits(ok, t, g, o);
            if ((cullm >> k) & 1u) {
                const V cosv = ax * V(ray.d.x) + ay * V(ray.d.y) + az * V(ray.d.z);
                report_cones(cosv, s, g, o);
            }
        }
    }
}

/// Ray r leaves the packet at a step whose children (`ch`) it would order otherwise: its own
/// stack is the packet's entries it takes (`sp` on `pstack`, bottom first) and its children in
/// its own order, from which the single-ray loop (wide_loop) finishes it.
template <bool kSlabs>
inline void leave_packet(const SurfelTree &tree, const Ray &ray, const TraceOptions &opt,
                         const LodGates &gates, Gather &pol, int r, const PacketEntry *pstack,
                         int sp, const PacketChildren &ch) {
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
    for (uint32_t m = ch.lanes[r]; m != 0; m &= m - 1) {
        const uint32_t s = uint32_t(__builtin_ctz(m));
        int j = k;
        for (; j > 0 && !packet_before(ch, r, order[j - 1], s); --j) order[j] = order[j - 1];
        order[j] = s;
        ++k;
    }
    for (int i = k - 1; i > 0; --i) stack[n++] = entry(ch.c[order[i]]);
    const RaySetup rs(tree, ray, opt, gates, pol, std::integral_constant<bool, kSlabs>());
    NoStats ns;
    wide_loop<kSlabs>(tree, ray, opt, rs, pol, ns, entry(ch.c[order[0]]), stack, n);
}

}  // namespace detail

/// Closest hits of `n` <= kPacket rays traversed as one packet (no level of detail, no
/// statistics; use_wide(tree, opt) must hold). A ray whose order of children differs from the
/// packet's leaves it there and finishes alone (leave_packet). Returns the mask of the rays
/// that stayed in the packet to the end.
template <bool kSlabs>
uint32_t closest_hits_packet_impl(const SurfelTree &tree, const Ray *rays, int n,
                                  const TraceOptions &opt, const LodGates &gates, SurfaceHit *out) {
    using namespace detail;
    const auto &nodes = tree.nodes();
    const WideTree &wide = tree.wide();
    alignas(64) Gather pol[kPacket] = {
        {rays[0].tmax, opt.window}, {n > 1 ? rays[1].tmax : 0.f, opt.window},
        {n > 2 ? rays[2].tmax : 0.f, opt.window}, {n > 3 ? rays[3].tmax : 0.f, opt.window},
        {n > 4 ? rays[4].tmax : 0.f, opt.window}, {n > 5 ? rays[5].tmax : 0.f, opt.window},
        {n > 6 ? rays[6].tmax : 0.f, opt.window}, {n > 7 ? rays[7].tmax : 0.f, opt.window}};
    Vec3 inv_d[kPacket];
    PacketEntry e;
    e.node = 0;
    e.ref = 0;
    e.depth = 0;
    e.flags = 0;
    e.active = 0;
    for (int r = 0; r < n; ++r) {
        const Ray &ray = rays[r];
        inv_d[r] = {1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z};
        e.t[r] = enter_bound<kSlabs>(tree, 0, 0, ray, inv_d[r], pol[r].tfar(), opt.box_depth);
        if (e.t[r] != kInf) e.active |= uint8_t(1u << r);
    }
    e.cull = opt.cull ? e.active : 0;
    uint32_t alive = (1u << n) - 1u;
    NoStats ns;

    PacketEntry stack[kStackSize];
    int sp = 0;
    bool have = e.active != 0;
    while (have) {
        uint32_t act = e.active, cullm = e.cull;
        uint32_t wi = kNoWide;
        PacketChildren ch;
        for (int r = 0; r < kPacket; ++r) ch.lanes[r] = 0;
        if (e.flags & kVisited) {
            if (e.ref >> 27) {
                for (uint32_t m = act; m != 0; m &= m - 1) {
                    const int r = __builtin_ctz(m);
                    visit_leaf(tree, e.ref & (kMaxTreeSurfels - 1), e.ref >> 27, rays[r],
                               ((cullm >> r) & 1u) != 0, pol[r], ns);
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
                    visit_leaf(tree, nd.index(), nd.count(), rays[r], ((cullm >> r) & 1u) != 0,
                               pol[r], ns);
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
            WideHits wh[kPacket];
            const uint32_t *refs;
            if (wide.box_level(e.depth)) {
                const WideBoxNode &w = wide.box_node(wi);
                packet_enter_wide_box(w, rays, inv_d, pol, act, cullm, wh);
                refs = w.ref;
            } else {
                const WideNode &w = wide.node(wi);
                packet_enter_wide<kSlabs>(w, rays, pol, act, cullm, wh);
                refs = w.ref;
            }
            // Each ray's entries as the single traversal makes them; slots in its order of
            // creation: A (leaf), A1, A2, B (leaf), B1, B2.
            static constexpr uint32_t kSlotOfLane[kWideUsed] = {0, 3, 1, 2, 4, 5};
            static constexpr uint32_t kLaneOfSlot[kWideUsed] = {0, 2, 3, 1, 4, 5};
            for (uint32_t m = act; m != 0; m &= m - 1) {
                const int r = __builtin_ctz(m);
                const WideHits &h = wh[r];
                const bool rc = ((cullm >> r) & 1u) != 0;
                for (uint32_t j = 0; j < 2; ++j) {
                    if (!((h.mask >> j) & 1u)) continue;
                    bool xc = rc;
                    if (xc && ((h.away >> j) & 1u)) continue;
                    if (xc && ((h.toward >> j) & 1u)) xc = false;
                    if (refs[j] >> 27) {
                        ch.add(kSlotOfLane[j], r, h.t[j], xc);
                        continue;
                    }
                    for (uint32_t k = 0; k < 2; ++k) {
                        const uint32_t lane = 2 + 2 * j + k;
                        if (!((h.mask >> lane) & 1u)) continue;
                        bool yc = xc;
                        if (yc && ((h.away >> lane) & 1u)) continue;
                        if (yc && ((h.toward >> lane) & 1u)) yc = false;
                        ch.add(kSlotOfLane[lane], r, h.t[lane], yc);
                    }
                }
            }
            for (uint32_t m = ch.used; m != 0; m &= m - 1) {
                const uint32_t s = uint32_t(__builtin_ctz(m));
                const uint32_t lane = kLaneOfSlot[s];
                PacketEntry &x = ch.c[s];
                x.node = 0;
                x.ref = refs[lane];
                x.depth = uint16_t(e.depth + 1 + (lane >= 2));
                x.flags = kVisited;
                prefetch_entry(tree, x.ref, x.depth);
            }
        }
        have = false;
        if (ch.used) {
            uint32_t order[kWideUsed];
            uint32_t leave = 0;
            const int k = packet_order(ch, act, leave, order);
            for (uint32_t m = leave; m != 0; m &= m - 1) {
                const int r = __builtin_ctz(m);
                leave_packet<kSlabs>(tree, rays[r], opt, gates, pol[r], r, stack, sp, ch);
            }
            alive &= ~leave;
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
        while (sp > 0) {
            e = stack[--sp];
            uint32_t a = e.active & alive;
            for (uint32_t m = a; m != 0; m &= m - 1) {
                const int r = __builtin_ctz(m);
                if (e.t[r] > pol[r].tfar()) a &= ~(1u << r);
            }
            if (a) {
                e.active = uint8_t(a);
                e.cull &= e.active;
                have = true;
                break;
            }
        }
    }
    for (int r = 0; r < n; ++r) finish_closest(tree, opt, pol[r], out[r]);
    return alive;
}

/// Whether rays [0, n) may take closest_hits_packet: the options are covered (wide traversal,
/// no level of detail for these rays) and the rays are coherent (one origin and tmin,
/// directions within kPacketMinCos of the first).
inline bool packet_covers(const SurfelTree &tree, const Ray *rays, int n, const TraceOptions &opt) {
    if (n < 2 || !use_wide(tree, opt)) return false;
    const Ray &f = rays[0];
    for (int r = 0; r < n; ++r) {
        const Ray &x = rays[r];
        if (opt.lod && (x.spread > 0.f || x.width0 > 0.f)) return false;
        if (!(x.o.x == f.o.x && x.o.y == f.o.y && x.o.z == f.o.z && x.tmin == f.tmin)) return false;
        if (!(dot(x.d, f.d) >= kPacketMinCos)) return false;
    }
    return true;
}

/// Closest hits of `n` <= kPacket rays that packet_covers: traversed as one packet, the rays
/// that leave it finished alone. Results equal closest_hit's for every ray, bit for bit.
inline void closest_hits_packet(const SurfelTree &tree, const Ray *rays, int n,
                                const TraceOptions &opt, const LodGates &gates, SurfaceHit *out) {
    if (opt.slabs) closest_hits_packet_impl<true>(tree, rays, n, opt, gates, out);
    else closest_hits_packet_impl<false>(tree, rays, n, opt, gates, out);
}

POINTVIZ_ISA_END
}  // namespace pointviz
