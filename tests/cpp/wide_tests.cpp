// pointviz — tests of the wide tree (wide.h) and its traversal (wide_trace.h) against the binary
// traversal (trace.h), run under ASan + UBSan by `make sanitize`:
// * the collapse: every lane of every wide node holds its binary node's bound, cone and leaf
//   range or wide node, and exactly the interior nodes of the wide levels have one;
// * the queries: on random clouds (disks at every orientation: culling and cones at work), an
//   analytic sphere and a plane, for every instruction set, with level of detail (size,
//   deviation and budget rules), culling, slabs, boxes and interpolation on and off, the wide
//   traversal gives the binary one's any hits exactly, the same nearest disk on every ray, and
//   the same blended hit on all but a few rays (the order in which disks reach the closest-hit
//   policy may differ, wide_trace.h); statistics agree to within a few percent.
// * packets (packet_trace.h, packet_cast.h): closest hits of coherent groups traversed together
//   (8x1 and 2x4 pixels, rays in the SIMD lanes) equal those of one ray at a time bit for bit
//   (t, normal, colour, radius, surfel, count) on primary grids with holes and silhouettes, rays
//   from inside, axis-aligned (degenerate) directions, with culling, slabs, boxes and
//   interpolation on and off, for every instruction set (through cast_rays: 2x4 blocks of the
//   grid's rows) and the portable kernels directly; any hits of the same groups (occluded and
//   the portable kernels, tmax per ray inside and beyond the surface, t_min on and off, culling
//   on and off) equal one ray at a time's.
// The brute-force checks of core_tests run the default traversal, which is the wide one.
//
// Random cases are seeded by their index; a failure prints the case to replay.
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "pointviz/cast.h"
#include "pointviz/dispatch.h"
#include "pointviz/packet_trace.h"
#include "pointviz/tree.h"
#include "check.h"

using namespace pointviz;

namespace {

/// Surfels as the build takes them.
struct Scene {
    std::vector<double> points;
    std::vector<float> normals, radii, colors;
};

enum class Shape { RandomDisks, Sphere, Plane };

/// `n` surfels: on the unit sphere with random normals (RandomDisks) or outward ones (Sphere),
/// or on the z = 0 square [-1, 1]^2 facing +z (Plane); random colours.
Scene make_scene(Shape shape, size_t n, uint64_t seed) {
    std::mt19937_64 g(seed);
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::uniform_real_distribution<double> uni(-1.0, 1.0);
    std::uniform_real_distribution<float> unit(0.f, 1.f);
    Scene s;
    const float spacing = float(std::sqrt(4.0 / double(n)));
    for (size_t i = 0; i < n; ++i) {
        double p[3], q[3];
        if (shape == Shape::Plane) {
            p[0] = uni(g);
            p[1] = uni(g);
            p[2] = 0.0;
            q[0] = 0.0;
            q[1] = 0.0;
            q[2] = 1.0;
        } else {
            double v[3] = {gauss(g), gauss(g), gauss(g)};
            const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
            for (int k = 0; k < 3; ++k) p[k] = q[k] = v[k] / l;
            if (shape == Shape::RandomDisks) {
                double w[3] = {gauss(g), gauss(g), gauss(g)};
                const double m = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
                for (int k = 0; k < 3; ++k) q[k] = w[k] / m;
            }
        }
        for (int k = 0; k < 3; ++k) {
            s.points.push_back(p[k]);
            s.normals.push_back(float(q[k]));
            s.colors.push_back(unit(g));
        }
        s.radii.push_back(shape == Shape::RandomDisks ? spacing * (1.f + 3.f * unit(g))
                                                      : 1.5f * spacing);
    }
    return s;
}

SurfelTree build_tree(const Scene &s, uint32_t leaf, uint32_t box_depth) {
    const double origin[3] = {0.0, 0.0, 0.0};
    SurfelArrays a{s.points.data(), s.normals.data(), s.radii.data(), s.colors.data(),
                   s.radii.size()};
    BuildOptions bo;
    bo.leaf_size = leaf;
    bo.box_depth = box_depth;
    bo.threads = 2;
    return SurfelTree(a, origin, bo);
}

/// `n` rays (origin, direction) from a sphere of radius 4 toward points within 1.2 of the
/// origin: most hit, some graze, some miss.
std::vector<double> make_rays(size_t n, uint64_t seed) {
    std::mt19937_64 g(seed);
    std::normal_distribution<double> gauss(0.0, 1.0);
    std::uniform_real_distribution<double> uni(-1.2, 1.2);
    std::vector<double> rays;
    for (size_t i = 0; i < n; ++i) {
        double v[3] = {gauss(g), gauss(g), gauss(g)};
        const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int k = 0; k < 3; ++k) rays.push_back(4.0 * v[k] / l);
        for (int k = 0; k < 3; ++k) rays.push_back(uni(g) - rays[rays.size() - 3]);
    }
    return rays;
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof(float)) == 0; }

