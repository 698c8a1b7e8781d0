// pointviz — the ray–disk test: one kernel for one disk (float lanes) and for eight disks at a
// time (F8 lanes, simd.h). Closest-hit and any-hit queries share it (trace.h, leaf_simd.h,
// kdtree.cpp); they differ only in what their policy does with the disks it reports. Scalar
// and SIMD lanes run the same operations in the same order, so with floating-point contraction
// off (the build's -ffp-contract=off) they agree bit for bit.
#pragma once

#include <cstdint>

#include "pointviz/isa.h"
#include "pointviz/simd.h"
#include "pointviz/surfel.h"

namespace pointviz {
POINTVIZ_ISA_BEGIN

/// Oriented-disk test of one ray against the disks in lanes V (float: one disk). Writes each
/// lane's t (on the disk's plane), (distance from the centre / radius)^2 and facing =
/// dot(d, n), and returns the lanes that hit (a mask; a bool for float): not (nearly) parallel
/// (|facing| >= kParallelCos), t in [ray.tmin, tmax], inside the radius, and with `cull`,
/// facing the ray (facing <= 0). NaN in any quantity is a miss (ordered comparisons).
template <class V>
inline auto disk_lanes(V px, V py, V pz, V r, V nx, V ny, V nz, const Ray &ray, float tmax,
                       bool cull, V &t, V &u2, V &facing) {
    const V ox(ray.o.x), oy(ray.o.y), oz(ray.o.z);
    const V dx(ray.d.x), dy(ray.d.y), dz(ray.d.z);
    facing = dx * nx + dy * ny + dz * nz;
    const V pox = px - ox, poy = py - oy, poz = pz - oz;
    t = (pox * nx + poy * ny + poz * nz) / facing;
    const V qx = (ox + dx * t) - px, qy = (oy + dy * t) - py, qz = (oz + dz * t) - pz;
    u2 = (qx * qx + qy * qy + qz * qz) / (r * r);
    auto ok = (vabs(facing) >= V(kParallelCos)) & (t >= V(ray.tmin)) & (t <= V(tmax)) &
              (u2 <= V(1.f));
    if (cull) ok = ok & (facing <= V(0.f));
    return ok;
}

/// One disk (centre p, unit normal n, radius r): whether the ray hits it within
/// [ray.tmin, tmax]; `facing` and `hit` as disk_lanes writes them.
inline bool intersect_disk(const Ray &ray, Vec3 p, Vec3 n, float r, float tmax, bool cull,
                           float &facing, DiskHit &hit) {
    float t, u2;
    if (!disk_lanes<float>(p.x, p.y, p.z, r, n.x, n.y, n.z, ray, tmax, cull, t, u2, facing))
        return false;
    hit = {t, u2};
    return true;
}

POINTVIZ_ISA_END
}  // namespace pointviz
