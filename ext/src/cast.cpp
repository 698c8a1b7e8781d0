// pointviz — batched ray queries.
#include "pointviz/cast.h"

#include <cmath>
#include <mutex>

#include "pointviz/parallel.h"

namespace pointviz {
namespace {

/// Rays handled per claimed chunk: large enough to amortise scheduling, small enough to balance.
constexpr size_t kRayGrain = 1024;

/// World ray i -> local unit ray; returns the caller's direction length.
inline float local_ray(const SurfelTree &tree, const double *r, Ray &ray) {
    const double *o = tree.origin();
    double dx = r[3], dy = r[4], dz = r[5];
    double len = std::sqrt(dx * dx + dy * dy + dz * dz);
    ray.o = {float(r[0] - o[0]), float(r[1] - o[1]), float(r[2] - o[2])};
    ray.d = {float(dx / len), float(dy / len), float(dz / len)};
    return float(len);
}

void merge(BatchStats *into, const BatchStats &s, std::mutex &m) {
    if (!into) return;
    std::lock_guard<std::mutex> lock(m);
    into->nodes += s.nodes;
    into->disks += s.disks;
    into->depth_sum += s.depth_sum;
    into->hits += s.hits;
    into->rays += s.rays;
    into->max_depth = std::max(into->max_depth, s.max_depth);
}

}  // namespace

void cast_rays(const SurfelTree &tree, const double *rays, size_t n, const TraceOptions &opt,
               float pixel_angle, int threads, CastOutput out, BatchStats *stats) {
    std::mutex m;
    const auto &order = tree.order();
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        for (size_t i = b; i < e; ++i) {
            Ray ray;
            float len = local_ray(tree, rays + 6 * i, ray);
            ray.spread = pixel_angle;
            SurfaceHit h;
            bool hit;
            if (stats) {
                CountStats cs;
                hit = closest_hit(tree, ray, opt, h, cs);
                local.nodes += cs.nodes;
                local.disks += cs.disks;
                local.depth_sum += cs.max_depth;
                local.max_depth = std::max(local.max_depth, cs.max_depth);
            } else {
                NoStats ns;
                hit = closest_hit(tree, ray, opt, h, ns);
            }
            local.hits += hit;
            if (out.t) out.t[i] = hit ? h.t / len : kInf;
            if (out.normal) {
                out.normal[3 * i] = hit ? h.n.x : 0.f;
                out.normal[3 * i + 1] = hit ? h.n.y : 0.f;
                out.normal[3 * i + 2] = hit ? h.n.z : 0.f;
            }
            if (out.color) {
                out.color[3 * i] = hit ? h.color.x : 0.f;
                out.color[3 * i + 1] = hit ? h.color.y : 0.f;
                out.color[3 * i + 2] = hit ? h.color.z : 0.f;
            }
            if (out.radius) out.radius[i] = hit ? h.radius : 0.f;
            if (out.index) out.index[i] = h.index >= 0 ? int32_t(order[size_t(h.index)]) : h.index;
            if (out.count) out.count[i] = uint8_t(h.count);
        }
        local.rays = e - b;
        merge(stats, local, m);
    });
}

void occluded(const SurfelTree &tree, const double *rays, const float *t_max, size_t n,
              const TraceOptions &opt, float t_min, float pixel_angle, int threads, uint8_t *hit,
              BatchStats *stats) {
    std::mutex m;
    parallel_for(n, kRayGrain, threads, [&](size_t b, size_t e, int) {
        BatchStats local;
        for (size_t i = b; i < e; ++i) {
            Ray ray;
            float len = local_ray(tree, rays + 6 * i, ray);
            ray.tmin = t_min * len;
            ray.tmax = t_max[i] * len;
            ray.spread = pixel_angle;
            bool h;
            if (stats) {
                CountStats cs;
                h = any_hit(tree, ray, opt, false, cs);
                local.nodes += cs.nodes;
                local.disks += cs.disks;
                local.depth_sum += cs.max_depth;
                local.max_depth = std::max(local.max_depth, cs.max_depth);
            } else {
                NoStats ns;
                h = any_hit(tree, ray, opt, false, ns);
            }
            hit[i] = h;
            local.hits += h;
        }
        local.rays = e - b;
        merge(stats, local, m);
    });
}

}  // namespace pointviz