// ------------------------------------------------------------------------------------------

/// Every lane of every wide node holds what its binary node gives the scalar tests.
void test_collapse() {
    for (uint32_t leaf : {1u, 8u, 31u})
        for (uint32_t bd : {0u, 1u, 3u, 6u, 255u}) {
            const Scene s = make_scene(Shape::RandomDisks, 3000, 11 + leaf);
            const SurfelTree tree = build_tree(s, leaf, bd);
            const WideTree &wide = tree.wide();
            const auto &nodes = tree.nodes();
            const auto &boxes = tree.boxes();
            const auto &ls = tree.level_start();
            CHECK(wide.box_depth() == tree.box_depth(), "leaf %u box %u: box depth %u", leaf, bd,
                  wide.box_depth());
            size_t bad = 0, count = 0;
            // One lane: the node's cone, its leaf range or wide node, and its bound.
            auto lane_ok = [&](const auto &w, int k, uint32_t x) {
                const Node &nd = nodes[x];
                const uint32_t ref = nd.is_leaf() ? nd.index_count : (wide.has(x) ? wide.index_of(x) : 0u);
                return w.ax[k] == nd.axis_q[0] && w.ay[k] == nd.axis_q[1] &&
                       w.az[k] == nd.axis_q[2] && w.cone_q[k] == nd.cone_q && w.ref[k] == ref;
            };
            auto sphere_ok = [&](const WideNode &w, int k, uint32_t x) {
                const Node &nd = nodes[x];
                return lane_ok(w, k, x) && same_bits(w.cx[k], nd.c.x) && same_bits(w.cy[k], nd.c.y) &&
                       same_bits(w.cz[k], nd.c.z) && same_bits(w.r[k], nd.radius) &&
                       w.slab_q[k] == nd.slab_q();
            };
            auto box_ok = [&](const WideBoxNode &w, int k, uint32_t x) {
                const Box &b = boxes[x];
                return x < boxes.size() && lane_ok(w, k, x) && same_bits(w.lx[k], b.lo.x) &&
                       same_bits(w.ly[k], b.lo.y) && same_bits(w.lz[k], b.lo.z) &&
                       same_bits(w.hx[k], b.hi.x) && same_bits(w.hy[k], b.hi.y) &&
                       same_bits(w.hz[k], b.hi.z);
            };
            const uint32_t first = WideTree::first_level(tree.box_depth());
            for (uint32_t lvl = 0; lvl < tree.depth(); ++lvl) {
                for (uint32_t i = ls[lvl]; i < ls[lvl + 1]; ++i) {
                    const Node &p = nodes[i];
                    const bool want = lvl % 2 == first % 2 && !p.is_leaf();
                    if (wide.has(i) != want) {
                        ++bad;
                        continue;
                    }
                    if (!want) continue;
                    ++count;
                    const bool box = wide.box_level(lvl);
                    bad += box != (lvl + 2 < tree.box_depth());  // every lane a box, or none
                    for (uint32_t j = 0; j < 2; ++j) {
                        const uint32_t x = p.index() + j;
                        std::vector<uint32_t> lanes{x};
                        if (!nodes[x].is_leaf()) lanes = {x, nodes[x].index(), nodes[x].index() + 1};
                        for (size_t m = 0; m < lanes.size(); ++m) {
                            const int k = m == 0 ? int(j) : int(2 + 2 * j + (m - 1));
                            const bool ok = box ? box_ok(wide.box_node(wide.index_of(i)), k, lanes[m])
                                                : sphere_ok(wide.node(wide.index_of(i)), k, lanes[m]);
                            bad += !ok;
                        }
                        if (!box && nodes[x].is_leaf())  // a leaf's children: absent lanes
                            for (int k = int(2 + 2 * j); k < int(4 + 2 * j); ++k)
                                bad += !std::isnan(wide.node(wide.index_of(i)).r[k]);
                    }
                }
            }
            CHECK(bad == 0, "leaf %u box %u: %zu wide lanes or nodes wrong", leaf, bd, bad);
            CHECK(count == wide.nodes().size() + wide.box_nodes().size(),
                  "leaf %u box %u: %zu of %zu wide nodes reached", leaf, bd, count,
                  wide.nodes().size() + wide.box_nodes().size());
            CHECK(tree.memory_bytes() >= wide.memory_bytes(), "memory counts the wide nodes");
        }
}

