// pointviz — the conventional KD-tree: binned-SAH build, front-to-back traversal, queries.
#include "pointviz/kdtree.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <stdexcept>
#include <string>

#include "pointviz/leaf_simd.h"
#include "pointviz/parallel.h"

namespace pointviz {
namespace {

/// Candidate split planes per axis: the bin boundaries. 32 bins find a plane within 3% of the
/// cell's width of the exact SAH optimum, at O(references) per axis.
constexpr int kSahBins = 32;
/// pbrt's budget of splits that cost more than the leaf they replace, along one path.
constexpr int kMaxBadRefines = 3;
/// Disk boxes grow by this fraction of the scene's extent, so that a hit point rounded in float
/// never falls outside every cell that references its disk.
constexpr float kBoxPad = 1e-6f;
/// The build polls for cancellation at least once per this many references binned.
constexpr size_t kPollRefs = size_t(1) << 16;

float half_area(Vec3 e) { return e.x * e.y + e.y * e.z + e.z * e.x; }

/// Recursive SAH build over reference lists; nodes in depth-first order (below child next).
struct Builder {
    const std::vector<Box> &boxes;
    const KdBuildOptions &opt;
    Progress *progress;
    uint32_t max_depth;
    std::vector<KdNode> &nodes;
    std::vector<uint32_t> &leaf_refs;
    uint32_t depth_reached = 0;

    void poll(size_t &since, size_t work) {
        since += work;
        if (since >= kPollRefs) {
            since = 0;
            check_cancel(progress);
        }
    }

    void leaf(const std::vector<uint32_t> &refs, uint32_t me, uint32_t depth) {
        if (refs.size() > kKdMaxIndex || leaf_refs.size() + refs.size() > kKdMaxIndex)
            throw std::length_error("KD-tree: too many surfel references (limit 2^30)");
        KdNode &nd = nodes[me];
        nd.first = uint32_t(leaf_refs.size());
        nd.bits = 3u | (uint32_t(refs.size()) << 2);
        leaf_refs.insert(leaf_refs.end(), refs.begin(), refs.end());
        depth_reached = std::max(depth_reached, depth);
        if (progress) progress->advance(refs.size());
    }

