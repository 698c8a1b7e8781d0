// pointviz — the rows of a batch query (cast.h): world rays in, local rays to the traversal,
// hits back out in the caller's units, and the per-thread sums. Shared by the single-ray kernels
// (ext/src/cast.cpp) and the packet kernels (ext/src/packet_cast.cpp).
#pragma once

#include <algorithm>
#include <cmath>
#include <mutex>

#include "pointviz/cast.h"
#include "pointviz/isa.h"
#include "pointviz/trace.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN
// Internal linkage, as when these lived in cast.cpp alone: each kernel unit gets its own copy,
// and cast.cpp's single-ray loop compiles exactly as before (an inline function with external
// linkage is inlined by other rules).
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
    into.add(s);
}

// Unused by the any-hit units (ext/src/packet_occlude.cpp).
[[maybe_unused]] void write_hit(const CastOutput &out, size_t i, bool hit, const SurfaceHit &h, double len,
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

}  // namespace
POINTVIZ_ISA_END
}  // namespace pointviz