struct Result {
    std::vector<float> t, nrm, col, rad;
    std::vector<int32_t> idx;
    std::vector<uint8_t> cnt, occ;
    BatchStats cs, os;
};

/// Closest hits of `rays`, with statistics (`count`) or without (the path packets take).
Result run_closest(const SurfelTree &tree, const std::vector<double> &rays, const TraceOptions &o,
                   float pixel_angle, bool count) {
    const size_t n = rays.size() / 6;
    Result r;
    r.t.resize(n);
    r.nrm.resize(3 * n);
    r.col.resize(3 * n);
    r.rad.resize(n);
    r.idx.resize(n);
    r.cnt.resize(n);
    CastOutput out{r.t.data(), r.nrm.data(), r.col.data(), r.rad.data(), r.idx.data(), r.cnt.data()};
    cast_rays(tree, rays.data(), n, o, pixel_angle, 2, out, count, r.cs);
    return r;
}

Result run(const SurfelTree &tree, const std::vector<double> &rays, const std::vector<float> &tmax,
           const TraceOptions &o, float pixel_angle) {
    Result r = run_closest(tree, rays, o, pixel_angle, true);
    r.occ.resize(r.t.size());
    occluded(tree, rays.data(), tmax.data(), r.t.size(), o, 0.f, pixel_angle, 2, r.occ.data(), true, r.os);
    return r;
}

/// Relative difference of two counts.
double rel(uint64_t a, uint64_t b) { return std::fabs(double(a) - double(b)) / std::max(1.0, double(b)); }

