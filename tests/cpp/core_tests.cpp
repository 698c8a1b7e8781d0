// pointviz — tests of the C++ core on its own (no Python), run under ASan + UBSan by
// `make sanitize`. Every accelerated query is checked against a brute-force oracle over all
// surfels in double precision; edge cases (one surfel, duplicates, a line, a plane, huge and tiny
// coordinates, rays parallel to disks, NaN directions) must give correct answers or clean misses.
//
// Random cases are seeded by their index; a failure prints the case name and index to replay it.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "pointviz/cast.h"
#include "pointviz/dispatch.h"
#include "pointviz/geometry.h"
#include "pointviz/render.h"
#include "pointviz/shading_lanes.h"
#include "pointviz/shading_math.h"
#include "pointviz/tree.h"
#include "check.h"

using namespace pointviz;

namespace {


/// The batch queries, whichever of the core's two signatures is present (statistics as a
/// pointer, or as a flag plus a reference): the tests survive that interface change.
template <class Tree>
auto cast_impl(int, const Tree &t, const double *r, size_t n, const TraceOptions &o, float pa,
               int th, CastOutput out, BatchStats *st)
    -> decltype(cast_rays(t, r, n, o, pa, th, out, true, *st), void()) {
    BatchStats local;
    cast_rays(t, r, n, o, pa, th, out, st != nullptr, st ? *st : local);
}
template <class Tree>
auto cast_impl(long, const Tree &t, const double *r, size_t n, const TraceOptions &o, float pa,
               int th, CastOutput out, BatchStats *st)
    -> decltype(cast_rays(t, r, n, o, pa, th, out, st), void()) {
    cast_rays(t, r, n, o, pa, th, out, st);
}
void cast(const SurfelTree &t, const double *r, size_t n, const TraceOptions &o, float pa, int th,
          CastOutput out, BatchStats *st) {
    cast_impl(0, t, r, n, o, pa, th, out, st);
}
template <class Tree>
auto occ_impl(int, const Tree &t, const double *r, const float *tm, size_t n,
              const TraceOptions &o, float tmin, float pa, int th, uint8_t *hit, BatchStats *st)
    -> decltype(occluded(t, r, tm, n, o, tmin, pa, th, hit, true, *st), void()) {
    BatchStats local;
    occluded(t, r, tm, n, o, tmin, pa, th, hit, st != nullptr, st ? *st : local);
}
template <class Tree>
auto occ_impl(long, const Tree &t, const double *r, const float *tm, size_t n,
              const TraceOptions &o, float tmin, float pa, int th, uint8_t *hit, BatchStats *st)
    -> decltype(occluded(t, r, tm, n, o, tmin, pa, th, hit, st), void()) {
    occluded(t, r, tm, n, o, tmin, pa, th, hit, st);
}
void any_hits(const SurfelTree &t, const double *r, const float *tm, size_t n, const TraceOptions &o,
         float tmin, float pa, int th, uint8_t *hit, BatchStats *st) {
    occ_impl(0, t, r, tm, n, o, tmin, pa, th, hit, st);
}

/// A cloud in world coordinates (double positions, as the Python layer hands them over).
struct Cloud {
    std::vector<double> p;   // (n, 3)
    std::vector<float> n;    // (n, 3) unit
    std::vector<float> r;    // (n,)
    std::vector<float> c;    // (n, 3)
    size_t size() const { return r.size(); }
    void add(double x, double y, double z, float nx, float ny, float nz, float rad) {
        p.insert(p.end(), {x, y, z});
        float l = std::sqrt(nx * nx + ny * ny + nz * nz);
        if (l > 0.f) { nx /= l; ny /= l; nz /= l; }
        n.insert(n.end(), {nx, ny, nz});
        r.push_back(rad);
        c.insert(c.end(), {0.5f, 0.25f, 1.f});
    }
};

/// The tree, built around the cloud's bounding-box centre like SurfelScene does.
std::unique_ptr<SurfelTree> build(const Cloud &cl, uint32_t leaf = 8, uint32_t box_depth = 0,
                                  int threads = 2) {
    double lo[3], hi[3];
    for (int k = 0; k < 3; ++k) {
        lo[k] = std::numeric_limits<double>::infinity();
        hi[k] = -lo[k];
    }
    for (size_t i = 0; i < cl.size(); ++i)
        for (int k = 0; k < 3; ++k) {
            lo[k] = std::min(lo[k], cl.p[3 * i + k]);
            hi[k] = std::max(hi[k], cl.p[3 * i + k]);
        }
    double origin[3] = {0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])};
    SurfelArrays a;
    a.points = cl.p.data();
    a.normals = cl.n.data();
    a.radii = cl.r.data();
    a.colors = cl.c.data();
    a.n = cl.size();
    BuildOptions bo;
    bo.leaf_size = leaf;
    bo.box_depth = box_depth;
    bo.threads = threads;
    return std::make_unique<SurfelTree>(a, origin, bo);
}

/// Exact options: nearest disk only, no LoD, no culling (what the brute force computes).
TraceOptions exact_options(uint32_t box_depth) {
    TraceOptions o;
    o.lod = false;
    o.cull = false;
    o.interp = Interpolation::None;
    o.box_depth = box_depth;
    return o;
}

/// Brute-force nearest disk in double precision. A disk counts as "certain" when the hit lies
/// well inside its rim and "possible" when within a rim tolerance: float32 rounding may decide
/// either way near a rim, so the tree must agree with the certain hit or find a possible one.
struct Oracle {
    double t_certain = INFINITY, t_possible = INFINITY;
};

Oracle brute(const Cloud &cl, const double *ray, double tmax = INFINITY) {
    const double kRim = 1e-3;   // relative rim band where float rounding may go either way
    const double kPar = 1e-4;   // |cos| below which a hit is numerically unstable
    Oracle o;
    double dl = std::sqrt(ray[3] * ray[3] + ray[4] * ray[4] + ray[5] * ray[5]);
    double d[3] = {ray[3] / dl, ray[4] / dl, ray[5] / dl};
    for (size_t i = 0; i < cl.size(); ++i) {
        const double *p = &cl.p[3 * i];
        double nn[3] = {cl.n[3 * i], cl.n[3 * i + 1], cl.n[3 * i + 2]};
        double facing = d[0] * nn[0] + d[1] * nn[1] + d[2] * nn[2];
        if (std::fabs(facing) < 1e-6) continue;
        double t = ((p[0] - ray[0]) * nn[0] + (p[1] - ray[1]) * nn[1] + (p[2] - ray[2]) * nn[2]) / facing;
        if (t < 0 || t > tmax) continue;
        double q2 = 0;
        for (int k = 0; k < 3; ++k) {
            double q = ray[k] + d[k] * t - p[k];
            q2 += q * q;
        }
        double u2 = q2 / (double(cl.r[i]) * cl.r[i]);
        bool stable = std::fabs(facing) > kPar;
        if (u2 <= 1.0 - kRim && stable) o.t_certain = std::min(o.t_certain, t / dl);
        if (u2 <= 1.0 + kRim) o.t_possible = std::min(o.t_possible, t / dl);
    }
    return o;
}

/// Casts `rays` with the exact options and compares with the brute force. `tol` is the allowed
/// error on t, in units of the ray direction.
void check_against_brute(const char *name, const Cloud &cl, const SurfelTree &tree,
                         const std::vector<double> &rays, uint32_t box_depth, double tol) {
    const size_t n = rays.size() / 6;
    std::vector<float> t(n), nrm(3 * n), col(3 * n), rad(n);
    std::vector<int32_t> idx(n);
    std::vector<uint8_t> cnt(n), occ(n);
    CastOutput out{t.data(), nrm.data(), col.data(), rad.data(), idx.data(), cnt.data()};
    BatchStats st;
    cast(tree, rays.data(), n, exact_options(box_depth), 0.f, 2, out, &st);
    CHECK(st.rays == n, "%s: stats counted %zu rays of %zu", name, size_t(st.rays), n);
    std::vector<float> tmax(n, 1e30f);
    any_hits(tree, rays.data(), tmax.data(), n, exact_options(box_depth), 0.f, 0.f, 2, occ.data(),
             nullptr);
    for (size_t i = 0; i < n; ++i) {
        Oracle o = brute(cl, &rays[6 * i]);
        const double ti = t[i];
        CHECK(!std::isnan(ti) && ti >= 0.0, "%s[%zu]: t = %g", name, i, ti);
        if (std::isinf(ti)) {
            CHECK(std::isinf(o.t_certain), "%s[%zu]: tree missed, brute force hits at %.9g", name, i,
                  o.t_certain);
            CHECK(idx[i] == -1, "%s[%zu]: miss with index %d", name, i, idx[i]);
            continue;
        }
        CHECK(idx[i] >= 0 && size_t(idx[i]) < cl.size(), "%s[%zu]: index %d", name, i, idx[i]);
        CHECK(ti >= o.t_possible - tol && ti <= o.t_certain + tol,
              "%s[%zu]: t %.9g outside brute force [%.9g, %.9g]", name, i, ti, o.t_possible,
              o.t_certain);
        float nl = std::sqrt(nrm[3 * i] * nrm[3 * i] + nrm[3 * i + 1] * nrm[3 * i + 1] +
                             nrm[3 * i + 2] * nrm[3 * i + 2]);
        CHECK(std::fabs(nl - 1.f) < 1e-3f, "%s[%zu]: |normal| = %g", name, i, nl);
        CHECK(rad[i] > 0.f && cnt[i] == 1, "%s[%zu]: radius %g count %d", name, i, rad[i], cnt[i]);
        for (int k = 0; k < 3; ++k) CHECK(col[3 * i + k] >= 0.f && col[3 * i + k] <= 1.f,
                                          "%s[%zu]: colour %g", name, i, col[3 * i + k]);
    }
    for (size_t i = 0; i < n; ++i) {
        Oracle o = brute(cl, &rays[6 * i], 1e30);
        if (std::isfinite(o.t_certain)) CHECK(occ[i], "%s[%zu]: occluded() missed a hit", name, i);
        if (std::isinf(o.t_possible)) CHECK(!occ[i], "%s[%zu]: occluded() found a phantom", name, i);
    }
}