    void build(std::vector<uint32_t> refs, const Box &cell, uint32_t depth, int bad) {
        check_cancel(progress);
        if (nodes.size() >= kKdMaxIndex) throw std::length_error("KD-tree: too many nodes");
        const uint32_t me = uint32_t(nodes.size());
        nodes.push_back(KdNode{});
        const size_t m = refs.size();
        if (m <= opt.max_leaf || depth >= max_depth) return leaf(refs, me, depth);

        const Vec3 ext = cell.hi - cell.lo;
        const float inv_area = 1.f / half_area(ext);
        float best_cost = kInf, best_plane = 0.f;
        int best_axis = -1;
        size_t since = 0;
        for (int a = 0; a < 3; ++a) {
            if (!(ext[a] > 0.f)) continue;
            uint32_t start[kSahBins] = {}, end[kSahBins] = {};
            const float scale = float(kSahBins) / ext[a], lo0 = cell.lo[a];
            auto bin = [&](float x) {
                float b = std::min(float(kSahBins - 1), std::max(0.f, (x - lo0) * scale));
                return int(b);
            };
            for (uint32_t r : refs) {
                ++start[bin(boxes[r].lo[a])];
                ++end[bin(boxes[r].hi[a])];
            }
            poll(since, m);
            // Plane k lies between bins k-1 and k: a reference starting in a bin below k lies
            // (partly) below it, one ending in a bin below k lies entirely below it.
            size_t below = 0, above = m;
            const float w = ext[a] / float(kSahBins);
            for (int k = 1; k < kSahBins; ++k) {
                below += start[k - 1];
                above -= end[k - 1];
                Vec3 eb = ext, ea = ext;
                eb[a] = w * float(k);
                ea[a] = ext[a] - eb[a];
                const float pb = half_area(eb) * inv_area, pa = half_area(ea) * inv_area;
                const float bonus = (below == 0 || above == 0) ? opt.empty_bonus : 0.f;
                const float cost =
                    1.f + opt.intersect_cost * (1.f - bonus) * (pb * float(below) + pa * float(above));
                if (cost < best_cost) {
                    best_cost = cost;
                    best_axis = a;
                    best_plane = lo0 + eb[a];
                }
            }
        }
        const float leaf_cost = opt.intersect_cost * float(m);
        if (best_cost > leaf_cost) ++bad;
        if (best_axis < 0 || (best_cost > 4.f * leaf_cost && m < 16) || bad >= kMaxBadRefines)
            return leaf(refs, me, depth);

        // A disk touching the plane goes to both sides: every point of it lies in a child cell.
        std::vector<uint32_t> below, above;
        for (uint32_t r : refs) {
            if (boxes[r].lo[best_axis] <= best_plane) below.push_back(r);
            if (boxes[r].hi[best_axis] >= best_plane) above.push_back(r);
        }
        if (progress) progress->total.fetch_add(below.size() + above.size() - m);
        std::vector<uint32_t>().swap(refs);
        Box cb = cell, ca = cell;
        cb.hi[best_axis] = best_plane;
        ca.lo[best_axis] = best_plane;
        build(std::move(below), cb, depth + 1, bad);
        const uint32_t above_index = uint32_t(nodes.size());
        build(std::move(above), ca, depth + 1, bad);
        KdNode &nd = nodes[me];
        nd.split = best_plane;
        nd.bits = uint32_t(best_axis) | (above_index << 2);
    }
};

/// Keeps each surfel once: a disk referenced from several cells is found again in each.
struct KdGather : detail::Gather {
    const uint32_t *index;
    KdGather(float tmax, float window_, const uint32_t *index_)
        : detail::Gather(tmax, window_), index(index_) {}
    bool add(const detail::Candidate &k) {
        for (int j = 0; j < n; ++j)
            if (index[c[j].ref] == index[k.ref]) return false;
        return detail::Gather::add(k);
    }
};

}  // namespace

KdTree::KdTree(const SurfelArrays &in, const double origin[3], const KdBuildOptions &opt,
               Progress *progress) {
    auto t0 = std::chrono::steady_clock::now();
    const size_t n = in.n;
    if (n == 0) throw std::invalid_argument("cannot build a KD-tree of zero surfels");
    if (n >= kMaxTreeSurfels)
        throw std::length_error("too many surfels for one tree (limit 2^27 = 134,217,728)");
    for (int k = 0; k < 3; ++k) origin_[k] = origin[k];
    n_surfels_ = n;
    if (progress) progress->total.store(n);

    // Local surfels and the exact box of each disk: extent r sqrt(1 - n_k^2) along axis k.
    std::vector<Surfel> surfels(n);
    std::vector<Box> boxes(n);
    Box all{{kInf, kInf, kInf}, {-kInf, -kInf, -kInf}};
    for (size_t i = 0; i < n; ++i) {
        if (i % kPollRefs == 0) check_cancel(progress);
        const double *p = in.points + 3 * i;
        const float *nn = in.normals + 3 * i;
        Surfel &s = surfels[i];
        s.p = {float(p[0] - origin[0]), float(p[1] - origin[1]), float(p[2] - origin[2])};
        s.r = in.radii[i];
        s.n = normalize(Vec3{nn[0], nn[1], nn[2]});
        s.rgba = in.colors ? pack_rgb(in.colors[3 * i], in.colors[3 * i + 1], in.colors[3 * i + 2])
                           : 0xffffffffu;
        if (!(std::isfinite(s.p.x) && std::isfinite(s.p.y) && std::isfinite(s.p.z) &&
              std::isfinite(s.r) && s.r >= 0.f))
            throw std::invalid_argument("KD-tree: surfel " + std::to_string(i) +
                                        " has a non-finite position or radius");
        Vec3 e;
        for (int k = 0; k < 3; ++k) e[k] = s.r * std::sqrt(std::max(0.f, 1.f - s.n[k] * s.n[k]));
        boxes[i] = {s.p - e, s.p + e};
        all.lo = vmin(all.lo, boxes[i].lo);
        all.hi = vmax(all.hi, boxes[i].hi);
    }
    const float pad = kBoxPad * std::max(max_component(all.hi - all.lo), 1e-30f);
    const Vec3 pv{pad, pad, pad};
    for (Box &b : boxes) b = {b.lo - pv, b.hi + pv};
    bounds_ = {all.lo - pv, all.hi + pv};

    const uint32_t max_depth =
        opt.max_depth ? opt.max_depth
                      : uint32_t(std::lround(8.0 + 1.3 * std::log2(double(n))));
    std::vector<uint32_t> leaf_refs;
    Builder b{boxes, opt, progress, std::min<uint32_t>(max_depth, kKdStackSize - 2), nodes_,
              leaf_refs};
    std::vector<uint32_t> refs(n);
    for (size_t i = 0; i < n; ++i) refs[i] = uint32_t(i);
    b.build(std::move(refs), bounds_, 0, 0);
    depth_ = b.depth_reached;
    nodes_.shrink_to_fit();

    slots_.resize(leaf_refs.size());
    for (size_t k = 0; k < leaf_refs.size(); ++k) slots_[k] = surfels[leaf_refs[k]];
    slot_index_ = std::move(leaf_refs);
    slot_index_.shrink_to_fit();
    build_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

size_t KdTree::memory_bytes() const {
    return nodes_.size() * sizeof(KdNode) + slots_.size() * (sizeof(Surfel) + sizeof(uint32_t));
}

template <class Policy, class Stats>
void traverse(const KdTree &tree, const Ray &ray, bool cull, Policy &policy, Stats &stats) {
    const Vec3 inv_d{1.f / ray.d.x, 1.f / ray.d.y, 1.f / ray.d.z};
    // The ray's interval inside the scene's bounds (a NaN from 0 * inf keeps the old bound).
    float tmin = ray.tmin, tmax = policy.tfar();
    const Box &bb = tree.bounds();
    for (int k = 0; k < 3; ++k) {
        float a = (bb.lo[k] - ray.o[k]) * inv_d[k], b = (bb.hi[k] - ray.o[k]) * inv_d[k];
        if (a > b) std::swap(a, b);
        tmin = std::max(tmin, a);
        tmax = std::min(tmax, b);
    }
    if (!(tmin <= tmax)) return;

    struct Todo {
        uint32_t node;
        float tmin, tmax;
        uint32_t depth;
    };
    Todo stack[kKdStackSize];
    int sp = 0;
    const auto &nodes = tree.nodes();
    const auto &slots = tree.slots();
    uint32_t node = 0, depth = 0;
    for (;;) {
        // Front to back: once the search's far bound lies before this cell, it lies before
        // every cell still pending.
        if (policy.tfar() < tmin) return;
        const KdNode &nd = nodes[node];
        stats.node(depth);
        if (!nd.is_leaf()) {
            const uint32_t a = nd.axis();
            const float o = ray.o[a], d = ray.d[a];
            const bool below_first = o < nd.split || (o == nd.split && d <= 0.f);
            const uint32_t first = below_first ? node + 1 : nd.above();
            const uint32_t second = below_first ? nd.above() : node + 1;
            ++depth;
            const float tp = (nd.split - o) * inv_d[a];
            if (d == 0.f || tp > tmax || tp <= 0.f) {
                node = first;
            } else if (tp < tmin) {
                node = second;
            } else {
                stack[sp++] = {second, tp, tmax, depth};
                node = first;
                tmax = tp;
            }
            continue;
        }
        const uint32_t b = nd.first, e = nd.first + nd.count();
        uint32_t k = b;
#if defined(POINTVIZ_LEAF_SIMD)
        for (; k < e; k += 8) {  // eight disks at a time; the last group may be shorter
            const uint32_t cnt = std::min<uint32_t>(8u, e - k);
            LeafHits lh;
            intersect_leaf8(ray, &slots[k], cnt, policy.tfar(), cull, lh);
            for (uint32_t j = 0; j < cnt; ++j) stats.disk();
            for (uint32_t mk = lh.mask; mk != 0; mk &= mk - 1) {
                uint32_t j = uint32_t(__builtin_ctz(mk));
                if (policy.add({lh.t[j], lh.u2[j], lh.facing[j], slots[k + j].r, k + j})) return;
            }
        }
#endif
        for (; k < e; ++k) {
            const Surfel &s = slots[k];
            stats.disk();
            float facing;
            DiskHit h;
            if (!intersect_disk(ray, s.p, s.n, s.r, policy.tfar(), cull, facing, h)) continue;
            if (policy.add({h.t, h.u2, facing, s.r, k})) return;
        }
        if (sp == 0) return;
        const Todo &t = stack[--sp];
        node = t.node;
        tmin = t.tmin;
        tmax = t.tmax;
        depth = t.depth;
    }
}

template <class Stats>
bool closest_hit(const KdTree &tree, const Ray &ray, const TraceOptions &opt, SurfaceHit &out,
                 Stats &stats) {
    KdGather g(ray.tmax, opt.window, tree.slot_index().data());
    traverse(tree, ray, opt.cull, g, stats);
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
        // The hierarchy's weights (trace.h), with the same floor so a rim hit never vanishes.
        float w = opt.interp == Interpolation::Paper    ? std::sqrt(c.u2) * c.r
                  : opt.interp == Interpolation::Smooth ? (1.f - c.u2) * (1.f - c.u2)
                                                        : 1.f;
        w += 1e-6f;
        const Surfel &s = tree.slots()[c.ref];
        wsum += w;
        tsum += w * c.t;
        rsum += w * c.r;
        nsum += s.n * w;
        csum += Vec3{channel(s.rgba, 0), channel(s.rgba, 1), channel(s.rgba, 2)} * w;
        ++used;
    }
    out.t = tsum / wsum;
    out.n = normalize(nsum);
    if (!(length2(out.n) > 0.5f)) out.n = tree.slots()[best.ref].n;  // normals cancelled out
    out.color = csum / wsum;
    out.radius = rsum / wsum;
    out.index = int32_t(tree.slot_index()[best.ref]);  // input index (the tree keeps no order)
    out.count = used;
    return true;
}

template <class Stats>
bool any_hit(const KdTree &tree, const Ray &ray, const TraceOptions &opt, bool cull, Stats &stats) {
    detail::AnyHit a(ray.tmax);
    traverse(tree, ray, cull, a, stats);
    return a.hit;
}

void KdGeometry::intersect(const Ray *rays, size_t n, SurfaceHit *hits) const {
    for (size_t i = 0; i < n; ++i) {
        Ray r = rays[i];
        r.o += offset_;
        NoStats ns;
        closest_hit(*tree_, r, opt_, hits[i], ns);
    }
}

void KdGeometry::occluded(const Ray *rays, size_t n, uint8_t *hit) const {
    for (size_t i = 0; i < n; ++i) {
        Ray r = rays[i];
        r.o += offset_;
        NoStats ns;
        hit[i] = any_hit(*tree_, r, opt_, false, ns);
    }
}

// ---- batched queries ------------------------------------------------------------------------

namespace {

/// Directions outside this length range cannot be traced (the same bounds as cast.cpp).
constexpr double kMinDirection = 1e-30, kMaxDirection = 1e30;

/// World ray -> local unit ray; returns the direction's length, 0 for a ray that cannot be traced.
template <class T>
double kd_local_ray(const KdTree &tree, const T *r, Ray &ray) {
    const double *o = tree.origin();
    double v[6];
    bool finite = true;
    for (int k = 0; k < 6; ++k) {
        v[k] = double(r[k]);
        finite = finite && std::isfinite(v[k]);
    }
    const double len = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5]);
    if (!finite || !(len >= kMinDirection && len <= kMaxDirection)) return 0.0;
    ray.o = {float(v[0] - o[0]), float(v[1] - o[1]), float(v[2] - o[2])};
    ray.d = {float(v[3] / len), float(v[4] / len), float(v[5] / len)};
    return len;
}