/// The wide traversal against the binary one, every instruction set, many option sets.
void test_wide_equals_binary() {
    const Shape shapes[] = {Shape::RandomDisks, Shape::Sphere, Shape::Plane};
    const char *shape_names[] = {"random disks", "sphere", "plane"};
    size_t rays_total = 0, blended_differ = 0;
    for (int si = 0; si < 3; ++si)
        for (uint32_t leaf : {1u, 8u, 31u}) {
            const uint32_t bd = leaf == 8 ? 4u : (leaf == 1 ? (si == 1 ? 255u : 0u) : (si == 2 ? 7u : 1u));
            const Scene s = make_scene(shapes[si], si == 0 ? 2000 : 6000, 100 + si * 7 + leaf);
            const SurfelTree tree = build_tree(s, leaf, bd);
            const std::vector<double> rays = make_rays(500, 900 + si * 7 + leaf);
            const size_t n = rays.size() / 6;
            std::vector<float> tmax(n);
            for (size_t i = 0; i < n; ++i) tmax[i] = float(2.5 + 3.0 * double(i % 5) / 5.0);
            for (int variant = 0; variant < 8; ++variant) {
                TraceOptions o;
                o.box_depth = bd;
                o.lod = variant >= 3;
                o.cull = variant % 2 == 1;
                o.slabs = variant != 2;
                o.interp = variant == 0 ? Interpolation::None : Interpolation::Smooth;
                if (variant == 5) o.lod_criterion = LodCriterion::Deviation;
                if (variant >= 6) {
                    o.lod_criterion = LodCriterion::Budget;
                    o.max_error = variant == 6 ? 0.01f : 0.2f;
                }
                const float pa = o.lod ? (variant == 4 ? 0.05f : 0.01f) : 0.f;
                for (Isa isa : available_isas()) {
                    o.isa = isa;
                    o.wide = false;
                    const Result b = run(tree, rays, tmax, o, pa);
                    o.wide = true;
                    const Result w = run(tree, rays, tmax, o, pa);
                    const std::string name = std::string(shape_names[si]) + " leaf " +
                                             std::to_string(leaf) + " variant " +
                                             std::to_string(variant) + " " + isa_name(isa);
                    CHECK(use_wide(tree, o), "%s: the wide traversal did not run", name.c_str());
                    // Closest hits: the same nearest disk (on the plane every disk a ray crosses
                    // is at the same t, so there the nearest t), and the same blend to float
                    // rounding (the blend sums the disks in arrival order) on all but 1 %.
                    size_t occ_differ = 0, nearest_differ = 0, hit_differ = 0, differ = 0;
                    for (size_t i = 0; i < n; ++i) {
                        occ_differ += b.occ[i] != w.occ[i];
                        hit_differ += std::isinf(b.t[i]) != std::isinf(w.t[i]);
                        if (shapes[si] != Shape::Plane) nearest_differ += b.idx[i] != w.idx[i];
                        else if (o.interp == Interpolation::None) nearest_differ += !same_bits(b.t[i], w.t[i]);
                        if (std::isinf(b.t[i])) continue;
                        auto close = [](float x, float y) { return std::fabs(x - y) <= 1e-5f * (1.f + std::fabs(y)); };
                        // (on the plane, ties decide which disks are nearest or among the eight
                        // blended: their colours and radii may differ, t and normal may not)
                        const bool ties = shapes[si] == Shape::Plane;
                        bool same = close(b.t[i], w.t[i]) &&
                                    (ties || (close(b.rad[i], w.rad[i]) && b.cnt[i] == w.cnt[i]));
                        for (int k = 0; k < 3; ++k)
                            same = same && close(b.nrm[3 * i + k], w.nrm[3 * i + k]) &&
                                   (ties || close(b.col[3 * i + k], w.col[3 * i + k]));
                        differ += !same;
                    }
                    rays_total += n;
                    blended_differ += differ;
                    CHECK(occ_differ == 0, "%s: %zu any hits differ", name.c_str(), occ_differ);
                    CHECK(hit_differ == 0, "%s: %zu hit/miss differ", name.c_str(), hit_differ);
                    CHECK(nearest_differ == 0, "%s: %zu nearest disks differ", name.c_str(), nearest_differ);
                    CHECK(differ <= n / 100, "%s: %zu of %zu blended hits differ", name.c_str(),
                          differ, n);
                    CHECK(w.cs.hits == b.cs.hits && w.os.hits == b.os.hits, "%s: hit counts",
                          name.c_str());
                    // Work: the closest-hit counts agree to a few percent (nodes: A and B are counted when
                    // tested, not when popped); any-hit queries stop at
                    // the first disk found, and which one comes first depends on the visiting
                    // order, so their counts only roughly.
                    CHECK(rel(w.cs.nodes, b.cs.nodes) < 0.1 && rel(w.cs.disks, b.cs.disks) < 0.05 &&
                              rel(w.os.nodes, b.os.nodes) < 0.3 && rel(w.os.disks, b.os.disks) < 0.3,
                          "%s: statistics differ: nodes %llu vs %llu, disks %llu vs %llu, any-hit "
                          "nodes %llu vs %llu", name.c_str(), (unsigned long long)w.cs.nodes,
                          (unsigned long long)b.cs.nodes, (unsigned long long)w.cs.disks,
                          (unsigned long long)b.cs.disks, (unsigned long long)w.os.nodes,
                          (unsigned long long)b.os.nodes);
                    CHECK(w.cs.max_depth == b.cs.max_depth, "%s: deepest level %u vs %u",
                          name.c_str(), w.cs.max_depth, b.cs.max_depth);
                }
            }
        }
    std::printf("wide_tests: %zu of %zu closest hits blended differently from the binary traversal\n",
                blended_differ, rays_total);
}

/// Every instruction set's wide traversal gives the portable one's answers bit for bit.
void test_every_isa_equals_base() {
    const Scene s = make_scene(Shape::RandomDisks, 4000, 77);
    const SurfelTree tree = build_tree(s, 8, 3);
    const std::vector<double> rays = make_rays(600, 78);
    std::vector<float> tmax(rays.size() / 6, 3.5f);
    for (int variant = 0; variant < 3; ++variant) {
        TraceOptions o;
        o.box_depth = 3;
        o.lod = variant == 2;
        o.cull = variant >= 1;
        const float pa = o.lod ? 0.02f : 0.f;
        o.isa = Isa::Base;
        const Result base = run(tree, rays, tmax, o, pa);
        for (Isa isa : available_isas()) {
            o.isa = isa;
            const Result r = run(tree, rays, tmax, o, pa);
            auto same = [](const auto &a, const auto &b) {
                return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
            };
            CHECK(same(r.t, base.t) && same(r.nrm, base.nrm) && same(r.col, base.col) &&
                      same(r.idx, base.idx) && same(r.cnt, base.cnt) && same(r.occ, base.occ) &&
                      r.cs.nodes == base.cs.nodes && r.cs.disks == base.cs.disks &&
                      r.os.nodes == base.os.nodes,
                  "variant %d: %s differs from base", variant, isa_name(isa));
        }
    }
}

