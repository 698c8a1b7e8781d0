// pointviz — tests of the depth-camera patch planes (depth_planes.h) on their own, run under
// ASan + UBSan by `make sanitize`. The eigen solve against Jacobi rotations; each point's plane
// against a brute-force fit over its patch's points (direct sums, Jacobi); degenerate patches
// (a line of points, too few points), holes and zero-coded pixels, flying pixels and segments
// on hand-made range images, the same bits on any thread count, and cancellation.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "pointviz/depth_planes.h"
#include "check.h"

using namespace pointviz;

namespace {

/// Eigenvalues (ascending) and the smallest's vector of a symmetric 3x3 by Jacobi rotations.
void jacobi(const double a6[6], double val[3], double vec[3]) {
    double a[3][3] = {{a6[0], a6[1], a6[2]}, {a6[1], a6[3], a6[4]}, {a6[2], a6[4], a6[5]}};
    double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int sweep = 0; sweep < 100; ++sweep) {
        double off = std::fabs(a[0][1]) + std::fabs(a[0][2]) + std::fabs(a[1][2]);
        if (off < 1e-300) break;
        for (int p = 0; p < 2; ++p)
            for (int q = p + 1; q < 3; ++q) {
                if (a[p][q] == 0) continue;
                double theta = (a[q][q] - a[p][p]) / (2 * a[p][q]);
                double t = (theta >= 0 ? 1 : -1) / (std::fabs(theta) + std::sqrt(theta * theta + 1));
                double c = 1 / std::sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < 3; ++k) {
                    double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - s * akq;
                    a[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; ++k) {
                    double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk;
                    a[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 3; ++k) {
                    double vkp = v[k][p], vkq = v[k][q];
                    v[k][p] = c * vkp - s * vkq;
                    v[k][q] = s * vkp + c * vkq;
                }
            }
    }
    int idx[3] = {0, 1, 2};
    std::sort(idx, idx + 3, [&](int x, int y) { return a[x][x] < a[y][y]; });
    for (int k = 0; k < 3; ++k) val[k] = a[idx[k]][idx[k]];
    for (int k = 0; k < 3; ++k) vec[k] = v[k][idx[0]];
}

double dot(const double *a, const double *b) { return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]; }

