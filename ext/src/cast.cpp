// pointviz — the batched ray queries of one instruction set. This file is compiled once per
// instruction set (ext/CMakeLists.txt: POINTVIZ_ISA_NS names the inline namespace of its
// kernels, isa.h; POINTVIZ_KERNELS the function returning its table); dispatch.cpp picks one
// at run time and holds the public cast_rays / occluded.
#include <cmath>
#include <mutex>

#include "pointviz/dispatch.h"
#include "pointviz/packet_trace.h"
#include "pointviz/parallel.h"
#include "pointviz/trace.h"
#include "pointviz/wide_trace.h"

#ifndef POINTVIZ_KERNELS
#define POINTVIZ_KERNELS kernels_base
#define POINTVIZ_KERNELS_ISA Isa::Base
#define POINTVIZ_KERNELS_NAME "base"
#endif

namespace pointviz {
POINTVIZ_ISA_BEGIN
namespace {

/// Rays handled per claimed chunk: large enough to amortise scheduling, small enough to balance.
constexpr size_t kRayGrain = 1024;

/// Directions shorter or longer than this cannot be traced: t in the caller's units would
/// leave float range (1e-30 * 1e30 = 1, so the bounds are symmetric around unit length).
constexpr double kMinDirection = 1e-30, kMaxDirection = 1e30;

/// World ray -> local unit ray. Returns the caller's direction length, or 0 for a ray that
/// cannot be traced (NaN/inf anywhere, or a zero or out-of-range direction).
template <class T>
inline double local_ray(const SurfelTree &tree, const T *r, Ray &ray) {
    const double *o = tree.origin();
    double v[6];
    bool finite = true;
    for (int k = 0; k < 6; ++k) {
        v[k] = double(r[k]);
        finite = finite && std::isfinite(v[k]);
    }
    double len = std::sqrt(v[3] * v[3] + v[4] * v[4] + v[5] * v[5]);
    if (!finite || !(len >= kMinDirection && len <= kMaxDirection)) return 0.0;
    ray.o = {float(v[0] - o[0]), float(v[1] - o[1]), float(v[2] - o[2])};
    ray.d = {float(v[3] / len), float(v[4] / len), float(v[5] / len)};
    return len;
}

void merge(BatchStats &into, const BatchStats &s, std::mutex &m) {
    std::lock_guard<std::mutex> lock(m);
    into.nodes += s.nodes;
    into.disks += s.disks;
    into.depth_sum += s.depth_sum;
    into.hits += s.hits;
    into.rays += s.rays;
    into.invalid += s.invalid;
    into.first_invalid = std::min(into.first_invalid, s.first_invalid);
    into.max_depth = std::max(into.max_depth, s.max_depth);
}

/// Runs `query(stats_hook)` with counting on or off, adding the counts to `local`.
template <class Query>
bool counted(bool count, BatchStats &local, Query &&query) {
    if (!count) {
        NoStats ns;
        return query(ns);
    }
    CountStats cs;
    bool r = query(cs);
    local.nodes += cs.nodes;
    local.disks += cs.disks;
    local.depth_sum += cs.max_depth;
    local.max_depth = std::max(local.max_depth, cs.max_depth);
    return r;
}

void write_hit(const CastOutput &out, size_t i, bool hit, const SurfaceHit &h, double len,
               const double *rd, const SurfelTree &tree) {
    const float inf = kInf;
    if (out.t) out.t[i] = hit ? float(double(h.t) / len) : inf;
    for (int k = 0; k < 3; ++k) {
        if (out.normal) out.normal[3 * i + k] = hit ? h.n[k] : 0.f;
        if (out.color) out.color[3 * i + k] = hit ? h.color[k] : 0.f;
        // world position in double: origin + t * direction, t in the caller's units
        if (out.position) out.position[3 * i + k] = hit ? rd[k] + rd[3 + k] * (double(h.t) / len) : inf;
    }
    if (out.radius) out.radius[i] = hit ? h.radius : 0.f;
    if (out.index) out.index[i] = h.index >= 0 ? int32_t(tree.order()[size_t(h.index)]) : h.index;
    if (out.count) out.count[i] = uint8_t(h.count);
}

/// Closest hits of rays [b, e) in groups of kPacket: the groups packet_covers traverse as
/// packets, the others one ray at a time (no statistics). Out of line: the single-ray loop of
/// cast_batch keeps the compiler's inlining of its own traversal.
template <class T>
__attribute__((noinline)) void cast_packets(const SurfelTree &tree, const T *rays, size_t b, size_t e,
                                            const TraceOptions &opt, const LodGates &gates,
                                            float pixel_angle, const CastOutput &out,
                                            BatchStats &local) {
    for (size_t g = b; g < e; g += kPacket) {
        const int k = int(std::min(e - g, size_t(kPacket)));
        Ray ray[kPacket];
        double len[kPacket];
        bool valid = true;
        for (int r = 0; r < k; ++r) {
            len[r] = local_ray(tree, rays + 6 * (g + size_t(r)), ray[r]);
            ray[r].spread = pixel_angle;
            valid = valid && len[r] != 0.0;
        }
        SurfaceHit h[kPacket];
        const bool packet = valid && packet_covers(tree, ray, k, opt);
        if (packet) closest_hits_packet(tree, ray, k, opt, gates, h);
        for (int r = 0; r < k; ++r) {
            const size_t i = g + size_t(r);
            double rd[6];
            for (int c = 0; c < 6; ++c) rd[c] = double(rays[6 * i + c]);
            bool hit = false;
            if (len[r] == 0.0) {
                ++local.invalid;
                local.first_invalid = std::min(local.first_invalid, i);
            } else if (packet) {
                hit = h[r].t != kInf;
            } else {
                NoStats ns;
                hit = closest_hit(tree, ray[r], opt, gates, h[r], ns);
            }
            local.hits += hit;
            write_hit(out, i, hit, h[r], len[r], rd, tree);
        }
    }
}

template <class T>
void cast_batch(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats) {
    std::mutex m;
    const LodGates gates = lod_gates(opt);
    // Coherent groups of rays go through the packet traversal (packet_trace.h) when it covers
    // them: no statistics, the wide traversal.
    const bool packets = opt.packets && !count && use_wide(tree, opt);
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        if (packets) {
            cast_packets(tree, rays, b, e, opt, gates, pixel_angle, out, local);
            local.rays = e - b;
            merge(stats, local, m);
            return;
        }
        for (size_t i = b; i < e; ++i) {
            Ray ray;
            double len = local_ray(tree, rays + 6 * i, ray);
            double rd[6];
            for (int k = 0; k < 6; ++k) rd[k] = double(rays[6 * i + k]);
            SurfaceHit h;
            bool hit = false;
            if (len == 0.0) {
                ++local.invalid;
                local.first_invalid = std::min(local.first_invalid, i);
            } else {
                ray.spread = pixel_angle;
                hit = counted(count, local, [&](auto &st) { return closest_hit(tree, ray, opt, gates, h, st); });
            }
            local.hits += hit;
            write_hit(out, i, hit, h, len, rd, tree);
        }
        local.rays = e - b;
        merge(stats, local, m);
    });
}