/// Rays from random points on a sphere of radius `far` around `c` toward random points within
/// `spread` of `c`.
std::vector<double> random_rays(std::mt19937_64 &g, size_t n, const double c[3], double far,
                                double spread) {
    std::normal_distribution<double> N(0.0, 1.0);
    std::uniform_real_distribution<double> U(-1.0, 1.0);
    std::vector<double> rays;
    for (size_t i = 0; i < n; ++i) {
        double v[3] = {N(g), N(g), N(g)};
        double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        double o[3], tg[3];
        for (int k = 0; k < 3; ++k) {
            o[k] = c[k] + far * v[k] / l;
            tg[k] = c[k] + spread * U(g);
        }
        rays.insert(rays.end(), {o[0], o[1], o[2], tg[0] - o[0], tg[1] - o[1], tg[2] - o[2]});
    }
    return rays;
}

Cloud random_sphere_cloud(std::mt19937_64 &g, size_t n, double scale, const double off[3]) {
    std::normal_distribution<double> N(0.0, 1.0);
    std::uniform_real_distribution<float> U(0.05f, 0.3f);
    Cloud cl;
    for (size_t i = 0; i < n; ++i) {
        double v[3] = {N(g), N(g), N(g)};
        double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        // random normals, not the sphere's: disks at every orientation
        float nx = float(N(g)), ny = float(N(g)), nz = float(N(g));
        cl.add(off[0] + scale * v[0] / l, off[1] + scale * v[1] / l, off[2] + scale * v[2] / l, nx,
               ny, nz, float(scale) * U(g));
    }
    return cl;
}

// ------------------------------------------------------------------------------------------

void test_random_clouds_match_brute_force() {
    const double zero[3] = {0, 0, 0};
    const uint32_t leaves[] = {1, 8, 31};
    const uint32_t boxes[] = {0, 3, 255};
    for (int seed = 0; seed < 6; ++seed) {
        std::mt19937_64 g(1000 + seed);
        size_t n = seed < 3 ? 300 : 2000;
        Cloud cl = random_sphere_cloud(g, n, 1.0, zero);
        for (uint32_t leaf : leaves)
            for (uint32_t bd : boxes) {
                auto tree = build(cl, leaf, bd);
                CHECK(tree->surfels().size() == n, "seed %d: %zu surfels", seed, tree->surfels().size());
                auto rays = random_rays(g, 300, zero, 4.0, 1.2);
                std::string name = "random seed " + std::to_string(seed) + " leaf " +
                                   std::to_string(leaf) + " box " + std::to_string(bd);
                check_against_brute(name.c_str(), cl, *tree, rays, bd, 1e-4);
            }
    }
}

