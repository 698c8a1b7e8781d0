// pointviz — tests of the conventional KD-tree (kdtree.h) on its own, run under ASan + UBSan by
// `make sanitize`. Oracles: brute force over all surfels in double precision, and the surfel
// hierarchy (SurfelTree) blending the same disks. Edge cases: one surfel, coincident surfels, an
// axis-aligned plane (every disk box flat on one coordinate), axis-parallel rays, NaN input,
// cancellation through Progress.
//
// Random cases are seeded by their index; a failure prints the case name and index to replay it.
#include <cmath>
#include <cstdio>
#include <limits>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "pointviz/cast.h"
#include "pointviz/kdtree.h"
#include "pointviz/tree.h"

using namespace pointviz;

namespace {

int checks = 0, failures = 0;

void expect(bool ok, const std::string &what) {
    ++checks;
    if (!ok) {
        ++failures;
        std::fprintf(stderr, "FAIL %s\n", what.c_str());
    }
}

/// Surfels in world coordinates, as the Python layer hands them over.
struct Surfels {
    std::vector<double> p;
    std::vector<float> n, r;
    size_t size() const { return r.size(); }
    void push(const double c[3], Vec3 nn, float rad) {
        nn = normalize(nn);
        p.insert(p.end(), {c[0], c[1], c[2]});
        n.insert(n.end(), {nn.x, nn.y, nn.z});
        r.push_back(rad);
    }
    SurfelArrays arrays() const { return {p.data(), n.data(), r.data(), nullptr, size()}; }
};

const double kOrigin[3] = {0.0, 0.0, 0.0};

/// Nearest disk along a world ray (unit direction) in double precision: t of a hit well inside
/// its rim ("certain") and of any hit within a rim band where float rounding may go either way.
void nearest_disk(const Surfels &s, const double *ray, double tmin, double &certain,
                  double &possible) {
    certain = possible = INFINITY;
    for (size_t i = 0; i < s.size(); ++i) {
        double nn[3] = {s.n[3 * i], s.n[3 * i + 1], s.n[3 * i + 2]}, num = 0, den = 0;
        for (int k = 0; k < 3; ++k) {
            num += (s.p[3 * i + k] - ray[k]) * nn[k];
            den += ray[3 + k] * nn[k];
        }
        if (std::fabs(den) < 1e-4) continue;  // near-parallel: unstable in float, skip
        const double t = num / den;
        if (t < tmin) continue;
        double q2 = 0;
        for (int k = 0; k < 3; ++k) {
            const double q = ray[k] + ray[3 + k] * t - s.p[3 * i + k];
            q2 += q * q;
        }
        const double u2 = q2 / (double(s.r[i]) * s.r[i]);
        if (u2 <= 0.999) certain = std::min(certain, t);
        if (u2 <= 1.001) possible = std::min(possible, t);
    }
}

std::vector<double> rays_toward(std::mt19937_64 &g, size_t n, double far, double spread) {
    std::normal_distribution<double> N(0.0, 1.0);
    std::uniform_real_distribution<double> U(-spread, spread);
    std::vector<double> rays;
    for (size_t i = 0; i < n; ++i) {
        double o[3] = {N(g), N(g), N(g)}, d[3];
        const double lo = std::sqrt(o[0] * o[0] + o[1] * o[1] + o[2] * o[2]);
        for (double &v : o) v *= far / lo;
        for (int k = 0; k < 3; ++k) d[k] = U(g) - o[k];
        const double ld = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        rays.insert(rays.end(), {o[0], o[1], o[2], d[0] / ld, d[1] / ld, d[2] / ld});
    }
    return rays;
}

TraceOptions nearest_only() {
    TraceOptions o;
    o.lod = false;
    o.cull = false;
    o.interp = Interpolation::None;
    return o;
}

/// The KD-tree's nearest hits and any-hits against the brute force.
void check_brute(const std::string &name, const Surfels &s, const std::vector<double> &rays) {
    KdTree tree(s.arrays(), kOrigin, KdBuildOptions{});
    const size_t n = rays.size() / 6;
    std::vector<float> t(n), tmax(n, 1e30f);
    std::vector<int32_t> idx(n);
    std::vector<uint8_t> occ(n);
    CastOutput out;
    out.t = t.data();
    out.index = idx.data();
    BatchStats st, st2;
    cast_rays(tree, rays.data(), n, nearest_only(), 0.f, 2, out, true, st);
    occluded(tree, rays.data(), tmax.data(), n, nearest_only(), 0.f, 0.f, 2, occ.data(), false, st2);
    expect(st.rays == n && st.invalid == 0, name + ": stats rays/invalid");
    for (size_t i = 0; i < n; ++i) {
        double certain, possible;
        nearest_disk(s, &rays[6 * i], 0.0, certain, possible);
        const std::string at = name + "[" + std::to_string(i) + "]";
        if (std::isinf(t[i])) {
            expect(std::isinf(certain), at + ": missed a hit at " + std::to_string(certain));
            expect(idx[i] == -1, at + ": a miss with an index");
        } else {
            expect(t[i] >= possible - 1e-4 && t[i] <= certain + 1e-4,
                   at + ": t " + std::to_string(t[i]) + " outside [" + std::to_string(possible) +
                       ", " + std::to_string(certain) + "]");
            expect(idx[i] >= 0 && size_t(idx[i]) < s.size(), at + ": index out of range");
        }
        if (std::isfinite(certain)) expect(occ[i] == 1, at + ": any-hit missed");
        if (std::isinf(possible)) expect(occ[i] == 0, at + ": any-hit found a phantom");
    }
}

void test_random_clouds() {
    for (int seed = 0; seed < 4; ++seed) {
        std::mt19937_64 g(500 + seed);
        std::normal_distribution<double> N(0.0, 1.0);
        std::uniform_real_distribution<float> R(0.02f, 0.2f);
        Surfels s;
        const size_t n = seed < 2 ? 400 : 3000;
        for (size_t i = 0; i < n; ++i) {
            double c[3] = {N(g), N(g), N(g)};
            s.push(c, {float(N(g)), float(N(g)), float(N(g))}, R(g));
        }
        check_brute("random " + std::to_string(seed), s, rays_toward(g, 300, 5.0, 1.5));
    }
}

void test_degenerate_clouds() {
    std::mt19937_64 g(600);
    Surfels one, same, plane;
    const double c1[3] = {1.0, 2.0, 3.0};
    one.push(c1, {0, 0, 1}, 0.5f);
    const double c0[3] = {0.0, 0.0, 0.0};
    for (int i = 0; i < 1500; ++i) same.push(c0, {0, 1, 0}, 0.25f);
    for (int i = 0; i < 50; ++i)
        for (int j = 0; j < 50; ++j) {
            const double c[3] = {0.04 * i - 1.0, 0.04 * j - 1.0, 0.0};
            plane.push(c, {0, 0, 1}, 0.03f);
        }
    auto rays = rays_toward(g, 200, 4.0, 1.0);
    // axis-parallel rays, some starting inside the bounds, some exactly in the plane z = 0
    for (int k = 0; k < 30; ++k) {
        const double a = 0.05 * k - 0.7;
        rays.insert(rays.end(), {a, -0.3, 2.0, 0, 0, -1});
        rays.insert(rays.end(), {a, 0.1, 0.0, 1, 0, 0});
        rays.insert(rays.end(), {-3.0, a, 0.01, 1, 0, 0});
    }
    std::vector<double> one_rays = rays;
    for (size_t i = 0; i < one_rays.size(); i += 6)
        for (int k = 0; k < 3; ++k) one_rays[i + k] += c1[k];
    check_brute("one surfel", one, one_rays);
    check_brute("coincident", same, rays);
    check_brute("plane", plane, rays);
}

/// Blended hits equal the hierarchy's: the same disks are gathered in the same depth window.
void test_blending_equals_hierarchy() {
    std::mt19937_64 g(700);
    std::normal_distribution<double> N(0.0, 1.0);
    Surfels s;
    for (int i = 0; i < 6000; ++i) {
        double c[3] = {N(g), N(g), N(g)};
        const double l = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
        for (double &v : c) v /= l;
        s.push(c, {float(c[0]), float(c[1]), float(c[2])}, 0.05f);
    }
    KdTree kd(s.arrays(), kOrigin, KdBuildOptions{});
    SurfelTree bvh(s.arrays(), kOrigin, BuildOptions{8, 255, 2});
    auto rays = rays_toward(g, 500, 3.0, 0.8);
    const size_t n = rays.size() / 6;
    std::vector<float> ta(n), tb(n), na(3 * n), nb(3 * n);
    std::vector<uint8_t> ca(n), cb(n);
    TraceOptions o;
    o.lod = false;
    o.cull = false;
    o.box_depth = 255;
    BatchStats st;
    cast_rays(kd, rays.data(), n, o, 0.f, 2, CastOutput{ta.data(), na.data(), nullptr, nullptr, nullptr, ca.data()}, false, st);
    cast_rays(bvh, rays.data(), n, o, 0.f, 2, CastOutput{tb.data(), nb.data(), nullptr, nullptr, nullptr, cb.data()}, false, st);
    int blended = 0;
    for (size_t i = 0; i < n; ++i) {
        const std::string at = "blend[" + std::to_string(i) + "]";
        expect(std::isinf(ta[i]) == std::isinf(tb[i]), at + ": hit/miss differs");
        if (std::isinf(ta[i])) continue;
        expect(std::fabs(ta[i] - tb[i]) <= 1e-6f * tb[i] && ca[i] == cb[i], at + ": t or count differs");
        for (int k = 0; k < 3; ++k) expect(std::fabs(na[3 * i + k] - nb[3 * i + k]) < 1e-5f, at + ": normal");
        blended += ca[i] > 1;
    }
    expect(blended > 100, "blending: too few rays blend several disks");
}

void test_bad_input_and_cancellation() {
    Surfels s;
    const double c[3] = {0, 0, 0};
    s.push(c, {0, 0, 1}, 0.5f);
    const double bad[3] = {std::numeric_limits<double>::quiet_NaN(), 0, 0};
    s.push(bad, {0, 0, 1}, 0.5f);
    bool threw = false;
    try {
        KdTree t(s.arrays(), kOrigin, KdBuildOptions{});
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    expect(threw, "a NaN position must throw invalid_argument");
    threw = false;
    try {
        KdTree t(SurfelArrays{}, kOrigin, KdBuildOptions{});
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    expect(threw, "zero surfels must throw invalid_argument");

    Surfels big;
    std::mt19937_64 g(800);
    std::normal_distribution<double> N(0.0, 1.0);
    for (int i = 0; i < 20000; ++i) {
        double p[3] = {N(g), N(g), N(g)};
        big.push(p, {0, 0, 1}, 0.05f);
    }
    Progress cancelled;
    cancelled.cancel = true;
    threw = false;
    try {
        KdTree t(big.arrays(), kOrigin, KdBuildOptions{}, &cancelled);
    } catch (const Cancelled &) {
        threw = true;
    }
    expect(threw, "a cancelled Progress must stop the build with Cancelled");
    Progress p;
    KdTree t(big.arrays(), kOrigin, KdBuildOptions{}, &p);
    expect(p.done.load() == p.total.load() && p.done.load() == t.slots().size(),
           "progress: done " + std::to_string(p.done.load()) + " total " +
               std::to_string(p.total.load()) + " references " + std::to_string(t.slots().size()));

    const double nan = std::numeric_limits<double>::quiet_NaN();
    std::vector<double> rays = {0, 0, 5, 0, 0, 0, 0, 0, 5, nan, 0, -1, 0, 0, 5, 0, 0, -1};
    std::vector<float> tt(3);
    CastOutput out;
    out.t = tt.data();
    BatchStats st;
    cast_rays(t, rays.data(), 3, nearest_only(), 0.f, 1, out, false, st);
    expect(st.invalid == 2 && st.first_invalid == 0, "two invalid rays, the first at row 0");
    expect(std::isinf(tt[0]) && std::isinf(tt[1]), "invalid rays miss");
}

}  // namespace

int main() {
    test_random_clouds();
    test_degenerate_clouds();
    test_blending_equals_hierarchy();
    test_bad_input_and_cancellation();
    std::printf("kdtree_tests: %d checks, %d failures\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