template <class T>
void occluded_batch(const SurfelTree &tree, const T *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float pixel_angle, int threads, uint8_t *hit,
              bool count, BatchStats &stats) {
    std::mutex m;
    const LodGates gates = lod_gates(opt);
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        for (size_t i = b; i < e; ++i) {
            Ray ray;
            double len = local_ray(tree, rays + 6 * i, ray);
            hit[i] = 0;
            if (len == 0.0 || std::isnan(t_max[i])) {
                ++local.invalid;
                local.first_invalid = std::min(local.first_invalid, i);
                continue;
            }
            ray.tmin = float(double(t_min) * len);
            ray.tmax = float(double(t_max[i]) * len);
            ray.spread = pixel_angle;
            bool h = counted(count, local, [&](auto &st) { return any_hit(tree, ray, opt, gates, false, st); });
            hit[i] = h;
            local.hits += h;
        }
        local.rays = e - b;
        merge(stats, local, m);
    });
}

/// Closest hits of local rays shifted by `offset` (the renderer's batches).
void intersect_local(const SurfelTree &tree, const Ray *rays, size_t n, Vec3 offset,
                     const TraceOptions &opt, SurfaceHit *hits) {
    const LodGates gates = lod_gates(opt);
    const bool packets = opt.packets && use_wide(tree, opt);
    for (size_t g = 0; g < n; g += kPacket) {
        const int k = int(std::min(n - g, size_t(kPacket)));
        Ray r[kPacket];
        for (int j = 0; j < k; ++j) {
            r[j] = rays[g + size_t(j)];
            r[j].o += offset;
        }
        if (packets && packet_covers(tree, r, k, opt)) {
            closest_hits_packet(tree, r, k, opt, gates, hits + g);
            continue;
        }
        for (int j = 0; j < k; ++j) {
            NoStats ns;
            closest_hit(tree, r[j], opt, gates, hits[g + size_t(j)], ns);
        }
    }
}

/// Any hits of local rays shifted by `offset`, two-sided (shadow rays).
void occlude_local(const SurfelTree &tree, const Ray *rays, size_t n, Vec3 offset,
                   const TraceOptions &opt, uint8_t *hit) {
    const LodGates gates = lod_gates(opt);
    for (size_t i = 0; i < n; ++i) {
        Ray r = rays[i];
        r.o += offset;
        NoStats ns;
        hit[i] = any_hit(tree, r, opt, gates, false, ns);
    }
}

}  // namespace
POINTVIZ_ISA_END

const QueryKernels &POINTVIZ_KERNELS() {
    static const QueryKernels k{POINTVIZ_KERNELS_ISA, POINTVIZ_KERNELS_NAME,
                                &POINTVIZ_ISA_NS::cast_batch<float>,
                                &POINTVIZ_ISA_NS::cast_batch<double>,
                                &POINTVIZ_ISA_NS::occluded_batch<float>,
                                &POINTVIZ_ISA_NS::occluded_batch<double>,
                                &POINTVIZ_ISA_NS::intersect_local,
                                &POINTVIZ_ISA_NS::occlude_local};
    return k;
}

}  // namespace pointviz