/// Options whose box depth differs from the tree's take the binary traversal (and still agree).
void test_other_box_depth_falls_back() {
    const Scene s = make_scene(Shape::Sphere, 3000, 5);
    const SurfelTree tree = build_tree(s, 8, 4);
    TraceOptions o;
    o.box_depth = 4;
    CHECK(use_wide(tree, o), "box depth 4 on a box-depth-4 tree runs wide");
    o.box_depth = 100;  // only the tree's 4 levels have boxes: the same as 4
    CHECK(use_wide(tree, o), "box depth 100 on a box-depth-4 tree runs wide");
    const SurfelTree all_boxes = build_tree(s, 8, 255);  // boxes on every level
    o.box_depth = 255;
    CHECK(use_wide(all_boxes, o) && all_boxes.wide().nodes().empty() &&
              !all_boxes.wide().box_nodes().empty(), "a tree of boxes runs wide on box nodes");
    o.box_depth = 2;
    CHECK(!use_wide(tree, o), "box depth 2 on a box-depth-4 tree runs binary");
    o.wide = false;
    o.box_depth = 4;
    CHECK(!use_wide(tree, o), "wide = false runs binary");
    const SurfelTree single = build_tree(make_scene(Shape::Plane, 5, 6), 8, 0);
    o.wide = true;
    o.box_depth = 0;
    CHECK(single.wide().empty() && !use_wide(single, o), "a one-leaf tree has no wide nodes");
}

/// Camera rays of a w x h grid in raster order from `eye` toward `at` (field of view `fov`
/// radians); `axis_aligned`: the grid's centre column and row have exactly zero components.
std::vector<double> grid_rays(const double *eye, const double *at, int w, int h, double fov) {
    double f[3], u[3] = {0, 0, 1}, x[3], y[3];
    for (int k = 0; k < 3; ++k) f[k] = at[k] - eye[k];
    auto norm = [](double *v) {
        const double l = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
        for (int k = 0; k < 3; ++k) v[k] /= l;
    };
    norm(f);
    if (std::fabs(f[2]) > 0.9) u[0] = 1, u[2] = 0;
    x[0] = f[1] * u[2] - f[2] * u[1], x[1] = f[2] * u[0] - f[0] * u[2], x[2] = f[0] * u[1] - f[1] * u[0];
    norm(x);
    y[0] = x[1] * f[2] - x[2] * f[1], y[1] = x[2] * f[0] - x[0] * f[2], y[2] = x[0] * f[1] - x[1] * f[0];
    const double s = std::tan(fov / 2) / (w / 2.0);
    std::vector<double> rays;
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double a = (i - w / 2) * s, b = (j - h / 2) * s;  // centre: exactly 0
            for (int k = 0; k < 3; ++k) rays.push_back(eye[k]);
            for (int k = 0; k < 3; ++k) rays.push_back(f[k] + a * x[k] + b * y[k]);
        }
    return rays;
}