/// Every instruction set's kernels give the portable kernels' answers bit for bit: closest hits
/// (t, normal, colour, radius, index, count), any hits and the statistics, with level of detail,
/// culling, interpolation, boxes and slabs on and off, on random clouds (including leaves of 1,
/// 8 and 31 surfels: the eight-disk lanes with partial and several loads).
void test_every_isa_equals_base() {
    const double zero[3] = {0, 0, 0};
    const std::vector<Isa> isas = available_isas();
    CHECK(!isas.empty() && isas[0] == Isa::Base, "available_isas starts with base");
    std::printf("core_tests: kernels checked against base:");
    for (Isa isa : isas) std::printf(" %s", isa_name(isa));
    std::printf(" (best %s)\n", isa_name(best_isa()));
    for (int seed = 0; seed < 4; ++seed) {
        std::mt19937_64 g(7000 + seed);
        Cloud cl = random_sphere_cloud(g, seed < 2 ? 500 : 3000, 1.0, zero);
        for (uint32_t leaf : {1u, 8u, 31u}) {
            auto tree = build(cl, leaf, seed % 2 ? 4 : 0);
            auto rays = random_rays(g, 400, zero, 4.0, 1.2);
            const size_t n = rays.size() / 6;
            std::vector<float> tmax(n);
            for (size_t i = 0; i < n; ++i) tmax[i] = float(1.0 + 3.0 * double(i % 7) / 7.0);
            for (int variant = 0; variant < 4; ++variant) {
                TraceOptions o;
                o.lod = variant >= 2;
                o.cull = variant % 2 == 1;
                o.slabs = variant != 1;
                o.interp = variant == 0 ? Interpolation::None : Interpolation::Smooth;
                o.box_depth = seed % 2 ? 4 : 0;
                const float pa = o.lod ? 0.01f : 0.f;
                struct Result {
                    std::vector<float> t, nrm, col, rad;
                    std::vector<int32_t> idx;
                    std::vector<uint8_t> cnt, occ;
                    BatchStats cs, os;
                };
                auto run = [&](Isa isa) {
                    Result r;
                    r.t.resize(n); r.nrm.resize(3 * n); r.col.resize(3 * n); r.rad.resize(n);
                    r.idx.resize(n); r.cnt.resize(n); r.occ.resize(n);
                    TraceOptions oi = o;
                    oi.isa = isa;
                    CastOutput out{r.t.data(), r.nrm.data(), r.col.data(), r.rad.data(),
                                   r.idx.data(), r.cnt.data()};
                    cast(*tree, rays.data(), n, oi, pa, 2, out, &r.cs);
                    any_hits(*tree, rays.data(), tmax.data(), n, oi, 0.f, pa, 2, r.occ.data(), &r.os);
                    return r;
                };
                const Result base = run(Isa::Base);
                for (Isa isa : isas) {
                    if (isa == Isa::Base) continue;
                    const Result r = run(isa);
                    auto same = [](const auto &a, const auto &b) {
                        return a.size() == b.size() &&
                               std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
                    };
                    const bool ok = same(r.t, base.t) && same(r.nrm, base.nrm) &&
                                    same(r.col, base.col) && same(r.rad, base.rad) &&
                                    same(r.idx, base.idx) && same(r.cnt, base.cnt) &&
                                    same(r.occ, base.occ) && r.cs.nodes == base.cs.nodes &&
                                    r.cs.disks == base.cs.disks && r.cs.hits == base.cs.hits &&
                                    r.os.nodes == base.os.nodes && r.os.hits == base.os.hits;
                    CHECK(ok, "isa %s differs from base: seed %d leaf %u variant %d", isa_name(isa),
                          seed, leaf, variant);
                }
            }
        }
    }
    bool threw = false;
    try {
        TraceOptions o;
        o.isa = Isa(200);
        query_kernels(o.isa);
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    CHECK(threw, "an unknown instruction set is refused");
}

void test_one_surfel() {
    Cloud cl;
    cl.add(1.0, 2.0, 3.0, 0, 0, 1, 0.5f);
    auto tree = build(cl, 8, 255);
    CHECK(tree->nodes().size() == 1 && tree->depth() == 1, "one surfel: %zu nodes, depth %u",
          tree->nodes().size(), tree->depth());
    std::vector<double> rays = {
        1.0, 2.0, 10.0, 0, 0, -1,     // through the centre, from the front
        1.0, 2.0, -10.0, 0, 0, 2,     // from the back, direction of length 2
        1.49, 2.0, 10.0, 0, 0, -1,    // just inside the rim
        1.51, 2.0, 10.0, 0, 0, -1,    // just outside the rim
        -5.0, 2.0, 3.0, 1, 0, 0,      // in the disk's plane: parallel, must miss
        -5.0, 2.0, 3.0001, 1, 0, 0,   // parallel just above
        1.0, 2.0, 3.0, 0, 0, 1,       // starting on the disk
    };
    check_against_brute("one surfel", cl, *tree, rays, 255, 1e-5);
    std::vector<float> t(7);
    CastOutput out;
    out.t = t.data();
    cast(*tree, rays.data(), 7, exact_options(255), 0.f, 1, out, nullptr);
    CHECK(std::fabs(t[0] - 7.f) < 1e-5f, "front hit t = %g", t[0]);
    CHECK(std::fabs(t[1] - 6.5f) < 1e-5f, "back hit t = %g (direction length 2)", t[1]);
    CHECK(std::isinf(t[3]) && std::isinf(t[4]) && std::isinf(t[5]), "misses: %g %g %g", t[3], t[4], t[5]);
}

void test_duplicates() {
    Cloud cl;
    for (int i = 0; i < 2000; ++i) cl.add(0.5, 0.5, 0.5, 0, 1, 0, 0.25f);
    for (uint32_t leaf : {1u, 8u}) {
        auto tree = build(cl, leaf, 4);
        // The median split keeps the depth logarithmic even when every centre coincides.
        CHECK(tree->depth() <= 14, "duplicates leaf %u: depth %u", leaf, tree->depth());
        std::mt19937_64 g(7);
        const double c[3] = {0.5, 0.5, 0.5};
        auto rays = random_rays(g, 200, c, 3.0, 0.3);
        check_against_brute("duplicates", cl, *tree, rays, 4, 1e-5);
    }
}

void test_line_and_plane() {
    Cloud line;
    for (int i = 0; i < 1000; ++i) line.add(0.01 * i, 0.0, 0.0, 0, 0, 1, 0.008f);
    auto lt = build(line, 8, 3);
    std::mt19937_64 g(11);
    const double lc[3] = {5.0, 0.0, 0.0};
    auto rays = random_rays(g, 400, lc, 8.0, 5.0);
    check_against_brute("line", line, *lt, rays, 3, 1e-4);

    Cloud plane;
    for (int i = 0; i < 60; ++i)
        for (int j = 0; j < 60; ++j) plane.add(0.1 * i, 0.1 * j, 2.0, 0, 0, 1, 0.075f);
    auto pt = build(plane, 8, 255);
    const double pc[3] = {3.0, 3.0, 2.0};
    rays = random_rays(g, 400, pc, 6.0, 3.0);
    check_against_brute("plane", plane, *pt, rays, 255, 1e-4);
    // Grazing and parallel rays over the plane: no NaN, and parallel rays in the plane miss.
    std::vector<double> graze;
    for (int k = 0; k < 100; ++k) {
        double e = std::pow(10.0, -double(k % 10));   // elevation from 1 down to 1e-9
        graze.insert(graze.end(), {-1.0, 3.0 + 0.01 * k, 2.0 + e, 1.0, 0.0, -e * 0.1});
    }
    graze.insert(graze.end(), {-1.0, 3.0, 2.0, 1.0, 0.0, 0.0});  // exactly in the plane
    check_against_brute("grazing", plane, *pt, graze, 255, 1e-3);
}

void test_offset_precision() {
    // Georeferenced coordinates: 1e7 from the world origin. The tree works relative to the
    // cloud's centre, so hits keep sub-millimetre accuracy on a unit-sized object.
    const double off[3] = {1.0e7, -2.0e7, 3.0e7};
    std::mt19937_64 g(21);
    Cloud cl = random_sphere_cloud(g, 1500, 1.0, off);
    auto tree = build(cl, 8, 255);
    auto rays = random_rays(g, 400, off, 4.0, 1.0);
    check_against_brute("offset 1e7", cl, *tree, rays, 255, 1e-4);
}

void test_scales() {
    const double zero[3] = {0, 0, 0};
    // Large and small, yet within float32's comfortable range (squares stay finite and normal).
    for (double scale : {1e-12, 1e-6, 1e6, 1e15}) {
        std::mt19937_64 g(31);
        Cloud cl = random_sphere_cloud(g, 800, scale, zero);
        auto tree = build(cl, 8, 3);
        auto rays = random_rays(g, 300, zero, 4.0 * scale, 1.2 * scale);
        std::string name = "scale " + std::to_string(scale);
        // t is in units of the ray direction (length ~ 4 x scale): the tolerance is relative.
        check_against_brute(name.c_str(), cl, *tree, rays, 3, 1e-5);
    }
    // Extreme scales: answers may be wrong (squares under- or overflow float32) but must be
    // clean: no NaN, t >= 0 or inf, valid indices, and no sanitizer report.
    for (double scale : {1e-30, 1e25, 1e300}) {
        std::mt19937_64 g(41);
        Cloud cl = random_sphere_cloud(g, 300, scale, zero);
        auto tree = build(cl, 8, 3);
        auto rays = random_rays(g, 200, zero, 4.0 * scale, 1.2 * scale);
        const size_t n = rays.size() / 6;
        std::vector<float> t(n);
        std::vector<int32_t> idx(n);
        CastOutput out;
        out.t = t.data();
        out.index = idx.data();
        cast(*tree, rays.data(), n, exact_options(3), 0.f, 2, out, nullptr);
        for (size_t i = 0; i < n; ++i) {
            CHECK(!std::isnan(t[i]) && t[i] >= 0.f, "extreme scale %g [%zu]: t %g", scale, i, t[i]);
            CHECK(idx[i] >= -1 && idx[i] < int32_t(cl.size()), "extreme scale %g: index %d", scale, idx[i]);
        }
    }
}

void test_degenerate_rays_and_surfels() {
    std::mt19937_64 g(51);
    const double zero[3] = {0, 0, 0};
    Cloud cl = random_sphere_cloud(g, 500, 1.0, zero);
    // A zero normal and a zero radius: such surfels can never be hit (the Python layer rejects
    // them, the core must still not misbehave).
    cl.add(0.0, 0.0, 0.0, 0, 0, 0, 0.5f);
    cl.add(0.0, 0.0, 0.0, 0, 0, 1, 0.0f);
    auto tree = build(cl, 8, 3);
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    std::vector<double> rays = {
        0, 0, 5, 0, 0, 0,        // zero direction: NaN after normalisation
        0, 0, 5, nan, 0, -1,     // NaN direction
        nan, 0, 5, 0, 0, -1,     // NaN origin
        0, 0, inf, 0, 0, -1,     // infinite origin
        0, 0, 5, 0, 0, -inf,     // infinite direction
        0, 0, 5, 0, 0, -1e-40,   // denormal direction
        0, 0, 5, 0, 0, -1,       // a normal ray, for contrast
    };
    const size_t n = rays.size() / 6;
    std::vector<float> t(n), nrm(3 * n), col(3 * n), rad(n), tmax(n, 100.f);
    std::vector<int32_t> idx(n);
    std::vector<uint8_t> cnt(n), occ(n);
    for (auto interp : {Interpolation::None, Interpolation::Paper, Interpolation::Smooth}) {
        TraceOptions o;
        o.interp = interp;
        o.box_depth = 3;
        CastOutput out{t.data(), nrm.data(), col.data(), rad.data(), idx.data(), cnt.data()};
        BatchStats st;
        cast(*tree, rays.data(), n, o, 0.002f, 2, out, &st);
        any_hits(*tree, rays.data(), tmax.data(), n, o, 0.f, 0.002f, 2, occ.data(), &st);
        for (size_t i = 0; i + 1 < n; ++i)
            CHECK(std::isinf(t[i]) || (t[i] >= 0.f && !std::isnan(t[i])), "degenerate ray %zu: t %g", i, t[i]);
        CHECK(std::isinf(t[0]) && std::isinf(t[1]) && std::isinf(t[2]),
              "NaN rays must miss: %g %g %g", t[0], t[1], t[2]);
        CHECK(std::isfinite(t[n - 1]) && idx[n - 1] >= 0, "normal ray: t %g index %d", t[n - 1], idx[n - 1]);
        CHECK(idx[n - 1] < 500, "the zero-normal / zero-radius surfels were hit: %d", idx[n - 1]);
    }
}

void test_lod_and_interpolation_are_clean() {
    // With LoD, culling and interpolation on, hits may differ from the nearest disk, but every
    // output stays finite, unit and within the cloud's extent.
    std::mt19937_64 g(61);
    const double zero[3] = {0, 0, 0};
    Cloud cl = random_sphere_cloud(g, 3000, 1.0, zero);
    auto tree = build(cl, 8, 4);
    auto rays = random_rays(g, 500, zero, 5.0, 1.0);
    const size_t n = rays.size() / 6;
    std::vector<float> t(n), nrm(3 * n), col(3 * n), rad(n);
    std::vector<int32_t> idx(n);
    std::vector<uint8_t> cnt(n);
    for (auto crit : {LodCriterion::Size, LodCriterion::Deviation})
        for (auto interp : {Interpolation::Paper, Interpolation::Smooth}) {
            TraceOptions o;
            o.lod_criterion = crit;
            o.interp = interp;
            o.box_depth = 4;
            o.lod_pixels = 4.f;
            CastOutput out{t.data(), nrm.data(), col.data(), rad.data(), idx.data(), cnt.data()};
            cast(*tree, rays.data(), n, o, 0.01f, 2, out, nullptr);
            for (size_t i = 0; i < n; ++i) {
                if (std::isinf(t[i])) continue;
                CHECK(t[i] >= 0.f && t[i] < 2.f, "lod [%zu]: t %g", i, t[i]);
                float nl = std::sqrt(nrm[3 * i] * nrm[3 * i] + nrm[3 * i + 1] * nrm[3 * i + 1] +
                                     nrm[3 * i + 2] * nrm[3 * i + 2]);
                CHECK(std::fabs(nl - 1.f) < 1e-3f, "lod [%zu]: |n| %g", i, nl);
                CHECK(idx[i] >= -2 && idx[i] < int32_t(cl.size()) && cnt[i] >= 1, "lod [%zu]: index %d", i, idx[i]);
            }
        }
}

void test_lod_budget() {
    // The byte in the radius: the stored radius still bounds, the byte reads back.
    for (float r : {0.f, 1e-30f, 1e-7f, 0.37f, 1.f, 3.9e5f, 1e30f})
        for (uint32_t b : {0u, 1u, 17u, 255u}) {
            Node nd{};
            nd.radius = radius_with_byte(r, b);
            CHECK(nd.radius >= r && nd.radius <= r * (1.f + 1e-4f) + 1e-37f,
                  "radius_with_byte(%g, %u) = %g", r, b, nd.radius);
            float want = (float(b) / 255.f) * (float(b) / 255.f) * kColourSpreadMax;
            CHECK(nd.colour_spread() == want, "byte %u reads %g", b, nd.colour_spread());
        }
    for (float r : {std::numeric_limits<float>::infinity(), std::nanf("")}) {
        float out = radius_with_byte(r, 7);
        CHECK(std::isinf(r) ? out == r : std::isnan(out), "non-finite radius %g -> %g", r, out);
    }
    // Quantised colour spread never below the truth, within one step above it.
    for (float c = 0.f; c <= 1.f; c += 0.0013f) {
        uint32_t q = quantize_colour_spread(c);
        float back = (float(q) / 255.f) * (float(q) / 255.f);
        float step = (float(q + 1) / 255.f) * (float(q + 1) / 255.f) - back;
        CHECK(q <= 255 && back >= c * (1.f - 1e-6f) && back - c <= step + 1e-6f,
              "colour spread %g -> q %u -> %g", c, q, back);
    }
    CHECK(quantize_colour_spread(std::nanf("")) == 0 && quantize_colour_spread(-1.f) == 0 &&
          quantize_colour_spread(1e9f) == 255, "colour spread: bad inputs");

    // Tree nodes: colour spread bounds the brute-force RMS colour deviation of each subtree.
    std::mt19937_64 g(67);
    const double zero[3] = {0, 0, 0};
    Cloud cl = random_sphere_cloud(g, 2000, 1.0, zero);
    std::uniform_real_distribution<float> u01(0.f, 1.f);
    for (size_t i = 0; i < cl.size(); ++i)  // half the sphere grey, half random colours
        for (int k = 0; k < 3; ++k) cl.c[3 * i + k] = cl.p[3 * i] > 0 ? 0.5f : u01(g);
    auto tree = build(cl, 8, 4);
    const auto &nodes = tree->nodes();
    const auto &surfels = tree->surfels();
    // subtree ranges, bottom-up (children after parents)
    std::vector<uint32_t> lo(nodes.size()), hi(nodes.size());
    for (size_t i = nodes.size(); i-- > 0;) {
        const Node &nd = nodes[i];
        if (nd.is_leaf()) lo[i] = nd.index(), hi[i] = nd.index() + nd.count();
        else lo[i] = lo[nd.index()], hi[i] = hi[nd.index() + 1];
    }
    size_t grey = 0;
    for (size_t i = 0; i < nodes.size(); ++i) {
        double m[3] = {0, 0, 0}, ss = 0;
        const double cnt = double(hi[i] - lo[i]);
        for (uint32_t k = lo[i]; k < hi[i]; ++k)
            for (int c = 0; c < 3; ++c) m[c] += channel(surfels[k].rgba, c) / cnt;
        for (uint32_t k = lo[i]; k < hi[i]; ++k)
            for (int c = 0; c < 3; ++c) ss += std::pow(channel(surfels[k].rgba, c) - m[c], 2) / cnt;
        const double rms = std::sqrt(ss);
        CHECK(nodes[i].colour_spread() >= rms * (1 - 1e-4) - 1e-6,
              "node %zu: colour spread %g below the subtree's %g", i, nodes[i].colour_spread(), rms);
        if (rms < 1e-6) {
            ++grey;
            CHECK(nodes[i].colour_spread() < 1e-4f, "grey node %zu: %g", i, nodes[i].colour_spread());
        }
        float rmax = 0.f;
        for (uint32_t k = lo[i]; k < hi[i]; ++k)
            rmax = std::max(rmax, length(surfels[k].p - nodes[i].c) + surfels[k].r);
        CHECK(nodes[i].radius >= rmax, "node %zu: radius %g below %g", i, nodes[i].radius, rmax);
    }
    CHECK(grey > 0, "no uniformly coloured node in the test tree");

    // The budget (max_error minus the floor): max_error 0 never stops; a flat grey node within the extent stops; too wide never.
    Node flat{};
    flat.radius = radius_with_byte(1.f, 0);
    flat.cone_q = uint16_t(std::ceil(kConeSlack * kConeScale));
    CHECK(!budget_allows(flat, 1.f, -kBudgetFloor, 1.f), "budget 0 stopped a node");
    CHECK(budget_allows(flat, 1.f, 0.005f - kBudgetFloor, 0.f), "budget 0.005 refused a flat grey node");
    CHECK(!budget_allows(flat, 2.f / (kBudgetMaxExtent * 1.01f), 1.f - kBudgetFloor, 0.f), "stopped beyond the extent");
    Node striped = flat;
    striped.radius = radius_with_byte(1.f, 60);
    CHECK(!budget_allows(striped, 10.f, 0.005f - kBudgetFloor, 1.f), "colour-spread node stopped by the size share");
    // The colour term's response: a node within a footprint whose colour term exceeds the
    // budget by less than 1 / kColourPixelResponse stops (by the size share); wider than a
    // footprint it does not; with a response of 1 it never does.
    {
        const float term = colour_term(striped.colour_spread());
        const float budget = 0.5f * (kColourPixelResponse * term + term);   // between the two
        CHECK(kColourPixelResponse < 1.f && budget < term, "test needs a response below 1");
        CHECK(budget_allows(striped, 2.01f, budget, 1.f), "sub-footprint node refused within its response");
        CHECK(!budget_allows(striped, 1.9f, budget, 1.f), "node wider than a footprint took the response");
        CHECK(!budget_allows(striped, 2.01f, budget, 1.f, 1.f), "response 1 stopped an over-budget node");
        CHECK(colour_response(2.f, 2.f, 0.5f) == 0.5f && colour_response(2.1f, 2.f, 0.5f) == 1.f &&
                  colour_response(1.f, 2.f, 3.f) == 1.f, "colour_response");
    }

    // The per-ray gate (LodGate) against budget_allows over every colour byte and a sweep of
    // cone values: a node it refuses is never allowed at any footprint (it is a necessary
    // condition), and its bounds are tight (the first value past each bound fails the term it
    // stands for).
    for (float e : {0.f, 0.002f, 0.005f, 0.01f, 0.08f, 1.f, 3.f}) {
        for (float share : {0.f, 1.f}) {
            const float budget = e - kBudgetFloor;
            const LodGate gate = budget_gate(budget, share);
            if (gate.colour_max < 255)
                CHECK(colour_term(Node::decode_colour_spread(uint32_t(gate.colour_max + 1))) *
                              std::min(1.f, kColourPixelResponse) > budget,
                      "E %g: colour bound %d not tight", e, gate.colour_max);
            if (share == 0.f && gate.cone_max < int32_t(kConeNeverQ) - 1)
                CHECK(spread_term(Node::decode_cone(uint32_t(gate.cone_max + 1))) > budget,
                      "E %g: cone bound %d not tight", e, gate.cone_max);
            for (uint32_t byte = 0; byte < 256; byte += 5) {
                for (uint32_t cq = 0; cq <= kConeNeverQ; cq += (cq < 2000 ? 7 : 997)) {
                    Node nd = flat;
                    nd.radius = radius_with_byte(0.5f, byte);
                    nd.cone_q = uint16_t(std::min<uint32_t>(cq, kConeNeverQ));
                    if (!nd.has_cone() || gate.passes(nd)) continue;
                    for (float fp : {0.01f, 1.f, 100.f})
                        CHECK(!budget_allows(nd, fp, budget, share),
                              "E %g share %g: gate refused byte %u cone %u that the budget allows", e,
                              share, byte, cq);
                }
            }
        }
    }
    Node wide = flat;
    wide.cone_q = kConeNeverQ;
    CHECK(!LodGate{}.passes(wide), "the open gate let a node without a cone through");

    // The visibility model (shadow and sky rays): no colour term, never within the clearance
    // of the ray's origin, never beyond the extent, never with max_error 0; its gate is a
    // necessary condition and tight.
    {
        const float budget = 0.005f - kBudgetFloor, w = kShadowFlipWeight;
        const float far2 = std::pow((2.f + kVisibilityClearance) * 1.f, 2.f);
        const float near2 = std::pow((1.f + kVisibilityClearance) * 0.99f, 2.f);
        CHECK(visibility_allows(striped, 1.f, far2, budget, w), "a flat striped node refused a shadow ray");
        CHECK(!visibility_allows(flat, 1.f, near2, budget, w), "stopped within the clearance");
        CHECK(!visibility_allows(flat, 2.f / (kBudgetMaxExtent * 1.01f), far2, budget, w),
              "visibility: stopped beyond the extent");
        CHECK(!visibility_allows(flat, 1.f, far2, -kBudgetFloor, w), "visibility: budget 0 stopped");
        for (float e : {0.f, 0.002f, 0.005f, 0.01f, 1.f})
            for (float wt : {kShadowFlipWeight, kSkyFlipWeight, 0.f}) {
                const float b = e - kBudgetFloor;
                const LodGate gate = visibility_gate(b, wt);
                CHECK(gate.colour_max == 255, "visibility gate bounds the colour");
                if (gate.cone_max < int32_t(kConeNeverQ) - 1)
                    CHECK(flip_term(wt, Node::decode_cone(uint32_t(gate.cone_max + 1))) > b,
                          "E %g w %g: visibility cone bound %d not tight", e, wt, gate.cone_max);
                for (uint32_t cq = 0; cq < kConeNeverQ; cq += (cq < 4000 ? 3 : 401)) {
                    Node nd = flat;
                    nd.cone_q = uint16_t(cq);
                    if (gate.passes(nd)) continue;
                    for (float fp : {0.01f, 1.f, 100.f})
                        CHECK(!visibility_allows(nd, fp, 1e6f, b, wt),
                              "E %g w %g: gate refused cone %u the model allows", e, wt, cq);
                }
            }
    }

    // Rays through the budget traversal stay clean (finite, unit normals, in range); with
    // max_error 0 they equal full detail exactly.
    auto rays = random_rays(g, 400, zero, 5.0, 1.0);
    const size_t n = rays.size() / 6;
    std::vector<float> t(n), nrm(3 * n), col(3 * n), rad(n), t0(n), nrm0(3 * n), col0(3 * n), rad0(n);
    std::vector<int32_t> idx(n), idx0(n);
    std::vector<uint8_t> cnt(n), cnt0(n);
    TraceOptions full;
    full.lod = false;
    CastOutput out0{t0.data(), nrm0.data(), col0.data(), rad0.data(), idx0.data(), cnt0.data()};
    cast(*tree, rays.data(), n, full, 0.01f, 2, out0, nullptr);
    for (float e : {0.f, 0.005f, 0.05f}) {
        TraceOptions o;
        o.lod_criterion = LodCriterion::Budget;
        o.max_error = e;
        o.lod_pixels = e > 0.f ? 1.f : 0.f;  // what pointviz.surfels gives the size share
        CastOutput out{t.data(), nrm.data(), col.data(), rad.data(), idx.data(), cnt.data()};
        cast(*tree, rays.data(), n, o, 0.05f, 2, out, nullptr);
        for (size_t i = 0; i < n; ++i) {
            if (e == 0.f) {
                CHECK((std::isinf(t[i]) && std::isinf(t0[i])) || (t[i] == t0[i] && idx[i] == idx0[i]),
                      "budget 0 [%zu]: t %g vs %g", i, t[i], t0[i]);
                continue;
            }
            if (std::isinf(t[i])) continue;
            float nl = std::sqrt(nrm[3 * i] * nrm[3 * i] + nrm[3 * i + 1] * nrm[3 * i + 1] +
                                 nrm[3 * i + 2] * nrm[3 * i + 2]);
            CHECK(t[i] >= 0.f && t[i] < 10.f && std::fabs(nl - 1.f) < 1e-3f &&
                  idx[i] >= -2 && idx[i] < int32_t(cl.size()), "budget %g [%zu]: t %g |n| %g", e, i,
                  t[i], nl);
        }
    }
}

/// A geometry that cancels the render from inside its first query: the cancel lands while
/// every worker is mid-tile (what Ctrl-C does), deterministically.
class CancellingGeometry final : public Geometry {
public:
    CancellingGeometry(std::shared_ptr<const Geometry> inner, Progress &p) : inner_(std::move(inner)), p_(p) {}
    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override {
        p_.cancel = true;
        inner_->intersect(rays, n, hits);
    }
    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override { inner_->occluded(rays, n, hit); }

private:
    std::shared_ptr<const Geometry> inner_;
    Progress &p_;
};

/// Cancelled in the middle: every worker finishes its tile and stops, the call returns false
/// with all its threads joined (ASan checks that nothing touches freed buffers afterwards).
void test_render_cancelled_midway(RenderScene scene, CameraModel cam, RenderSettings set) {
    cam.width = 160;   // 10 x 8 tiles: far more than workers
    cam.height = 128;
    const auto plain = scene.objects[0].geometry;
    for (int threads : {1, 2, 4}) {
        set.threads = threads;
        Progress p;
        scene.objects[0].geometry = std::make_shared<CancellingGeometry>(plain, p);
        auto fb = std::make_unique<FrameBuffers>();
        RenderStats st;
        CHECK(!render(scene, cam, set, *fb, st, p), "threads %d: a render cancelled midway reported success", threads);
        CHECK(p.done <= uint64_t(threads) && p.done < p.total, "threads %d: %llu of %llu tiles after the cancel",
              threads, (unsigned long long)p.done.load(), (unsigned long long)p.total.load());
        fb.reset();  // the buffers go while nothing may use them any more
    }
}

/// The same geometry without bounds: the renderer must query it with every ray.
class BoundlessGeometry final : public Geometry {
public:
    explicit BoundlessGeometry(std::shared_ptr<const Geometry> inner) : inner_(std::move(inner)) {}
    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override { inner_->intersect(rays, n, hits); }
    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override { inner_->occluded(rays, n, hit); }

private:
    std::shared_ptr<const Geometry> inner_;
};

/// Rays the renderer does not trace because they cannot reach an object's bounds (camera,
/// shadow and reflection rays that miss its sphere; sky-visibility rays that start farther than
/// their length from every object, which are not even sampled) change no bit of the frame:
/// the oracle is the same scene with the bounds hidden, where every ray is traced. Neither do
/// tiles written as background without a ray (RenderSettings::background_shortcut; with the
/// bounds hidden no tile can be proven to show only background): `background` says whether
/// the view has such tiles, and the frame is also compared with the shortcut turned off.
void test_render_skips_match_boundless(RenderScene scene, CameraModel cam, RenderSettings set,
                                       bool background = false) {
    for (int spp : {1, 3}) {
        set.spp = spp;
        FrameBuffers direct, boundless, traced;
        RenderStats sd, sb, st;
        Progress pd, pb, pt;
        CHECK(render(scene, cam, set, direct, sd, pd), "spp %d: render cancelled", spp);
        RenderScene hidden = scene;
        for (auto &o : hidden.objects) o.geometry = std::make_shared<BoundlessGeometry>(o.geometry);
        CHECK(render(hidden, cam, set, boundless, sb, pb), "spp %d: render cancelled", spp);
        RenderSettings no_shortcut = set;
        no_shortcut.background_shortcut = false;
        CHECK(render(scene, cam, no_shortcut, traced, st, pt), "spp %d: render cancelled", spp);
        CHECK(sb.background == 0 && st.background == 0 && (sd.background > 0) == background,
              "spp %d: background samples %llu (bounds hidden %llu, shortcut off %llu)", spp,
              (unsigned long long)sd.background.load(), (unsigned long long)sb.background.load(),
              (unsigned long long)st.background.load());
        CHECK(direct.color == traced.color && direct.depth == traced.depth && direct.normal == traced.normal &&
                  direct.alpha == traced.alpha && direct.albedo == traced.albedo &&
                  direct.object_alpha == traced.object_alpha,
              "spp %d: the tiles written as background changed the frame", spp);
        CHECK(sd.shadow == sb.shadow && sd.shadow_traced < sb.shadow_traced && sd.primary_traced < sb.primary_traced,
              "spp %d: shadow rays %llu / %llu traced %llu / %llu, camera rays traced %llu / %llu: nothing skipped", spp,
              (unsigned long long)sd.shadow.load(), (unsigned long long)sb.shadow.load(),
              (unsigned long long)sd.shadow_traced.load(), (unsigned long long)sb.shadow_traced.load(),
              (unsigned long long)sd.primary_traced.load(), (unsigned long long)sb.primary_traced.load());
        const auto same = [](const std::vector<float> &a, const std::vector<float> &b) {
            return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
        };
        CHECK(same(direct.color, boundless.color) && same(direct.depth, boundless.depth) &&
                  same(direct.normal, boundless.normal) && same(direct.alpha, boundless.alpha) &&
                  same(direct.albedo, boundless.albedo) && same(direct.object_alpha, boundless.object_alpha),
              "spp %d: skipping rays that cannot reach an object changed the frame", spp);
    }
}

/// The ground's samples shaded in lanes (RenderSettings::simd_lanes, shading_lanes.h) give
/// the frame the scalar path gives, bit for bit: the oracle is the same render with the lanes
/// off. Ground kinds (matte; glossy; mirror; a shininess that is not a whole number, whose lobe
/// goes through std::pow), the fade and the sky-visibility rays on and off, 1 and 3 samples;
/// the scene's lights are of every type (directional soft and hard, point, area).
void test_render_simd_lanes(RenderScene scene, CameraModel cam, RenderSettings set) {
    struct Kind {
        const char *name;
        float mirror, roughness, shininess;
    };
    const Kind kinds[] = {{"matte", 0.f, 0.f, 48.f}, {"glossy", 0.3f, 0.2f, 48.f},
                          {"mirror", 0.8f, 0.f, 48.f}, {"matte, shininess 47.5", 0.f, 0.f, 47.5f}};
    const auto same = [](const FrameBuffers &a, const FrameBuffers &b) {
        const auto eq = [](const std::vector<float> &x, const std::vector<float> &y) {
            return x.size() == y.size() && std::memcmp(x.data(), y.data(), x.size() * sizeof(float)) == 0;
        };
        return eq(a.color, b.color) && eq(a.depth, b.depth) && eq(a.normal, b.normal) && eq(a.alpha, b.alpha) &&
               eq(a.albedo, b.albedo) && eq(a.object_alpha, b.object_alpha);
    };
    for (const Kind &k : kinds)
        for (float fade : {scene.sky.ground_fade, 0.f})
            for (float occlusion : {scene.sky.occlusion_distance, 0.f})
                for (int spp : {1, 3}) {
                    RenderScene sc = scene;
                    sc.ground_material.mirror = k.mirror;
                    sc.ground_material.roughness = k.roughness;
                    sc.ground_material.shininess = k.shininess;
                    sc.sky.ground_fade = fade;
                    sc.sky.occlusion_distance = occlusion;
                    RenderSettings on = set, off = set;
                    on.spp = off.spp = spp;
                    off.simd_lanes = false;
                    FrameBuffers a, b;
                    RenderStats sa, sb;
                    Progress pa, pb;
                    CHECK(render(sc, cam, on, a, sa, pa) && render(sc, cam, off, b, sb, pb), "render cancelled");
                    size_t ground = 0;   // pixels that see the ground
                    for (size_t i = 0; i < a.alpha.size(); ++i) ground += a.alpha[i] > a.object_alpha[i];
                    CHECK(ground > 0, "%s: no ground in view", k.name);
                    CHECK(same(a, b), "%s, fade %g, occlusion %g, spp %d, %dx%d: the lanes changed the frame",
                          k.name, fade, occlusion, spp, cam.width, cam.height);
                }
}

/// A scene with two surfel objects, a ground, lights of every type.
void test_render() {
    std::mt19937_64 g(71);
    const double zero[3] = {0, 0, 0};
    Cloud sphere = random_sphere_cloud(g, 2000, 1.0, zero);
    for (size_t i = 0; i < sphere.size(); ++i)   // outward normals for a sensible picture
        for (int k = 0; k < 3; ++k) sphere.n[3 * i + k] = float(sphere.p[3 * i + k]);
    Cloud one;
    one.add(2.0, 0.0, 0.0, 0, 0, 1, 0.5f);
    auto t1 = build(sphere, 8, 4);
    auto t2 = build(one, 8, 4);
    TraceOptions o;
    o.box_depth = 4;
    RenderScene scene;
    RenderScene::Object a, b;
    a.geometry = std::make_shared<SurfelGeometry>(t1.get(), o, Vec3{0, 0, 0});
    b.geometry = std::make_shared<SurfelGeometry>(t2.get(), o, Vec3{-2.f, 0, 0});
    b.material.mirror = 0.5f;
    b.material.roughness = 0.2f;
    scene.objects = {a, b};
    scene.ground = true;
    scene.ground_point = {0, -1.f, 0};
    scene.ground_material.mirror = 0.3f;
    scene.ground_material.checker = {0.2f, 0.2f, 0.2f};
    scene.ground_material.checker_size = 0.5f;
    Light sun;
    sun.direction = normalize(Vec3{0.3f, 1.f, 0.2f});
    sun.angle = 0.05f;
    Light pt;
    pt.type = LightType::Point;
    pt.position = {0, 3, 3};
    pt.radius = 0.2f;
    Light area;
    area.type = LightType::Area;
    area.position = {-1, 3, 0};
    area.edge_u = {1, 0, 0};
    area.edge_v = {0, 0, 1};
    Light fill;   // shadowless
    fill.direction = normalize(Vec3{-1.f, 0.3f, 0.5f});
    fill.cast_shadows = false;
    scene.lights = {sun, pt, area, fill};
    scene.scale = 2.f;
    scene.sky.occlusion_distance = 0.8f;   // sky-visibility rays
    scene.sky.ground_fade = 3.f;           // studio backdrop
    scene.sky.background_is_sky = false;
    CameraModel cam;
    cam.eye = {0, 0.5f, 5};
    cam.forward = normalize(Vec3{0, -0.1f, -1});
    cam.right = normalize(cross(cam.forward, Vec3{0, 1, 0}));
    cam.up = cross(cam.right, cam.forward);
    cam.width = 37;   // not a multiple of the tile size
    cam.height = 23;
    RenderSettings set;
    set.spp = 3;
    set.reflections = 2;
    FrameBuffers fb1, fb2;
    RenderStats s1, s2;
    Progress p1, p2;
    set.threads = 1;
    bool ok1 = render(scene, cam, set, fb1, s1, p1);
    set.threads = 2;
    bool ok2 = render(scene, cam, set, fb2, s2, p2);
    CHECK(ok1 && ok2, "render returned cancelled");
    CHECK(fb1.color == fb2.color && fb1.alpha == fb2.alpha, "render depends on thread count");
    size_t hit = 0;
    for (size_t i = 0; i < fb1.alpha.size(); ++i) {
        CHECK(fb1.alpha[i] >= 0.f && fb1.alpha[i] <= 1.f, "alpha %g", fb1.alpha[i]);
        hit += fb1.alpha[i] > 0.f;
        CHECK(fb1.alpha[i] == 0.f ? std::isinf(fb1.depth[i]) : fb1.depth[i] > 0.f, "depth %g alpha %g",
              fb1.depth[i], fb1.alpha[i]);
    }
    for (float v : fb1.color) CHECK(std::isfinite(v) && v >= 0.f, "colour %g", v);
    for (float v : fb1.normal) CHECK(std::isfinite(v), "normal %g", v);
    CHECK(fb1.albedo.size() == fb1.color.size() && fb1.albedo == fb2.albedo, "albedo buffer");
    for (float v : fb1.albedo) CHECK(v >= 0.f && v <= 1.f, "albedo %g", v);
    for (size_t i = 0; i < fb1.alpha.size(); ++i)
        CHECK(fb1.object_alpha[i] >= 0.f && fb1.object_alpha[i] <= fb1.alpha[i], "object alpha %g of %g",
              fb1.object_alpha[i], fb1.alpha[i]);
    CHECK(hit > fb1.alpha.size() / 4, "only %zu of %zu pixels hit", hit, fb1.alpha.size());
    CHECK(s1.tiles_done == s1.tiles_total, "tiles %llu of %llu", (unsigned long long)s1.tiles_done.load(),
          (unsigned long long)s1.tiles_total);
    CHECK(p1.done == s1.tiles_total && p1.total == s1.tiles_total, "progress %llu of %llu",
          (unsigned long long)p1.done.load(), (unsigned long long)p1.total.load());
    // Cancelled before the start: returns false, touches no tile.
    Progress cancelled;
    cancelled.cancel = true;
    FrameBuffers fb3;
    RenderStats s3;
    CHECK(!render(scene, cam, set, fb3, s3, cancelled), "a cancelled render reported success");
    CHECK(s3.tiles_done == 0, "cancelled render did %llu tiles", (unsigned long long)s3.tiles_done.load());
    test_render_cancelled_midway(scene, cam, set);
    test_render_simd_lanes(scene, cam, set);   // 37x23: widths off the lanes' step
    cam.width = 64;   // the ground far from the objects in view: sky-visibility rays skipped
    cam.height = 48;
    cam.eye = {0, 3.f, 9};
    cam.forward = normalize(Vec3{0, -0.45f, -1});
    cam.right = normalize(cross(cam.forward, Vec3{0, 1, 0}));
    cam.up = cross(cam.right, cam.forward);
    test_render_skips_match_boundless(scene, cam, set, false);
    test_render_simd_lanes(scene, cam, set);
    cam.eye = {1.f, 4.f, 40};   // far: most tiles show only the faded ground and the sky
    cam.forward = normalize(Vec3{0, -0.1f, -1});
    cam.right = normalize(cross(cam.forward, Vec3{0, 1, 0}));
    cam.up = cross(cam.right, cam.forward);
    test_render_skips_match_boundless(scene, cam, set, true);
    test_render_simd_lanes(scene, cam, set);   // the far view: the fade's edge
    RenderScene sky_scene = scene;   // the sky behind the faded ground: its colour per sample
    sky_scene.sky.background_is_sky = true;
    test_render_skips_match_boundless(sky_scene, cam, set, true);
    // A 1x1 frame and a camera inside the sphere.
    cam.width = cam.height = 1;
    cam.eye = {0, 0, 0};
    FrameBuffers fb4;
    RenderStats s4;
    Progress p4;
    CHECK(render(scene, cam, set, fb4, s4, p4) && std::isfinite(fb4.color[0]), "1x1 render");
}

void test_empty_and_oversized_builds_throw() {
    SurfelArrays a;
    double origin[3] = {0, 0, 0};
    bool threw = false;
    try {
        SurfelTree t(a, origin, BuildOptions{});
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    CHECK(threw, "a tree of zero surfels did not throw invalid_argument");
    // One more surfel than a tree can index: refused before any input is read (the arrays
    // are null, so a read would crash under the sanitizers).
    SurfelArrays big;
    big.n = size_t(kMaxTreeSurfels);
    bool threw_big = false;
    try {
        SurfelTree t(big, origin, BuildOptions{});
    } catch (const std::length_error &) {
        threw_big = true;
    }
    CHECK(threw_big, "a tree of 2^27 surfels did not throw length_error");
}

/// The staged build (inputs freed stage by stage) gives the one-call build's tree byte for byte,
/// reads each input only in its own stage, and refuses stages out of order.
void test_staged_build() {
    std::mt19937_64 g(77);
    const double zero[3] = {0, 0, 0};
    Cloud cl = random_sphere_cloud(g, 3000, 1.0, zero);
    const double origin[3] = {0.25, -0.5, 0.125};
    BuildOptions bo{5, 4, 2};
    SurfelArrays a{cl.p.data(), cl.n.data(), cl.r.data(), cl.c.data(), cl.size()};
    SurfelTree one(a, origin, bo);
    std::vector<double> points = cl.p;
    SurfelTreeBuild build(points.data(), cl.size(), origin, bo);
    CHECK(build.next_stage() == 2, "stage %d after the constructor", build.next_stage());
    bool threw = false;
    try {
        (void)build.finish();
    } catch (const std::logic_error &) {
        threw = true;
    }
    CHECK(threw, "finish() before add_surfels() did not throw logic_error");
    std::vector<double>().swap(points);  // positions are not read after stage 1 (ASan would see it)
    std::vector<float> normals = cl.n, radii = cl.r, colors = cl.c;
    build.add_surfels(normals.data(), radii.data(), colors.data());
    std::vector<float>().swap(normals);
    std::vector<float>().swap(radii);
    std::vector<float>().swap(colors);
    SurfelTree staged = build.finish();
    CHECK(build.next_stage() == 4, "stage %d after finish()", build.next_stage());
    CHECK(staged.surfels().size() == one.surfels().size() &&
              std::memcmp(staged.surfels().data(), one.surfels().data(),
                          one.surfels().size() * sizeof(Surfel)) == 0,
          "staged surfels differ");
    CHECK(staged.nodes().size() == one.nodes().size() &&
              std::memcmp(staged.nodes().data(), one.nodes().data(), one.nodes().size() * sizeof(Node)) == 0,
          "staged nodes differ");
    CHECK(staged.boxes().size() == one.boxes().size() &&
              std::memcmp(staged.boxes().data(), one.boxes().data(), one.boxes().size() * sizeof(Box)) == 0,
          "staged boxes differ");
    CHECK(staged.order() == one.order() && staged.level_start() == one.level_start() &&
              staged.box_depth() == one.box_depth() && staged.memory_bytes() == one.memory_bytes(),
          "staged order, levels or box depth differ");
    threw = false;
    try {
        (void)build.finish();
    } catch (const std::logic_error &) {
        threw = true;
    }
    CHECK(threw, "a second finish() did not throw logic_error");
}

}  // namespace


/// The shading's sine, cosine and lobe power (shading_math.h) against double precision: the
/// cosine and sine of 2 pi u within 3e-7 on a grid of 2^20 turns' fractions and the largest
/// floats below 1, quarter turns and their neighbours; x^e within e ulp (relative), or 1e-36
/// where the power underflows, for whole exponents, and std::pow's value for the others.
void test_shading_math() {
    double worst = 0.0;
    auto check_turn = [&](float u) {
        float c, s;
        turn_sincos(u, c, s);
        const double a = 2.0 * 3.14159265358979323846 * double(u);
        const double ec = std::fabs(double(c) - std::cos(a)), es = std::fabs(double(s) - std::sin(a));
        worst = std::max({worst, ec, es});
        CHECK(ec <= 3e-7 && es <= 3e-7, "turn_sincos(%.9g) = (%.9g, %.9g), errors %.3g %.3g", u, c, s, ec, es);
    };
    for (int i = 0; i < (1 << 20); ++i) check_turn(float(i) / float(1 << 20));
    for (float q : {0.125f, 0.25f, 0.375f, 0.5f, 0.625f, 0.75f, 0.875f, 1.f}) {
        float v = q;
        for (int k = 0; k < 64; ++k) {
            v = std::nextafter(v, 0.f);
            check_turn(v);
        }
        if (q < 1.f) {
            v = q;
            for (int k = 0; k < 64; ++k) {
                check_turn(v);
                v = std::nextafter(v, 1.f);
            }
        }
    }
    std::printf("turn_sincos: largest error %.3g\n", worst);
    for (float e : {1.f, 2.f, 3.f, 5.f, 7.f, 16.f, 48.f, 100.f, 1024.f}) {
        for (int i = 0; i <= 4096; ++i) {
            const float x = float(i) / 4096.f;
            const double ref = std::pow(double(x), double(e)), got = double(lobe_pow(x, e));
            const double tol = std::max(double(e) * std::ldexp(1.0, -24) * ref, 1e-36);
            CHECK(std::fabs(got - ref) <= tol, "lobe_pow(%.9g, %g) = %.9g, expected %.9g", x, e, got, ref);
        }
    }
    for (float e : {0.5f, 1.5f, 47.9f, 2000.f, 0.f})
        for (float x : {0.f, 0.25f, 0.7f, 1.f})
            CHECK(lobe_pow(x, e) == std::pow(x, e), "lobe_pow(%g, %g) is not std::pow's", x, e);
}

/// The lane kernels (shading_lanes.h) four at a time against the scalar expressions of
/// render.cpp and vec.h, written out here with Vec3 as render.cpp writes them: every output the
/// same bits, on random inputs, the quarter turns and their neighbours, zero-length vectors,
/// samples on both sides of the fade's end, exponents whole and not.
void test_shading_lanes() {
#ifdef POINTVIZ_SHADING_LANES_SSE2
    using lanes::F1;
    using lanes::F4;
    std::mt19937_64 g(18);
    std::uniform_real_distribution<float> U(0.f, 1.f), S(-2.f, 2.f);
    const auto bits = [](float x) { uint32_t u; std::memcpy(&u, &x, 4); return u; };
    const auto eq3 = [&](Vec3 a, const float *x, const float *y, const float *z, int i) {
        return bits(a.x) == bits(x[i]) && bits(a.y) == bits(y[i]) && bits(a.z) == bits(z[i]);
    };
    // turn_sincos
    std::vector<float> us;
    for (int i = 0; i < 4096; ++i) us.push_back(U(g));
    for (float q : {0.f, 0.125f, 0.25f, 0.375f, 0.5f, 0.625f, 0.75f, 0.875f, 1.f}) {
        float v = q;
        for (int k = 0; k < 8 && v > 0.f; ++k) us.push_back(v = std::nextafter(v, 0.f));
        v = q;
        for (int k = 0; k < 8 && q < 1.f; ++k, v = std::nextafter(v, 1.f)) us.push_back(v);
    }
    while (us.size() % 4) us.push_back(0.5f);
    for (size_t i = 0; i < us.size(); i += 4) {
        F4 c, s;
        lanes::turn_sincos(F4::load(&us[i]), c, s);
        float cc[4], ss[4];
        c.store(cc), s.store(ss);
        for (int k = 0; k < 4; ++k) {
            float rc, rs;
            turn_sincos(us[i + k], rc, rs);
            CHECK(bits(rc) == bits(cc[k]) && bits(rs) == bits(ss[k]), "lanes turn_sincos(%.9g): (%.9g, %.9g), scalar (%.9g, %.9g)",
                  us[i + k], cc[k], ss[k], rc, rs);
        }
    }
    // lobe_pow
    for (float e : {1.f, 2.f, 7.f, 48.f, 1024.f, 47.5f, 0.5f, 2000.f})
        for (size_t i = 0; i < us.size(); i += 4) {
            float out[4];
            lanes::lobe_pow(F4::load(&us[i]), e).store(out);
            for (int k = 0; k < 4; ++k)
                CHECK(bits(out[k]) == bits(lobe_pow(us[i + k], e)), "lanes lobe_pow(%.9g, %g) = %.9g, scalar %.9g",
                      us[i + k], e, out[k], lobe_pow(us[i + k], e));
        }
    // normalize3, cone and cosine directions, light terms, fade: four random cases a step
    const int n = 4096;
    size_t zero_lengths = 0, faded = 0, fading = 0;
    for (int i = 0; i < n; i += 4) {
        float x[4], y[4], z[4], u1[4], u2[4], dx[4], dy[4], dz[4], t[4];
        Vec3 nrm[4], tb[4], bb[4];
        for (int k = 0; k < 4; ++k) {
            const bool zero = (i / 4 + k) % 13 == 0;
            x[k] = zero ? 0.f : S(g), y[k] = zero ? 0.f : S(g), z[k] = zero ? 0.f : S(g);
            zero_lengths += zero;
            u1[k] = U(g), u2[k] = U(g);
            const Vec3 d = normalize(Vec3{S(g), S(g) - 1.5f, S(g)});
            dx[k] = d.x, dy[k] = d.y, dz[k] = d.z;
            t[k] = 40.f * U(g);
            nrm[k] = normalize(Vec3{S(g), S(g), S(g)});
            make_basis(nrm[k], tb[k], bb[k]);
        }
        {   // normalize3
            F4 a = F4::load(x), b = F4::load(y), c = F4::load(z);
            lanes::normalize3(a, b, c);
            float ox[4], oy[4], oz[4];
            a.store(ox), b.store(oy), c.store(oz);
            for (int k = 0; k < 4; ++k)
                CHECK(eq3(normalize(Vec3{x[k], y[k], z[k]}), ox, oy, oz, k), "lanes normalize differs");
        }
        const Vec3 axis = normalize(Vec3{x[0] + 0.1f, y[0] + 3.f, z[0]});
        Vec3 at, ab;
        make_basis(axis, at, ab);
        const float cos_max = std::cos(0.05f + 0.5f * u1[0]);
        float lx[4], ly[4], lz[4];
        {   // sample_cone(Cone, u1, u2)
            F4 a, b, c;
            lanes::cone_direction(axis, at, ab, cos_max, F4::load(u1), F4::load(u2), a, b, c);
            a.store(lx), b.store(ly), c.store(lz);
            for (int k = 0; k < 4; ++k) {
                const float cz = 1.f - u1[k] * (1.f - cos_max);
                const float sz = std::sqrt(std::max(0.f, 1.f - cz * cz));
                float cs, sn;
                turn_sincos(u2[k], cs, sn);
                const Vec3 ref = normalize(at * (sz * cs) + ab * (sz * sn) + axis * cz);
                CHECK(eq3(ref, lx, ly, lz, k), "lanes cone direction differs (u %.9g %.9g)", u1[k], u2[k]);
            }
        }
        {   // sample_cosine(n, t, b, u1, u2)
            float in[9][4], ox[4], oy[4], oz[4];
            for (int k = 0; k < 4; ++k) {
                const Vec3 v[3] = {nrm[k], tb[k], bb[k]};
                for (int c = 0; c < 9; ++c) in[c][k] = v[c / 3][c % 3];
            }
            F4 a, b, c;
            lanes::cosine_direction(F4::load(in[0]), F4::load(in[1]), F4::load(in[2]), F4::load(in[3]),
                                    F4::load(in[4]), F4::load(in[5]), F4::load(in[6]), F4::load(in[7]),
                                    F4::load(in[8]), F4::load(u1), F4::load(u2), a, b, c);
            a.store(ox), b.store(oy), c.store(oz);
            for (int k = 0; k < 4; ++k) {
                const float r = std::sqrt(u1[k]);
                float c2, s2;
                turn_sincos(u2[k], c2, s2);
                const Vec3 ref = normalize(tb[k] * (r * c2) + bb[k] * (r * s2) +
                                           nrm[k] * std::sqrt(std::max(0.f, 1.f - u1[k])));
                CHECK(eq3(ref, ox, oy, oz, k), "lanes cosine direction differs");
            }
        }
        for (float shin : {48.f, 47.5f}) {   // ndl and the lobe
            float nx[4], ny[4], nz[4], ndl[4], spec[4];
            for (int k = 0; k < 4; ++k) nx[k] = nrm[k].x, ny[k] = nrm[k].y, nz[k] = nrm[k].z;
            F4 a, b;
            lanes::light_terms(F4::load(nx), F4::load(ny), F4::load(nz), F4::load(lx), F4::load(ly),
                               F4::load(lz), F4::load(dx), F4::load(dy), F4::load(dz), 0.15f, shin, a, b);
            a.store(ndl), b.store(spec);
            for (int k = 0; k < 4; ++k) {
                const Vec3 ldir{lx[k], ly[k], lz[k]}, d{dx[k], dy[k], dz[k]};
                const Vec3 hv = normalize(ldir - d);
                const float rs = 0.15f * lobe_pow(std::max(0.f, dot(nrm[k], hv)), shin);
                CHECK(bits(dot(nrm[k], ldir)) == bits(ndl[k]) && bits(rs) == bits(spec[k]),
                      "lanes light terms differ: ndl %.9g / %.9g, spec %.9g / %.9g", ndl[k], dot(nrm[k], ldir), spec[k], rs);
            }
        }
        {   // the fade: rays from an eye above the plane y = -1
            const Vec3 gp{0.f, -1.f, 0.f}, gn{0.f, 1.f, 0.f};
            const float fade = 3.f, end = 2.0001f * fade, end2 = end * end;
            float ox[4], oy[4], oz[4], f[4];
            for (int k = 0; k < 4; ++k) ox[k] = 0.3f, oy[k] = 2.f, oz[k] = 5.f;
            lanes::ground_fade(F4::load(ox), F4::load(oy), F4::load(oz), F4::load(dx), F4::load(dy), F4::load(dz),
                               F4::load(t), gp, gn, fade, end2).store(f);
            for (int k = 0; k < 4; ++k) {
                const Vec3 p = Vec3{ox[k], oy[k], oz[k]} + Vec3{dx[k], dy[k], dz[k]} * t[k];
                const Vec3 gg = p - gp;
                const float d2 = length2(gg - gn * dot(gg, gn));
                float ref = 1.f;
                if (!(d2 > end2)) {
                    ref = std::clamp(std::sqrt(d2) / fade - 1.f, 0.f, 1.f);
                    ref = ref * ref * (3.f - 2.f * ref);
                }
                faded += d2 > end2;
                fading += ref > 0.f && ref < 1.f;
                CHECK(bits(ref) == bits(f[k]), "lanes fade %.9g, scalar %.9g (d2 %.9g)", f[k], ref, d2);
            }
        }
    }
    CHECK(zero_lengths > 0 && faded > 0 && fading > 0, "cases not met: zero %zu faded %zu fading %zu",
          zero_lengths, faded, fading);
    // the scalar lane type is the scalar functions
    F1 c1, s1;
    lanes::turn_sincos(F1{0.3f}, c1, s1);
    float rc, rs;
    turn_sincos(0.3f, rc, rs);
    CHECK(bits(c1.v) == bits(rc) && bits(s1.v) == bits(rs), "F1 turn_sincos");
#endif
}

int main() {
    test_one_surfel();
    test_duplicates();
    test_line_and_plane();
    test_random_clouds_match_brute_force();
    test_every_isa_equals_base();
    test_offset_precision();
    test_scales();
    test_degenerate_rays_and_surfels();
    test_lod_and_interpolation_are_clean();
    test_lod_budget();
    test_render();
    test_shading_math();
    test_shading_lanes();
    test_empty_and_oversized_builds_throw();
    test_staged_build();
    std::printf("core_tests: %d checks, %d failures\n", pointviz_tests::g_checks, pointviz_tests::g_failures);
    return pointviz_tests::g_failures == 0 ? 0 : 1;
}