/// Runs `per_ray(i, ray, len, local_stats)` over all rays on `threads` workers; counts bad rays.
template <class T, class PerRay>
void kd_batch(const KdTree &tree, const T *rays, size_t n, int threads, BatchStats &stats,
              PerRay &&per_ray) {
    std::mutex mu;
    parallel_for(n, 1024, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        for (size_t i = b; i < e; ++i) {
            Ray ray;
            const double len = kd_local_ray(tree, rays + 6 * i, ray);
            if (!per_ray(i, ray, len, local)) {
                ++local.invalid;
                local.first_invalid = std::min(local.first_invalid, i);
            }
        }
        local.rays = e - b;
        std::lock_guard<std::mutex> lock(mu);
        stats.add(local);
    });
}

/// `query(stats_hook)` with or without counting; counts go to `local`.
template <class Query>
bool kd_counted(bool count, BatchStats &local, Query &&query) {
    if (!count) {
        NoStats ns;
        return query(ns);
    }
    CountStats cs;
    const bool r = query(cs);
    local.nodes += cs.nodes;
    local.disks += cs.disks;
    local.depth_sum += cs.max_depth;
    local.max_depth = std::max(local.max_depth, cs.max_depth);
    return r;
}

}  // namespace

template <class T>
void cast_rays(const KdTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float /*pixel_angle*/, int threads, CastOutput out, bool count, BatchStats &stats) {
    kd_batch(tree, rays, n, threads, stats, [&](size_t i, Ray &ray, double len, BatchStats &local) {
        SurfaceHit h;
        const bool ok = len != 0.0;
        const bool hit = ok && kd_counted(count, local, [&](auto &st) {
                             return closest_hit(tree, ray, opt, h, st);
                         });
        local.hits += hit;
        const double s = hit ? double(h.t) / len : double(kInf);
        if (out.t) out.t[i] = float(s);
        for (int k = 0; k < 3; ++k) {
            if (out.normal) out.normal[3 * i + k] = hit ? h.n[k] : 0.f;
            if (out.color) out.color[3 * i + k] = hit ? h.color[k] : 0.f;
            if (out.position)
                out.position[3 * i + k] =
                    hit ? double(rays[6 * i + k]) + double(rays[6 * i + 3 + k]) * s : double(kInf);
        }
        if (out.radius) out.radius[i] = hit ? h.radius : 0.f;
        if (out.index) out.index[i] = h.index;
        if (out.count) out.count[i] = uint8_t(h.count);
        return ok;
    });
}