/// Packets of coherent rays give one ray at a time's closest hits bit for bit.
void test_packets_equal_single_rays() {
    const Shape shapes[] = {Shape::RandomDisks, Shape::Sphere, Shape::Plane};
    // outside looking at the middle, outside along an axis (zero direction components), inside,
    // at the rim (silhouettes)
    const double eyes[4][3] = {{3.1, -2.2, 1.3}, {0.0, 0.0, 4.0}, {0.05, -0.1, 0.02}, {0.0, 0.0, 4.0}};
    const double ats[4][3] = {{0.1, 0.2, -0.1}, {0.0, 0.0, 0.0}, {1.0, 0.3, 0.2}, {0.99, 0.0, 0.0}};
    size_t kept = 0, total = 0, kept_block = 0, total_block = 0, any_total = 0, any_hits = 0;
    constexpr size_t kGridW = 37, kGridH = 23;
    for (int si = 0; si < 3; ++si)
        for (uint32_t leaf : {4u, 8u})
            for (uint32_t box_depth : {0u, 3u, 4u}) {
                const Scene s = make_scene(shapes[si], 6000, 300 + si);
                const SurfelTree tree = build_tree(s, leaf, box_depth);
                for (int ei = 0; ei < 4; ++ei) {
                    // a tight grid (coherent: packets) and a wide one (silhouettes, holes,
                    // groups beyond kPacketMinCos: one ray at a time)
                    for (double fov : {0.06, 0.25, 1.4}) {
                        const std::vector<double> rays = grid_rays(eyes[ei], ats[ei], int(kGridW), int(kGridH), fov);
                        for (int variant = 0; variant < 4; ++variant) {
                            TraceOptions o;
                            o.box_depth = box_depth;
                            o.cull = variant != 1;
                            o.slabs = variant != 2;
                            o.interp = variant == 3 ? Interpolation::Paper : Interpolation::Smooth;
                            if (variant == 3) o.window = 2.f;
                            o.packets = false;
                            o.isa = Isa::Base;
                            const Result single = run_closest(tree, rays, o, 0.f, false);
                            // Any hits: tmax per ray around the closest hit (before it, beyond
                            // it), far or infinite on misses, one NaN (an invalid ray: its
                            // group goes one ray at a time); t_min on in one variant.
                            const size_t nr = rays.size() / 6;
                            std::vector<float> tmax(nr);
                            for (size_t i = 0; i < nr; ++i) {
                                const float t = single.t[i];
                                tmax[i] = std::isfinite(t) ? t * (0.5f + float((i * 37) % 100) / 100.f)
                                                           : (i % 3 == 0 ? kInf : 5.f);
                            }
                            tmax[nr / 2] = std::numeric_limits<float>::quiet_NaN();
                            const float t_min = variant == 2 ? 0.05f : 0.f;
                            std::vector<uint8_t> occ_single(nr), occ(nr);
                            BatchStats os;
                            occluded(tree, rays.data(), tmax.data(), nr, o, t_min, 0.f, 2,
                                     occ_single.data(), false, os);
                            o.packets = true;
                            for (Isa isa : available_isas()) {
                                o.isa = isa;
                                const Result p = run_closest(tree, rays, o, 0.f, false);
                                auto same = [](const auto &a, const auto &b) {
                                    return std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
                                };
                                CHECK(same(p.t, single.t) && same(p.nrm, single.nrm) &&
                                          same(p.col, single.col) && same(p.rad, single.rad) &&
                                          same(p.idx, single.idx) && same(p.cnt, single.cnt),
                                      "shape %d leaf %u box depth %u eye %d fov %.2f variant %d %s: "
                                      "packets differ from single rays", si, leaf, box_depth, ei,
                                      fov, variant, isa_name(isa));
                                BatchStats ps;
                                occluded(tree, rays.data(), tmax.data(), nr, o, t_min, 0.f, 2,
                                         occ.data(), false, ps);
                                CHECK(occ == occ_single && ps.hits == os.hits && ps.invalid == os.invalid &&
                                          ps.first_invalid == os.first_invalid && ps.rays == os.rays,
                                      "shape %d leaf %u box depth %u eye %d fov %.2f variant %d %s: "
                                      "packet any hits differ from single rays", si, leaf, box_depth,
                                      ei, fov, variant, isa_name(isa));
                            }
                            // The portable kernels directly, on groups of eight in a row and
                            // on blocks of 2x4 pixels (what cast_rays makes of rows of rays in
                            // raster order): the packet path ran, and most rays of the tight
                            // grid stayed in their packet.
                            o.isa = Isa::Base;
                            const LodGates gates = lod_gates(o);
                            auto check_group = [&](const size_t *idx, uint32_t centre, size_t &kept_n,
                                                   size_t &total_n) {
                                Ray r[kPacket];
                                for (int k = 0; k < kPacket; ++k) {
                                    const double *x = &rays[6 * idx[k]];
                                    const double l = std::sqrt(x[3] * x[3] + x[4] * x[4] + x[5] * x[5]);
                                    r[k].o = {float(x[0]), float(x[1]), float(x[2])};
                                    r[k].d = {float(x[3] / l), float(x[4] / l), float(x[5] / l)};
                                }
                                if (!packet_covers(tree, r, kPacket, o)) return;
                                SurfaceHit h[kPacket];
                                const uint32_t stayed =
                                    o.slabs ? closest_hits_packet_impl<true>(tree, r, kPacket, o, gates, h, centre)
                                            : closest_hits_packet_impl<false>(tree, r, kPacket, o, gates, h, centre);
                                kept_n += size_t(__builtin_popcount(stayed));
                                total_n += kPacket;
                                for (int k = 0; k < kPacket; ++k) {
                                    SurfaceHit one;
                                    NoStats ns;
                                    closest_hit(tree, r[k], o, gates, one, ns);
                                    CHECK(same_bits(one.t, h[k].t) && one.index == h[k].index &&
                                              same_bits(one.n.x, h[k].n.x) && same_bits(one.color.y, h[k].color.y) &&
                                              one.count == h[k].count,
                                          "shape %d leaf %u eye %d variant %d ray %zu: packet differs",
                                          si, leaf, ei, variant, idx[k]);
                                }
                                // Any hits, culling as the variant says and the other way.
                                Ray a[kPacket];
                                for (int k = 0; k < kPacket; ++k) {
                                    const float tm = tmax[idx[k]];
                                    a[k] = r[k];
                                    a[k].tmin = t_min;
                                    a[k].tmax = std::isnan(tm) ? kInf : tm;
                                }
                                if (!packet_covers(tree, a, kPacket, o, false)) return;
                                for (bool cull : {o.cull, !o.cull}) {
                                    uint8_t ah[kPacket];
                                    const uint32_t mask =
                                        o.slabs ? any_hits_packet_impl<true>(tree, a, kPacket, o, gates, cull, ah, centre)
                                                : any_hits_packet_impl<false>(tree, a, kPacket, o, gates, cull, ah, centre);
                                    for (int k = 0; k < kPacket; ++k) {
                                        NoStats ns;
                                        const bool one = any_hit(tree, a[k], o, gates, cull, ns);
                                        any_total += 1;
                                        any_hits += one;
                                        CHECK(one == (ah[k] != 0) && one == (((mask >> k) & 1u) != 0),
                                              "shape %d leaf %u eye %d variant %d cull %d ray %zu: "
                                              "packet any hit differs", si, leaf, ei, variant, int(cull), idx[k]);
                                    }
                                }
                            };
                            size_t idx[kPacket];
                            for (size_t g = 0; g + kPacket <= rays.size() / 6; g += kPacket) {
                                for (int k = 0; k < kPacket; ++k) idx[k] = g + size_t(k);
                                check_group(idx, kRowCentre, kept, total);
                            }
                            for (size_t j = 0; j + 1 < kGridH; j += 2)
                                for (size_t i = 0; i + 4 <= kGridW; i += 4) {
                                    for (int k = 0; k < kPacket; ++k)
                                        idx[k] = (j + size_t(k / 4)) * kGridW + i + size_t(k % 4);
                                    check_group(idx, kBlockCentre, kept_block, total_block);
                                }
                        }
                    }
                }
            }
    CHECK(total > 0 && kept * 2 > total, "packets ran: %zu of %zu rays stayed in theirs", kept, total);
    CHECK(total_block > 0 && kept_block * 2 > total_block,
          "2x4 packets ran: %zu of %zu rays stayed in theirs", kept_block, total_block);
    CHECK(any_total > 0 && any_hits > any_total / 10 && any_hits < any_total - any_total / 10,
          "packet any hits ran on hits and misses: %zu of %zu", any_hits, any_total);
    std::printf("wide_tests: %zu of %zu packet any hits hit\n", any_hits, any_total);
    std::printf("wide_tests: %zu of %zu rays stayed in their packet of 8x1, %zu of %zu of 2x4\n",
                kept, total, kept_block, total_block);
}

}  // namespace

int main() {
    test_collapse();
    test_wide_equals_binary();
    test_every_isa_equals_base();
    test_other_box_depth_falls_back();
    test_packets_equal_single_rays();
    std::printf("wide_tests: %d checks, %d failures\n", pointviz_tests::g_checks,
                pointviz_tests::g_failures);
    return pointviz_tests::g_failures == 0 ? 0 : 1;
}