void test_smallest_eigen_matches_jacobi() {
    std::mt19937 g(3);
    std::normal_distribution<double> N;
    for (int t = 0; t < 2000; ++t) {
        // covariances of random flat point sets (a plane's: one small eigenvalue)
        double axes[3] = {1.0 + std::fabs(N(g)), 0.5 + std::fabs(N(g)), 1e-3 * std::fabs(N(g))};
        double a[6] = {0, 0, 0, 0, 0, 0};
        double u[3][3];
        for (int k = 0; k < 3; ++k)
            for (int i = 0; i < 3; ++i) u[k][i] = N(g);
        // Gram-Schmidt
        for (int k = 0; k < 3; ++k) {
            for (int j = 0; j < k; ++j) {
                double d = dot(u[k], u[j]);
                for (int i = 0; i < 3; ++i) u[k][i] -= d * u[j][i];
            }
            double l = std::sqrt(dot(u[k], u[k]));
            for (int i = 0; i < 3; ++i) u[k][i] /= l;
        }
        const int pairs[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
        for (int m = 0; m < 6; ++m)
            for (int k = 0; k < 3; ++k) a[m] += axes[k] * u[k][pairs[m][0]] * u[k][pairs[m][1]];
        double small, middle, vec[3], val[3], want[3];
        smallest_eigen(a, small, middle, vec);
        jacobi(a, val, want);
        CHECK(std::fabs(small - val[0]) < 1e-9, "case %d: smallest %g vs %g", t, small, val[0]);
        CHECK(std::fabs(middle - val[1]) < 1e-9, "case %d: middle %g vs %g", t, middle, val[1]);
        CHECK(std::fabs(std::fabs(dot(vec, want)) - 1.0) < 1e-6, "case %d: vector off by %g", t,
              std::fabs(dot(vec, want)));
    }
    // degenerate: a multiple of the identity (no smallest direction: NaN vector, middle 0 gap)
    double iso[6] = {2, 0, 0, 2, 0, 2};
    double small, middle, vec[3];
    smallest_eigen(iso, small, middle, vec);
    CHECK(std::fabs(small - 2.0) < 1e-12 && std::fabs(middle - 2.0) < 1e-12, "iso %g %g", small,
          middle);
    // a line's covariance (rank 1): smallest and middle 0, the plane undetermined
    double line[6] = {1, 1, 1, 1, 1, 1};
    smallest_eigen(line, small, middle, vec);
    CHECK(std::fabs(small) < 1e-12 && std::fabs(middle) < 1e-12, "line %g %g", small, middle);
}

/// A frame of h x w pixels seen from the origin: a tilted plane with noise, quantised depths.
struct Frame {
    size_t h, w;
    std::vector<double> pts, step;
    std::vector<int32_t> grid;
    size_t n() const { return step.size(); }
};

Frame plane_frame(size_t h, size_t w, unsigned seed, double holes, double zeros) {
    std::mt19937 g(seed);
    std::uniform_real_distribution<double> U(0, 1);
    std::normal_distribution<double> N;
    Frame f{h, w, {}, {}, {}};
    for (size_t r = 0; r < h; ++r)
        for (size_t c = 0; c < w; ++c) {
            if (U(g) < holes) continue;  // NaN hole: no point on the grid
            double x = (double(c) - double(w) / 2) / 150, y = (double(r) - double(h) / 2) / 150;
            double z = 2.0 + 0.4 * x - 0.3 * y + 0.002 * N(g);
            double q = 0.004 * z * z;
            z = std::round(z / q) * q;
            if (U(g) < zeros) {
                f.pts.insert(f.pts.end(), {0.0, 0.0, 0.0});  // zero-coded pixel
            } else {
                f.pts.insert(f.pts.end(), {x * z, y * z, z});
            }
            f.step.push_back(q);
            f.grid.insert(f.grid.end(), {int32_t(r), int32_t(c)});
        }
    return f;
}

void test_planes_match_brute_force_fits() {
    Frame f = plane_frame(48, 64, 5, 0.1, 0.03);
    const double vp[3] = {0, 0, 0};
    DepthPlaneOptions opt;
    opt.edges = false;  // square patches: each the seen points in the clipped window
    DepthPlaneResult r = depth_patch_planes(f.pts.data(), f.n(), f.grid.data(), vp, f.step.data(), opt);
    // brute force: the patch's points, centred on their own mean, Jacobi's smallest vector
    std::vector<long> at(f.h * f.w, -1);
    for (size_t i = 0; i < f.n(); ++i)
        if (f.pts[3 * i + 2] != 0) at[size_t(f.grid[2 * i]) * f.w + size_t(f.grid[2 * i + 1])] = long(i);
    size_t fitted = 0, moved = 0;
    for (size_t i = 0; i < f.n(); ++i) {
        const double *p = &f.pts[3 * i];
        double len = std::sqrt(dot(p, p));
        if (len == 0) {
            CHECK(r.radius[i] == 0, "zero-coded point %zu has radius %lld", i, (long long)r.radius[i]);
            continue;
        }
        double ray[3] = {p[0] / len, p[1] / len, p[2] / len};
        long rad = long(r.radius[i]);
        if (rad == 0) continue;
        ++fitted;
        std::vector<long> members;
        long row = f.grid[2 * i], col = f.grid[2 * i + 1];
        for (long y = std::max(0L, row - rad); y <= std::min(long(f.h) - 1, row + rad); ++y)
            for (long x = std::max(0L, col - rad); x <= std::min(long(f.w) - 1, col + rad); ++x)
                if (at[size_t(y) * f.w + size_t(x)] >= 0) members.push_back(at[size_t(y) * f.w + size_t(x)]);
        double mu[3] = {0, 0, 0};
        for (long m : members)
            for (int k = 0; k < 3; ++k) mu[k] += f.pts[3 * size_t(m) + k] / double(members.size());
        double cov[6] = {0, 0, 0, 0, 0, 0};
        const int pairs[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
        for (long m : members)
            for (int q = 0; q < 6; ++q)
                cov[q] += (f.pts[3 * size_t(m) + pairs[q][0]] - mu[pairs[q][0]]) *
                          (f.pts[3 * size_t(m) + pairs[q][1]] - mu[pairs[q][1]]) / double(members.size());
        double val[3], want[3];
        jacobi(cov, val, want);
        if (dot(want, ray) > 0)
            for (double &v : want) v = -v;
        double got[3] = {r.normals[3 * i], r.normals[3 * i + 1], r.normals[3 * i + 2]};
        CHECK(dot(got, ray) < 0, "point %zu: normal faces away", i);
        CHECK(std::fabs(dot(got, want) - 1.0) < 1e-6, "point %zu (r %ld): normal off, cos %.9f",
              i, rad, dot(got, want));
        // a moved point lies on its patch's plane
        const double *q = &r.points[3 * i];
        if (q[0] != p[0] || q[1] != p[1] || q[2] != p[2]) {
            ++moved;
            double d[3] = {q[0] - mu[0], q[1] - mu[1], q[2] - mu[2]};
            CHECK(std::fabs(dot(d, want)) < 1e-9, "point %zu: %g off its plane", i, dot(d, want));
        }
    }
    CHECK(fitted > f.n() / 2 && moved > f.n() / 4, "fitted %zu, moved %zu of %zu", fitted, moved, f.n());
}

void test_degenerate_patches_and_holes_give_finite_output() {
    const double vp[3] = {0, 0, 0};
    for (bool edges : {true, false}) {
        DepthPlaneOptions opt;
        opt.edges = edges;
        // one row: every patch lies in the plane y = 0, which holds the camera (edge-on): a
        // plane found there is that one, and no point moves along its ray onto it
        Frame f{1, 200, {}, {}, {}};
        for (int c = 0; c < 200; ++c) {
            double x = (c - 100) / 150.0, z = 2.0 + 0.01 * (c % 3);
            f.pts.insert(f.pts.end(), {x * z, 0.0, z});
            f.step.push_back(0.01);
            f.grid.insert(f.grid.end(), {0, c});
        }
        DepthPlaneResult r = depth_patch_planes(f.pts.data(), f.n(), f.grid.data(), vp, f.step.data(), opt);
        for (size_t i = 0; i < f.n(); ++i) {
            const double *p = &f.pts[3 * i];
            for (int k = 0; k < 3; ++k) CHECK(r.points[3 * i + k] == p[k], "one row: point %zu moved", i);
            if (r.radius[i] > 0)
                CHECK(std::fabs(std::fabs(r.normals[3 * i + 1]) - 1.0) < 1e-6, "one row: normal %zu", i);
        }
        // points on one line through the camera (every patch a line: no plane): unmoved, no
        // radius, the normal toward the camera
        Frame l{10, 20, {}, {}, {}};
        for (int i = 0; i < 200; ++i) {
            double z = 1.0 + 0.01 * double(i % 37);
            l.pts.insert(l.pts.end(), {0.1 * z, 0.2 * z, z});
            l.step.push_back(0.01);
            l.grid.insert(l.grid.end(), {i / 20, i % 20});
        }
        r = depth_patch_planes(l.pts.data(), l.n(), l.grid.data(), vp, l.step.data(), opt);
        for (size_t i = 0; i < l.n(); ++i) {
            const double *p = &l.pts[3 * i];
            double len = std::sqrt(dot(p, p));
            for (int k = 0; k < 3; ++k) {
                CHECK(std::isfinite(r.normals[3 * i + k]), "line: normal %zu not finite", i);
                if (r.radius[i] == 0)
                    CHECK(std::fabs(r.normals[3 * i + k] + p[k] / len) < 1e-6, "line: normal %zu", i);
                CHECK(std::fabs(r.points[3 * i + k] - p[k]) < 1e-9, "line: point %zu moved", i);
            }
        }
        // holes (points missing from the grid), zero-coded pixels, points far beyond the
        // doubles' squares, a lone point: finite output everywhere
        Frame h = plane_frame(30, 40, 9, 0.4, 0.2);
        for (size_t i = 0; i < h.n(); i += 13)
            for (int k = 0; k < 3; ++k) h.pts[3 * i + k] *= 1e160;
        r = depth_patch_planes(h.pts.data(), h.n(), h.grid.data(), vp, h.step.data(), opt);
        for (size_t i = 0; i < h.n(); ++i) {
            bool unseen = h.pts[3 * i + 2] == 0 || std::fabs(h.pts[3 * i + 2]) > 1e100;
            for (int k = 0; k < 3; ++k) {
                CHECK(std::isfinite(r.points[3 * i + k]), "holes: point %zu not finite", i);
                CHECK(std::isfinite(r.normals[3 * i + k]), "holes: normal %zu not finite", i);
                if (unseen) CHECK(r.points[3 * i + k] == h.pts[3 * i + k], "unseen %zu moved", i);
            }
            if (unseen) CHECK(r.radius[i] == 0 && !r.flying[i], "unseen %zu fitted", i);
        }
        double lone[3] = {0.1, 0.2, 2.0}, step = 0.01;
        int32_t cell[2] = {3, 4};
        r = depth_patch_planes(lone, 1, cell, vp, &step, opt);
        CHECK(r.radius[0] == 0 && r.points[2] == 2.0, "lone point fitted");
    }
}

void test_flying_pixels_and_segments() {
    // a row of a near surface (1 m) and a far one (3 m), one pixel in mid-air between them
    const size_t h = 5, w = 12;
    std::vector<double> R(h * w), J(h * w, 0.05);
    for (size_t y = 0; y < h; ++y)
        for (size_t x = 0; x < w; ++x) R[y * w + x] = x < 6 ? 1.0 + 0.001 * double(x) : 3.0;
    for (size_t y = 0; y < h; ++y) R[y * w + 6] = 2.0;  // the mixed pixels
    std::vector<uint8_t> fly = depth_flying_pixels(R.data(), J.data(), h, w, 2);
    for (size_t y = 0; y < h; ++y)
        for (size_t x = 0; x < w; ++x)
            CHECK(fly[y * w + x] == (x == 6), "pixel (%zu, %zu): flying %d", y, x, fly[y * w + x]);
    // a NaN hole two pixels wide next to the edge: no pixel flies for want of a neighbour
    std::vector<double> R2 = R;
    for (size_t y = 0; y < h; ++y) R2[y * w + 4] = R2[y * w + 5] = NAN;
    fly = depth_flying_pixels(R2.data(), J.data(), h, w, 1);
    for (size_t y = 0; y < h; ++y) CHECK(!fly[y * w + 6], "row %zu: flies across a hole", y);
    // segments: without the mixed column, two (near, far); with it valid, three
    std::vector<uint8_t> valid(h * w, 1);
    for (size_t y = 0; y < h; ++y) valid[y * w + 6] = 0;
    std::vector<int32_t> labels;
    size_t count = depth_segment_labels(R.data(), J.data(), valid.data(), h, w, labels);
    CHECK(count == 2, "segments %zu", count);
    CHECK(labels[0] == 0 && labels[w - 1] == 1 && labels[6] == -1, "labels %d %d %d", labels[0],
          labels[w - 1], labels[6]);
    std::fill(valid.begin(), valid.end(), 1);
    count = depth_segment_labels(R.data(), J.data(), valid.data(), h, w, labels);
    CHECK(count == 3, "segments with the mixed column %zu", count);
}

void test_same_bits_on_any_thread_count_and_cancel() {
    Frame f = plane_frame(60, 80, 2, 0.1, 0.02);
    const double vp[3] = {0.01, -0.02, 0.0};
    for (bool edges : {true, false}) {
        DepthPlaneOptions one, many;
        one.edges = many.edges = edges;
        one.threads = 1;
        many.threads = 3;
        DepthPlaneResult a = depth_patch_planes(f.pts.data(), f.n(), f.grid.data(), vp, f.step.data(), one);
        DepthPlaneResult b = depth_patch_planes(f.pts.data(), f.n(), f.grid.data(), vp, f.step.data(), many);
        CHECK(a.points == b.points && a.normals == b.normals && a.radius == b.radius &&
                  a.flying == b.flying, "edges %d: threads change the result", int(edges));
        Progress progress;
        progress.cancel = true;
        bool thrown = false;
        try {
            depth_patch_planes(f.pts.data(), f.n(), f.grid.data(), vp, f.step.data(), many, &progress);
        } catch (const Cancelled &) {
            thrown = true;
        }
        CHECK(thrown, "edges %d: not cancelled", int(edges));
    }
}

}  // namespace

int main() {
    test_smallest_eigen_matches_jacobi();
    test_planes_match_brute_force_fits();
    test_degenerate_patches_and_holes_give_finite_output();
    test_flying_pixels_and_segments();
    test_same_bits_on_any_thread_count_and_cancel();
    std::printf("depth_tests: %d checks, %d failures\n", pointviz_tests::g_checks,
                pointviz_tests::g_failures);
    return pointviz_tests::g_failures == 0 ? 0 : 1;
}