template <class T>
void occluded(const KdTree &tree, const T *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float /*pixel_angle*/, int threads,
              uint8_t *hit, bool count, BatchStats &stats) {
    kd_batch(tree, rays, n, threads, stats, [&](size_t i, Ray &ray, double len, BatchStats &local) {
        hit[i] = 0;
        if (len == 0.0 || std::isnan(t_max[i])) return false;
        ray.tmin = float(double(t_min) * len);
        ray.tmax = float(double(t_max[i]) * len);
        hit[i] = kd_counted(count, local, [&](auto &st) { return any_hit(tree, ray, opt, false, st); });
        local.hits += hit[i];
        return true;
    });
}

template bool closest_hit<NoStats>(const KdTree &, const Ray &, const TraceOptions &,
                                  SurfaceHit &, NoStats &);
template bool closest_hit<CountStats>(const KdTree &, const Ray &, const TraceOptions &,
                                     SurfaceHit &, CountStats &);
template bool any_hit<NoStats>(const KdTree &, const Ray &, const TraceOptions &, bool, NoStats &);
template bool any_hit<CountStats>(const KdTree &, const Ray &, const TraceOptions &, bool,
                                  CountStats &);
template void cast_rays<float>(const KdTree &, const float *, size_t, const TraceOptions &, float,
                               int, CastOutput, bool, BatchStats &);
template void cast_rays<double>(const KdTree &, const double *, size_t, const TraceOptions &, float,
                                int, CastOutput, bool, BatchStats &);
template void occluded<float>(const KdTree &, const float *, const float *, size_t,
                              const TraceOptions &, float, float, int, uint8_t *, bool, BatchStats &);
template void occluded<double>(const KdTree &, const double *, const float *, size_t,
                               const TraceOptions &, float, float, int, uint8_t *, bool,
                               BatchStats &);

}  // namespace pointviz
