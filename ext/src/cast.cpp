// pointviz — the batched ray queries of one instruction set. This file is compiled once per
// instruction set (ext/CMakeLists.txt: POINTVIZ_ISA_NS names the inline namespace of its
// kernels, isa.h; POINTVIZ_KERNELS the function returning its table); dispatch.cpp picks one
// at run time and holds the public cast_rays / occluded.
#include <cmath>
#include <mutex>

#include "pointviz/cast_rows.h"
#include "pointviz/dispatch.h"
#include "pointviz/packet_cast.h"
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

template <class T>
void cast_batch(const SurfelTree &tree, const T *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, bool count, BatchStats &stats) {
    std::mutex m;
    const LodGates gates = lod_gates(opt);
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
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
    for (size_t i = 0; i < n; ++i) {
        Ray r = rays[i];
        r.o += offset;
        NoStats ns;
        closest_hit(tree, r, opt, gates, hits[i], ns);
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
                                &POINTVIZ_ISA_NS::cast_packets<float>,
                                &POINTVIZ_ISA_NS::cast_packets<double>,
                                &POINTVIZ_ISA_NS::occluded_packets<float>,
                                &POINTVIZ_ISA_NS::occluded_packets<double>,
                                &POINTVIZ_ISA_NS::intersect_local,
                                &POINTVIZ_ISA_NS::occlude_local};
    return k;
}

}  // namespace pointviz
