// pointviz — tests of the preprocessing core (knn.h, scan_neighbours.h, normals.h, orient.h,
// radii.h, surface_fit.h) on their own, run under ASan + UBSan by `make sanitize`. Neighbours are checked against brute force over all points; every
// step must give the same result on any thread count, stop with Cancelled once cancelled, and
// give finite output on degenerate input (duplicates, a line, fewer points than neighbours).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <numeric>
#include <random>
#include <stdexcept>
#include <vector>

#include "pointviz/dispatch.h"
#include "pointviz/knn_kernels.h"
#include "pointviz/pca.h"
#include "pointviz/preprocess.h"
#include "pointviz/radii.h"
#include "pointviz/scan_neighbours.h"
#include "pointviz/surface_fit.h"
#include "check.h"

using namespace pointviz;

namespace {

std::vector<double> sphere_points(size_t n, unsigned seed, double noise = 0.0) {
    std::mt19937 g(seed);
    std::normal_distribution<double> N;
    std::vector<double> p(3 * n);
    for (size_t i = 0; i < n; ++i) {
        double x = N(g), y = N(g), z = N(g), l = std::sqrt(x * x + y * y + z * z);
        double r = 1.0 + noise * N(g);
        p[3 * i] = r * x / l, p[3 * i + 1] = r * y / l, p[3 * i + 2] = r * z / l;
    }
    return p;
}

double d2(const double *a, const double *b) {
    return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
           (a[2] - b[2]) * (a[2] - b[2]);
}

/// Brute force: the k nearest other points by (distance, index); with `group`, among the points
/// of i's group only (the oracle of the within-scan searches).
std::vector<uint32_t> brute_row(const std::vector<double> &p, size_t i, uint32_t k,
                                const std::vector<int32_t> *group = nullptr) {
    size_t n = p.size() / 3;
    std::vector<uint32_t> idx;
    for (size_t j = 0; j < n; ++j)
        if (j != i && (!group || (*group)[j] == (*group)[i])) idx.push_back(uint32_t(j));
    std::sort(idx.begin(), idx.end(), [&](uint32_t a, uint32_t b) {
        double da = d2(&p[3 * i], &p[3 * size_t(a)]), db = d2(&p[3 * i], &p[3 * size_t(b)]);
        return da < db || (da == db && a < b);
    });
    idx.resize(std::min<size_t>(k, idx.size()));
    return idx;
}

void test_knn_matches_brute_force() {
    for (unsigned seed = 0; seed < 3; ++seed) {
        std::vector<double> p = sphere_points(700, seed);
        // duplicates and a grid's equal distances
        for (int c = 0; c < 20; ++c) p.insert(p.end(), p.begin(), p.begin() + 3);
        for (int x = 0; x < 5; ++x)
            for (int y = 0; y < 5; ++y) p.insert(p.end(), {3.0 + x, 3.0 + y, 0.0});
        size_t n = p.size() / 3;
        for (uint32_t k : {1u, 8u, 15u, 31u, 33u}) {
            KnnTree tree(p.data(), n, 2);
            NeighbourTable t = knn_all(tree, p.data(), k, 3);
            size_t bad = 0;
            for (size_t i = 0; i < n; ++i) {
                std::vector<uint32_t> want = brute_row(p, i, k);
                bad += !std::equal(want.begin(), want.end(), t.row(i));
            }
            CHECK(bad == 0, "seed %u k %u: %zu rows differ from brute force", seed, k, bad);
        }
    }
}

/// knn_each unsorted: each row holds brute force's neighbours (as a set); and the radii measured
/// from it as the neighbours are found are the radii of the stored table, bit for bit.
void test_unsorted_rows_and_fused_radii() {
    std::vector<double> p = sphere_points(900, 5, 0.02);
    for (int c = 0; c < 12; ++c) p.insert(p.end(), p.begin(), p.begin() + 3);  // duplicates
    size_t n = p.size() / 3;
    std::vector<float> nrm(3 * n);
    for (size_t i = 0; i < 3 * n; ++i) nrm[i] = float(p[i]);
    KnnTree tree(p.data(), n, 2);
    for (uint32_t k : {1u, 10u, 33u}) {
        std::vector<std::vector<uint32_t>> rows(n);
        knn_each(tree, p.data(), k, false, 3, nullptr, [&](uint32_t i, const uint32_t *row) {
            rows[i].assign(row, row + k);
        });
        size_t bad = 0;
        for (size_t i = 0; i < n; ++i) {
            std::vector<uint32_t> want = brute_row(p, i, k), got = rows[i];
            std::sort(want.begin(), want.end());
            std::sort(got.begin(), got.end());
            bad += want != got;
        }
        CHECK(bad == 0, "k %u: %zu unsorted rows differ from brute force's sets", k, bad);
        CoverOptions co;
        for (int threads : {1, 3}) {
            co.threads = threads;
            NeighbourTable t = knn_all(tree, p.data(), k, threads);
            std::vector<float> want = coverage_radii(p.data(), nrm.data(), t, co);
            std::vector<float> got = coverage_radii(p.data(), nrm.data(), tree, k, co);
            CHECK(got.size() == n && std::memcmp(got.data(), want.data(), 4 * n) == 0,
                  "k %u, %d threads: the fused radii differ from the table's", k, threads);
        }
    }
}

/// coverage_radii_from_rows with a table on the same positions as the radii (nothing moved):
/// every member's k nearest members lie in its row wherever the row holds k members, so the
/// radii equal coverage_radii of the members alone, bit for bit, for any thread count; members
/// whose rows hold fewer are searched (none of the whole cloud's, some of every fifth point's).
void test_radii_from_rows_equal_the_members_own() {
    std::vector<double> p = sphere_points(1500, 9, 0.01);
    for (int c = 0; c < 4; ++c) p.insert(p.end(), p.begin(), p.begin() + 3);  // duplicates
    const size_t n = p.size() / 3;
    std::vector<float> nrm(3 * n);
    for (size_t i = 0; i < 3 * n; ++i) nrm[i] = float(p[i]);
    KnnTree tree(p.data(), n, 2);
    NeighbourTable rows = knn_all(tree, p.data(), 31, 2);
    for (int every : {1, 2, 5}) {
        std::vector<uint8_t> member(n);
        std::vector<double> sub;
        std::vector<float> sub_n;
        for (size_t i = 0; i < n; ++i) {
            member[i] = i % every == 0;
            if (!member[i]) continue;
            sub.insert(sub.end(), p.begin() + 3 * i, p.begin() + 3 * i + 3);
            sub_n.insert(sub_n.end(), nrm.begin() + 3 * i, nrm.begin() + 3 * i + 3);
        }
        const size_t m = sub.size() / 3;
        KnnTree sub_tree(sub.data(), m, 2);
        CoverOptions co;
        const std::vector<float> want = coverage_radii(sub.data(), sub_n.data(), sub_tree, 10, co);
        for (int threads : {1, 3}) {
            co.threads = threads;
            RowRadii got = coverage_radii_from_rows(p.data(), nrm.data(), n, member.data(), rows,
                                                    10, co);
            CHECK(got.radii.size() == m &&
                      std::memcmp(got.radii.data(), want.data(), 4 * m) == 0,
                  "every %d, %d threads: the rows' radii differ from the members' own", every,
                  threads);
            CHECK((every == 1 ? got.searched == 0 : every < 5 || got.searched > 0) &&
                      got.searched < m,
                  "every %d: %zu of %zu members searched", every, got.searched, m);
        }
    }
}

void test_knn_within_groups_matches_brute_force() {
    // three interleaved "scans" of one sphere and a scan of 5 points (fewer than k + 1: its
    // points take their neighbours among all points); the scans numbered 0-2 and 7, or by
    // numbers far apart (negative, up to INT32_MAX: a sparse range)
    std::vector<double> p = sphere_points(1500, 11, 0.02);
    size_t n = p.size() / 3;
    const int32_t dense[4] = {0, 1, 2, 7};
    const int32_t sparse[4] = {-2000000000, 5, 2000000000, 2147483647};
    for (const int32_t *number : {dense, sparse}) {
        std::vector<int32_t> group(n);
        for (size_t i = 0; i < n; ++i) group[i] = i < 5 ? number[3] : number[i % 3];
        const uint32_t k = 12;
        KnnTree all(p.data(), n, 2);
        decltype(NeighbourTable::index) ref;
        for (int threads : {1, 3}) {
            NeighbourTable t = knn_within_groups(p.data(), n, group.data(), k, all, threads);
            CHECK(t.n == n && t.k == k, "table shape");
            if (threads == 1) {
                ref = t.index;
            } else {
                CHECK(t.index == ref, "within-group neighbours differ at %d threads", threads);
            }
        }
        size_t bad = 0;
        for (size_t i = 0; i < n; ++i) {
            std::vector<uint32_t> want;
            if (i < 5) {
                want = brute_row(p, i, k);
            } else {
                want = brute_row(p, i, k, &group);  // over the same group only
            }
            bad += !std::equal(want.begin(), want.end(), ref.begin() + i * k);
        }
        CHECK(bad == 0, "within-group neighbours (scans %d ...): %zu of %zu rows differ from "
              "brute force", number[0], bad, n);
    }
}

/// A scan of the smooth surface z = 0.3 sin(1.3 x) + 0.2 x y on a sheared grid with 2.5x the
/// spacing along rows as along columns (a surface seen obliquely): points, their cells.
void grid_scan(int rows, int cols, double x0, double y0, std::vector<double> &p,
               std::vector<int32_t> &cell, std::vector<int32_t> &group, int32_t g) {
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
            double x = x0 + 0.01 * c + 0.004 * r, y = y0 + 0.025 * r;
            p.insert(p.end(), {x, y, 0.3 * std::sin(1.3 * x) + 0.2 * x * y});
            cell.insert(cell.end(), {r, c});
            group.push_back(g);
        }
}

void test_grid_neighbours_match_brute_force_within_scan() {
    // two overlapping scans of one surface (different grids), a third whose points have no
    // cells, a fourth with two points in one cell (not a grid: searched in its tree), and a
    // group of 5 points (neighbours among all points); stored in a shuffled order
    std::vector<double> p0;
    std::vector<int32_t> c0, g0;
    grid_scan(40, 50, 0.0, 0.0, p0, c0, g0, 0);
    grid_scan(30, 45, 0.003, 0.011, p0, c0, g0, 1);
    grid_scan(12, 12, 0.1, 0.1, p0, c0, g0, 2);
    grid_scan(12, 12, 0.2, 0.1, p0, c0, g0, 3);
    size_t n = g0.size();
    for (size_t i = 0; i < n; ++i) {
        if (g0[i] == 2) c0[2 * i] = c0[2 * i + 1] = -1;
        if (g0[i] == 3 && c0[2 * i] == 5 && c0[2 * i + 1] == 6) c0[2 * i + 1] = 7;
    }
    for (size_t i = 0; i < 5; ++i) {  // the small group
        p0.insert(p0.end(), {0.5 + 0.01 * i, 0.3, 0.2});
        c0.insert(c0.end(), {0, int32_t(i)});
        g0.push_back(9);
    }
    n = g0.size();
    std::vector<size_t> order(n);
    std::iota(order.begin(), order.end(), size_t(0));
    std::shuffle(order.begin(), order.end(), std::mt19937(5));
    std::vector<double> p(3 * n);
    std::vector<int32_t> cell(2 * n), group(n);
    for (size_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a) p[3 * i + a] = p0[3 * order[i] + a];
        for (int a = 0; a < 2; ++a) cell[2 * i + a] = c0[2 * order[i] + a];
        group[i] = g0[order[i]];
    }
    const uint32_t k = 31;
    KnnTree all(p.data(), n, 2);
    decltype(NeighbourTable::index) ref;
    GridNeighbourStats st;
    for (int threads : {1, 2, 3}) {
        NeighbourTable t = knn_within_grids(p.data(), n, group.data(), cell.data(), nullptr, 0,
                                            k, all, threads, nullptr, &st);
        CHECK(t.n == n && t.k == k, "grid table shape");
        if (threads == 1)
            ref = t.index;
        else
            CHECK(t.index == ref, "grid neighbours differ at %d threads", threads);
    }
    CHECK(st.from_grid + st.from_tree == n - 5, "grid stats: %zu + %zu of %zu", st.from_grid,
          st.from_tree, n - 5);
    // the grids' borders (a quarter of these small grids' points) may need more rings
    CHECK(st.from_tree >= 2 * 144 && st.from_grid > (n - 5 - 2 * 144) * 8 / 10,
          "grid stats: %zu from the grid, %zu from trees", st.from_grid, st.from_tree);
    size_t bad = 0;
    for (size_t i = 0; i < n; ++i) {
        std::vector<uint32_t> want = group[i] == 9 ? brute_row(p, i, k) : brute_row(p, i, k, &group);
        bad += !std::equal(want.begin(), want.end(), ref.begin() + i * k);
    }
    CHECK(bad == 0, "grid neighbours: %zu of %zu rows differ from brute force within the scan",
          bad, n);
    // the normals from them equal those of the per-scan KD-trees
    PointsView v;
    v.points = p.data();
    v.n = n;
    v.group = group.data();
    double eye[3] = {0.3, 0.3, 5.0};
    v.viewpoints = eye;
    v.n_viewpoints = 1;
    Progress pr;
    NormalOptions no;
    OrientOptions oo;
    NormalsOutput a = normals_points(v, no, oo, pr);
    v.cell = cell.data();
    NormalsOutput b = normals_points(v, no, oo, pr);
    CHECK(a.est.normals == b.est.normals, "normals from grid neighbours differ from the trees'");
    CHECK(b.grid.from_grid == st.from_grid, "normals' grid stats %zu, expected %zu",
          b.grid.from_grid, st.from_grid);
}

/// A range scan from `eye` looking at the origin: a grid of rays (rows x cols, `dr` and `dc`
/// radians apart) cast at a unit sphere in front of the plane z = -1.6 (a depth jump at the
/// sphere's outline); rays that hit neither (beyond |x|, |y| < 2.5) give no point. Depth noise
/// of `noise` along the rays. Appends the points, their group and viewpoint.
void ray_scan(const double eye[3], int rows, int cols, double dr, double dc, double noise,
              unsigned seed, int32_t g, std::vector<double> &p, std::vector<int32_t> &group,
              std::vector<double> &view) {
    double w[3] = {-eye[0], -eye[1], -eye[2]};
    double wl = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
    for (double &c : w) c /= wl;
    double u[3] = {w[1] * 0.3 - w[2] * 0.5, w[2] * 0.2 - w[0] * 0.3, w[0] * 0.5 - w[1] * 0.2};
    double ul = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
    for (double &c : u) c /= ul;
    double v[3] = {w[1] * u[2] - w[2] * u[1], w[2] * u[0] - w[0] * u[2], w[0] * u[1] - w[1] * u[0]};
    std::mt19937 gen(seed);
    std::normal_distribution<double> N;
    for (int r = 0; r < rows; ++r)
        for (int c = 0; c < cols; ++c) {
            double a = (r - rows / 2) * dr, b = (c - cols / 2) * dc;  // angles: a spherical grid
            double d[3];
            for (int x = 0; x < 3; ++x)
                d[x] = std::cos(a) * std::cos(b) * w[x] + std::sin(a) * u[x] +
                       std::cos(a) * std::sin(b) * v[x];
            double ed = d[0] * eye[0] + d[1] * eye[1] + d[2] * eye[2];
            double ee = eye[0] * eye[0] + eye[1] * eye[1] + eye[2] * eye[2];
            double disc = ed * ed - (ee - 1.0), s = -1;
            if (disc > 0) s = -ed - std::sqrt(disc);
            if (s <= 0 && d[2] < 0) {
                s = (-1.6 - eye[2]) / d[2];
                if (std::fabs(eye[0] + s * d[0]) > 2.5 || std::fabs(eye[1] + s * d[1]) > 2.5)
                    s = -1;
            }
            if (s <= 0) continue;
            s += noise * N(gen);
            for (int x = 0; x < 3; ++x) p.push_back(eye[x] + s * d[x]);
            group.push_back(g);
            view.insert(view.end(), eye, eye + 3);
        }
}

void test_view_grid_neighbours_match_brute_force() {
    // scans of a sphere before a plane (a depth jump) from four scanners, with and without
    // noise; one samples 3x as densely along one axis as along the other (cells hold several
    // points); and a cylinder seen from its axis (its points all around their scanner: no grid,
    // its KD-tree); stored in a shuffled order
    std::vector<double> p0, v0;
    std::vector<int32_t> g0;
    const double e0[3] = {0.4, -0.3, 4.0}, e1[3] = {-2.5, 1.0, 2.5}, e2[3] = {1.5, 2.0, 3.0},
                 e3[3] = {5.0, 5.0, 0.0};
    ray_scan(e0, 48, 48, 0.016, 0.016, 0.0, 1, 0, p0, g0, v0);
    ray_scan(e1, 40, 44, 0.014, 0.016, 0.004, 2, 1, p0, g0, v0);
    ray_scan(e2, 24, 72, 0.027, 0.009, 0.002, 3, 2, p0, g0, v0);
    for (int r = 0; r < 12; ++r)  // a cylinder around its scanner at e3
        for (int c = 0; c < 60; ++c) {
            double t = 0.1047 * c;
            p0.insert(p0.end(), {e3[0] + std::cos(t), e3[1] + std::sin(t), e3[2] + 0.1 * r});
            g0.push_back(3);
            v0.insert(v0.end(), e3, e3 + 3);
        }
    for (size_t i = 0; i < 5; ++i) {  // a group of 5 points: neighbours among all points
        p0.insert(p0.end(), {0.5 + 0.01 * i, 0.3, 1.2});
        g0.push_back(9);
        v0.insert(v0.end(), e0, e0 + 3);
    }
    size_t n = g0.size();
    std::vector<size_t> order(n);
    std::iota(order.begin(), order.end(), size_t(0));
    std::shuffle(order.begin(), order.end(), std::mt19937(6));
    std::vector<double> p(3 * n), view(3 * n);
    std::vector<int32_t> group(n);
    for (size_t i = 0; i < n; ++i) {
        for (int a = 0; a < 3; ++a) p[3 * i + a] = p0[3 * order[i] + a];
        for (int a = 0; a < 3; ++a) view[3 * i + a] = v0[3 * order[i] + a];
        group[i] = g0[order[i]];
    }
    size_t scan3 = std::count(group.begin(), group.end(), 3);
    KnnTree all(p.data(), n, 2);
    for (uint32_t k : {15u, 31u}) {
        decltype(NeighbourTable::index) ref;
        GridNeighbourStats st;
        for (int threads : {1, 2, 3}) {
            NeighbourTable t = knn_within_grids(p.data(), n, group.data(), nullptr, view.data(),
                                                n, k, all, threads, nullptr, &st);
            CHECK(t.n == n && t.k == k, "view grid table shape");
            if (threads == 1)
                ref = t.index;
            else
                CHECK(t.index == ref, "view grid neighbours differ at %d threads", threads);
        }
        CHECK(st.from_grid == 0 && st.from_view + st.from_tree == n - 5,
              "k %u view grid stats: %zu + %zu + %zu of %zu", k, st.from_grid, st.from_view,
              st.from_tree, n - 5);
        // the close scanner's scan is searched in its tree; of the others, only points seen
        // nearly edge-on
        CHECK(st.from_tree >= scan3 && st.from_view > (n - 5 - scan3) * 8 / 10,
              "k %u: %zu from view grids, %zu from trees (%zu in the wide scan)", k,
              st.from_view, st.from_tree, scan3);
        size_t bad = 0;
        for (size_t i = 0; i < n; ++i) {
            std::vector<uint32_t> want =
                group[i] == 9 ? brute_row(p, i, k) : brute_row(p, i, k, &group);
            bad += !std::equal(want.begin(), want.end(), ref.begin() + i * k);
        }
        CHECK(bad == 0, "k %u view grid: %zu of %zu rows differ from brute force within the scan",
              k, bad, n);
        // one viewpoint for all points: every scan binned from it (one row of viewpoints)
        NeighbourTable one = knn_within_grids(p.data(), n, group.data(), nullptr, e0, 1, k, all,
                                              2, nullptr, &st);
        CHECK(one.index == ref, "k %u: neighbours from one viewpoint differ", k);
        CHECK(st.from_view > 0, "k %u: no view grid from a single viewpoint", k);
        // rows taken from the neighbours across scans where they hold k of the point's own
        // scan: the same table; with k_least < k, shorter rows that are its rows' prefixes
        NeighbourTable across = knn_all(all, p.data(), 2 * k, 2);
        for (int threads : {1, 2}) {
            ScanRows same = knn_within_grids_reusing(p.data(), n, group.data(), nullptr,
                                                     view.data(), n, k, k, across, all, threads);
            CHECK(same.table.index == ref, "k %u: reused rows differ from the search's", k);
            CHECK(same.reused > n / 4 && std::count(same.count.begin(), same.count.end(), k) ==
                                             ptrdiff_t(n),
                  "k %u: %zu rows reused", k, same.reused);
            ScanRows part = knn_within_grids_reusing(p.data(), n, group.data(), nullptr,
                                                     view.data(), n, k, 7, across, all, threads);
            size_t short_rows = 0, wrong = 0;
            for (size_t i = 0; i < n; ++i) {
                uint32_t c = part.count[i];
                short_rows += c < k;
                wrong += c < 7 || !std::equal(ref.begin() + i * k, ref.begin() + i * k + c,
                                              part.table.index.begin() + i * k);
            }
            CHECK(wrong == 0 && short_rows > 0 && part.reused >= same.reused,
                  "k %u: %zu partly reused rows wrong, %zu short", k, wrong, short_rows);
            // normals over rows of given lengths: full lengths change nothing; a shorter row
            // is fitted up to its length
            NormalOptions nopt;
            nopt.k_max = k + 1;
            nopt.threads = threads;
            NormalResult plain = estimate_normals(p.data(), same.table, nopt);
            NormalResult full =
                estimate_normals(p.data(), same.table, nopt, nullptr, same.count.data());
            CHECK(plain.normals == full.normals && plain.support == full.support,
                  "k %u: normals over full-length rows differ", k);
            NormalResult shorter =
                estimate_normals(p.data(), part.table, nopt, nullptr, part.count.data());
            size_t over = 0, bad_normal = 0;
            for (size_t i = 0; i < n; ++i) {
                over += shorter.support[i] > part.count[i] + 1;
                const float *q = &shorter.normals[3 * i];
                bad_normal += !(std::fabs(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] - 1.f) < 1e-4f);
            }
            CHECK(over == 0 && bad_normal == 0, "k %u: short rows: %zu supports too large, %zu "
                  "bad normals", k, over, bad_normal);
        }
    }
}

void test_tiny_clouds() {
    double one[3] = {1, 2, 3};
    KnnTree t1(one, 1);
    NeighbourTable a = knn_all(t1, one, 8, 1);
    CHECK(a.k == 0 && a.index.empty(), "one point: %u columns", a.k);
    double two[6] = {0, 0, 0, 1, 0, 0};
    KnnTree t2(two, 2);
    NeighbourTable b = knn_all(t2, two, 8, 1);
    CHECK(b.k == 1 && b.row(0)[0] == 1 && b.row(1)[0] == 0, "two points: k %u", b.k);
    KnnTree t0(nullptr, 0);
    CHECK(t0.size() == 0, "empty tree");
}

/// The stray clusters against an oracle written here: each point's spacing (the rank-th nearest
/// distinct neighbour of its own scan in its row, else the farthest listed), links as
/// distance <= reach x the smaller spacing (the rooted distance compared), components by a
/// breadth-first search, numbered by their first point. On one thread the links are tested as
/// the union-find meets them (no table), on more they are tabled first: both must be the
/// oracle's. A square grid of unit spacing puts many neighbours at exactly 3 = reach x spacing
/// (the boundary, where comparing squares instead of roots could differ), beside small clusters
/// and isolated points.
void test_stray_clusters_match_an_oracle() {
    std::vector<double> p;
    std::vector<int32_t> group;
    for (int y = 0; y < 40; ++y)
        for (int x = 0; x < 40; ++x) {
            p.insert(p.end(), {double(x), double(y), 0.0});
            group.push_back(y < 20 ? 0 : 1);  // two scans side by side
        }
    std::mt19937 g(5);
    std::uniform_real_distribution<double> U(-0.5, 0.5);
    for (int c = 0; c < 6; ++c)  // small clusters 10 + 4c away from the grid
        for (int j = 0; j < 5 + 3 * c; ++j) {
            p.insert(p.end(), {60.0 + 4.0 * c + 0.4 * U(g), 10.0 + 0.4 * U(g), 0.1 * U(g)});
            group.push_back(2);
        }
    for (int j = 0; j < 8; ++j) {  // isolated points, and duplicates of a grid point
        p.insert(p.end(), {-20.0 - 7.0 * j, -20.0, 3.0 * j});
        group.push_back(3);
    }
    for (int j = 0; j < 3; ++j) {
        p.insert(p.end(), {5.0, 5.0, 0.0});
        group.push_back(1);
    }
    const size_t n = p.size() / 3;
    KnnTree tree(p.data(), n, 1);
    NeighbourTable t = knn_all(tree, p.data(), 31, 1);
    StrayOptions so;
    // oracle
    std::vector<double> spacing(n, 0.0);
    for (size_t i = 0; i < n; ++i) {
        uint32_t own = 0;
        for (uint32_t m = 0; m < t.k && own < so.rank; ++m) {
            const uint32_t j = t.row(i)[m];
            const double d = std::sqrt(d2(&p[3 * i], &p[3 * size_t(j)]));
            if (d > 0) spacing[i] = d;
            if (d > 0 && group[j] == group[i]) ++own;
        }
    }
    std::vector<std::vector<uint32_t>> adj(n);
    size_t at_boundary = 0;
    for (size_t i = 0; i < n; ++i)
        for (uint32_t m = 0; m < t.k; ++m) {
            const uint32_t j = t.row(i)[m];
            const double d = std::sqrt(d2(&p[3 * i], &p[3 * size_t(j)]));
            const double limit = so.reach * std::min(spacing[i], spacing[j]);
            at_boundary += d == limit;
            if (d <= limit) adj[i].push_back(j), adj[j].push_back(uint32_t(i));
        }
    std::vector<uint32_t> label(n, kNoIndex), size;
    for (size_t s = 0; s < n; ++s) {
        if (label[s] != kNoIndex) continue;
        const uint32_t c = uint32_t(size.size());
        size.push_back(0);
        std::vector<uint32_t> queue{uint32_t(s)};
        label[s] = c;
        for (size_t q = 0; q < queue.size(); ++q) {
            ++size[c];
            for (uint32_t j : adj[queue[q]])
                if (label[j] == kNoIndex) label[j] = c, queue.push_back(j);
        }
    }
    const size_t largest = size_t(std::max_element(size.begin(), size.end()) - size.begin());
    const double below = std::max(double(so.min_points), so.fraction * double(n));
    CHECK(at_boundary > 1000, "stray oracle: %zu links exactly at the reach", at_boundary);
    CHECK(size.size() >= 8, "stray oracle: %zu components", size.size());
    for (int threads : {1, 3}) {
        so.threads = threads;
        StrayResult r = find_stray_clusters(p.data(), t, group.data(), so);
        CHECK(r.label == label && r.components == size.size(),
              "%d threads: components differ from the oracle's (%zu vs %zu)", threads,
              r.components, size.size());
        size_t wrong = 0;
        for (size_t i = 0; i < n; ++i)
            wrong += r.stray[i] != uint8_t(label[i] != largest && double(size[label[i]]) < below);
        CHECK(wrong == 0, "%d threads: %zu points' stray flag differs from the oracle's", threads,
              wrong);
    }
}

/// The smallest eigenvector of a symmetric 3x3 matrix by Jacobi rotations (the oracle of the
/// normals' closed-form solve).
void jacobi_smallest(double a[3][3], double out[3]) {
    double v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
    for (int sweep = 0; sweep < 50; ++sweep)
        for (int p = 0; p < 3; ++p)
            for (int q = p + 1; q < 3; ++q) {
                if (std::fabs(a[p][q]) < 1e-300) continue;
                double th = (a[q][q] - a[p][p]) / (2 * a[p][q]);
                double t = (th >= 0 ? 1 : -1) / (std::fabs(th) + std::sqrt(th * th + 1));
                double c = 1 / std::sqrt(t * t + 1), s = t * c;
                for (int k = 0; k < 3; ++k) {  // A <- J^T A J, V <- V J
                    double akp = a[k][p], akq = a[k][q];
                    a[k][p] = c * akp - s * akq, a[k][q] = s * akp + c * akq;
                }
                for (int k = 0; k < 3; ++k) {
                    double apk = a[p][k], aqk = a[q][k];
                    a[p][k] = c * apk - s * aqk, a[q][k] = s * apk + c * aqk;
                }
                for (int k = 0; k < 3; ++k) {
                    double vkp = v[k][p], vkq = v[k][q];
                    v[k][p] = c * vkp - s * vkq, v[k][q] = s * vkp + c * vkq;
                }
            }
    int m = 0;
    for (int k = 1; k < 3; ++k)
        if (a[k][k] < a[m][m]) m = k;
    for (int k = 0; k < 3; ++k) out[k] = v[k][m];
}

/// NormalOptions::growth: the sizes tried are k_min, k_min x growth, ..., then k_max; each
/// point's normal is the weighted plane of the size it chose, checked against a Jacobi
/// eigen-solve of that neighbourhood's weighted covariance (weights (1 - d^2 / h^2)^2, h 1.5 x
/// the farthest member's distance, the point itself weight 1).
void test_normal_sizes_follow_the_growth() {
    std::vector<double> p = sphere_points(4000, 21, 0.002);
    const size_t n = p.size() / 3;
    KnnTree tree(p.data(), n, 1);
    NeighbourTable t = knn_all(tree, p.data(), 15, 1);
    for (double growth : {1.5, 2.0}) {
        NormalOptions no;
        no.k_min = 8, no.k_max = 16, no.growth = growth, no.threads = 2;
        NormalResult r = estimate_normals(p.data(), t, no);
        std::vector<size_t> seen(17, 0);
        size_t far = 0;
        for (size_t i = 0; i < n; ++i) {
            const uint32_t k = r.support[i];
            ++seen[std::min<uint32_t>(k, 16)];
            double h2 = 2.25 * d2(&p[3 * i], &p[3 * size_t(t.row(i)[k - 2])]);
            double s0 = 1, c[3] = {0, 0, 0}, a[3][3] = {};
            std::vector<double> w(k - 1);
            for (uint32_t m = 0; m + 1 < k; ++m) {
                const double *q = &p[3 * size_t(t.row(i)[m])];
                double u = 1 - d2(q, &p[3 * i]) / h2;
                w[m] = u * u, s0 += w[m];
                for (int x = 0; x < 3; ++x) c[x] += w[m] * (q[x] - p[3 * i + x]);
            }
            for (double &x : c) x /= s0;
            for (uint32_t m = 0; m <= k - 1; ++m) {  // m == k - 1: the point itself
                const double *q = m + 1 < k ? &p[3 * size_t(t.row(i)[m])] : &p[3 * i];
                const double wm = m + 1 < k ? w[m] : 1.0;
                double d[3];
                for (int x = 0; x < 3; ++x) d[x] = q[x] - p[3 * i + x] - c[x];
                for (int x = 0; x < 3; ++x)
                    for (int y = 0; y < 3; ++y) a[x][y] += wm * d[x] * d[y] / s0;
            }
            double e[3];
            jacobi_smallest(a, e);
            const float *nn = &r.normals[3 * i];
            far += std::fabs(e[0] * nn[0] + e[1] * nn[1] + e[2] * nn[2]) < 1 - 1e-6;
        }
        CHECK(far == 0, "growth %.1f: %zu normals off the Jacobi solve of their neighbourhood",
              growth, far);
        const bool twos = growth == 2.0;
        CHECK(seen[16] > 0 && (twos ? seen[12] == 0 : seen[12] > 0) &&
                  seen[8] + seen[12] + seen[16] == n,
              "growth %.1f: sizes 8 / 12 / 16 chosen %zu / %zu / %zu times of %zu", growth,
              seen[8], seen[12], seen[16], n);
    }
    bool threw = false;
    try {
        NormalOptions no;
        no.growth = 1.0;
        estimate_normals(p.data(), t, no);
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    CHECK(threw, "growth 1: expected invalid_argument");
}

void test_identical_for_any_thread_count() {
    std::vector<double> p = sphere_points(3000, 7, 0.01);
    PointsView v;
    v.points = p.data();
    v.n = p.size() / 3;
    double centre[3] = {0, 0, 0};
    std::vector<int32_t> group(v.n);
    for (size_t i = 0; i < v.n; ++i) group[i] = int32_t(i % 4);
    std::vector<float> ref_n, ref_r, ref_gn, ref_fr;
    std::vector<double> ref_p;
    std::vector<uint8_t> ref_keep;
    std::vector<uint32_t> ref_label;
    for (int threads : {1, 2, 4}) {
        Progress pr;
        NormalOptions no;
        no.threads = threads;
        OrientOptions oo;
        NormalsOutput nr = normals_points(v, no, oo, pr);
        CoverOptions co;
        co.threads = threads;
        std::vector<float> r = radii_points(v, nr.est.normals.data(), 10, co, pr);
        PointsView vv = v;
        vv.viewpoints = centre;
        vv.n_viewpoints = 1;
        FitOptions fo;
        fo.threads = threads;
        StrayOptions so;  // the stray clusters run beside the fit
        so.threads = threads;
        FitOutput f = fit_points(vv, nullptr, no, oo, fo, pr, &so, &co, 10);
        vv.group = group.data();  // normals from each scan's own neighbours
        NormalsOutput gn = normals_points(vv, no, oo, pr);
        if (threads == 1) {
            ref_n = nr.est.normals, ref_r = r, ref_p = f.fit.points, ref_gn = gn.est.normals;
            ref_keep = f.fit.keep, ref_label = f.stray.label, ref_fr = f.radii;
            size_t bad = 0;
            for (size_t i = 0; i < v.n; ++i)
                bad += f.fit.keep[i] ? !(f.radii[i] > 0 && std::isfinite(f.radii[i]))
                                     : f.radii[i] != 0;
            CHECK(f.radii.size() == v.n && bad == 0, "fit radii: %zu bad", bad);
            size_t outward = 0;
            for (size_t i = 0; i < v.n; ++i)
                outward += ref_n[3 * i] * p[3 * i] + ref_n[3 * i + 1] * p[3 * i + 1] +
                               ref_n[3 * i + 2] * p[3 * i + 2] > 0;
            CHECK(outward == v.n, "MST orientation: %zu of %zu outward", outward, v.n);
            bool finite = std::all_of(r.begin(), r.end(), [](float x) { return x > 0 && std::isfinite(x); });
            CHECK(finite, "radii must be positive and finite");
        } else {
            CHECK(nr.est.normals == ref_n, "normals differ at %d threads", threads);
            CHECK(r == ref_r, "radii differ at %d threads", threads);
            CHECK(f.fit.points == ref_p, "fitted points differ at %d threads", threads);
            CHECK(f.radii == ref_fr, "the fit's radii differ at %d threads", threads);
            CHECK(f.fit.keep == ref_keep && f.stray.label == ref_label,
                  "kept points or components differ at %d threads", threads);
            CHECK(gn.est.normals == ref_gn, "per-scan normals differ at %d threads", threads);
        }
    }
}

void test_cancel_stops_every_step() {
    std::vector<double> p = sphere_points(5000, 3);
    PointsView v;
    v.points = p.data();
    v.n = p.size() / 3;
    auto cancelled = [&](auto &&fn) {
        Progress pr;
        pr.cancel = true;
        try {
            fn(pr);
        } catch (const Cancelled &) {
            return true;
        }
        return false;
    };
    std::vector<float> nrm(3 * v.n, 0.f);
    for (size_t i = 0; i < v.n; ++i) nrm[3 * i + 2] = 1.f;
    CHECK(cancelled([&](Progress &pr) { knn_points(v, 8, 2, pr); }), "knn");
    CHECK(cancelled([&](Progress &pr) { normals_points(v, NormalOptions{}, OrientOptions{}, pr); }),
           "normals");
    CHECK(cancelled([&](Progress &pr) { radii_points(v, nrm.data(), 10, CoverOptions{}, pr); }),
           "radii");
    CHECK(cancelled([&](Progress &pr) {
               fit_points(v, nrm.data(), NormalOptions{}, OrientOptions{}, FitOptions{}, pr);
           }), "fit");
    // and progress is counted when not cancelled
    Progress pr;
    knn_points(v, 8, 2, pr);
    CHECK(pr.done.load() == pr.total.load() && pr.total.load() == v.n, "progress %llu of %llu",
           (unsigned long long)pr.done.load(), (unsigned long long)pr.total.load());
}

void test_degenerate_neighbourhoods_give_finite_output() {
    // a line, stacks of duplicates, and fewer points than neighbours
    std::vector<double> line;
    for (int i = 0; i < 40; ++i) line.insert(line.end(), {i * 0.1, 0.0, 0.0});
    std::vector<double> dup;
    for (int i = 0; i < 30; ++i) dup.insert(dup.end(), {0.5, 0.5, 0.5});
    for (int i = 0; i < 30; ++i) dup.insert(dup.end(), {double(i % 6), double(i / 6), 0.0});
    std::vector<double> four = {0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0};
    for (const std::vector<double> *p : {&line, &dup, &four}) {
        PointsView v;
        v.points = p->data();
        v.n = p->size() / 3;
        Progress pr;
        NormalsOutput nr = normals_points(v, NormalOptions{}, OrientOptions{}, pr);
        bool unit = true;
        for (size_t i = 0; i < v.n; ++i) {
            const float *n = &nr.est.normals[3 * i];
            double l = std::sqrt(double(n[0]) * n[0] + double(n[1]) * n[1] + double(n[2]) * n[2]);
            unit = unit && std::fabs(l - 1.0) < 1e-5;
        }
        CHECK(unit, "%zu points: every normal must be a finite unit vector", v.n);
        std::vector<float> r = radii_points(v, nr.est.normals.data(), 10, CoverOptions{}, pr);
        bool ok = std::all_of(r.begin(), r.end(), [](float x) { return std::isfinite(x) && x >= 0; });
        CHECK(ok, "%zu points: radii finite (0 marks a stack of duplicates)", v.n);
        FitOutput f = fit_points(v, nr.est.normals.data(), NormalOptions{}, OrientOptions{},
                                 FitOptions{}, pr);
        bool fin = std::all_of(f.fit.points.begin(), f.fit.points.end(),
                               [](double x) { return std::isfinite(x); });
        CHECK(fin, "%zu points: fitted positions finite", v.n);
    }
    PointsView v;
    v.points = line.data();
    v.n = line.size() / 3;
    Progress pr;
    NormalsOutput nr = normals_points(v, NormalOptions{}, OrientOptions{}, pr);
    CHECK(nr.est.arbitrary == v.n, "a line: %zu of %zu normals arbitrary", nr.est.arbitrary, v.n);
}

/// The cell radii of coverage_radii (before its global cap) computed one direction at a time,
/// the plain formula of radii.h: the SIMD loop must give the same floats bit for bit, for any
/// number of directions (padding lanes included).
void test_radii_match_the_scalar_formula() {
    std::vector<double> p = sphere_points(600, 11, 0.02);
    size_t n = p.size() / 3;
    std::vector<float> nrm(3 * n);
    for (size_t i = 0; i < 3 * n; ++i) nrm[i] = float(p[i]);  // the sphere's normals, roughly
    const uint32_t k = 10;
    NeighbourTable t;
    t.n = n, t.k = k;
    for (size_t i = 0; i < n; ++i) {
        std::vector<uint32_t> row = brute_row(p, i, k);
        t.index.insert(t.index.end(), row.begin(), row.end());
    }
    for (uint32_t nd : {3u, 5u, 16u, 64u}) {
        CoverOptions co;
        co.directions = nd;
        co.global_cap = 1e30;  // the per-point radii only
        std::vector<float> got = coverage_radii(p.data(), nrm.data(), t, co);
        size_t bad = 0;
        const float inf = std::numeric_limits<float>::infinity();
        for (size_t i = 0; i < n; ++i) {
            double nn[3] = {nrm[3 * i], nrm[3 * i + 1], nrm[3 * i + 2]}, t1[3], t2[3];
            double l = std::sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
            for (double &c : nn) c /= l;
            tangent_basis(nn, t1, t2);
            std::vector<float> edge(nd, inf);
            double d1 = 0, dk = 0;
            for (uint32_t m = 0; m < k; ++m) {
                const double *q = &p[3 * size_t(t.row(i)[m])], *o = &p[3 * i];
                double d[3] = {q[0] - o[0], q[1] - o[1], q[2] - o[2]};
                float x = float(d[0] * t1[0] + d[1] * t1[1] + d[2] * t1[2]);
                float y = float(d[0] * t2[0] + d[1] * t2[1] + d[2] * t2[2]);
                float r2 = x * x + y * y;
                double dist = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                if (m == 0) d1 = dist;
                dk = std::max(dk, dist);
                if (!(r2 > 0.f)) continue;
                float floor_ = 1e-6f * std::sqrt(r2);
                for (uint32_t a = 0; a < nd; ++a) {
                    double th = 2.0 * M_PI * a / nd;
                    float proj = x * float(std::cos(th)) + y * float(std::sin(th));
                    if (proj > floor_) edge[a] = std::min(edge[a], r2 / (2.f * proj));
                }
            }
            double cell = 0.0;
            for (float e : edge)
                if (e < inf) cell = std::max(cell, double(e));
            double r = std::min(co.margin * cell, co.cap * dk);
            if (!(r > 0)) r = std::max(0.5 * d1, co.cap * dk);
            float want = r > 0 ? std::max(float(r), std::numeric_limits<float>::min()) : 0.f;
            bad += got[i] != want;
        }
        CHECK(bad == 0, "%u directions: %zu of %zu radii differ from the scalar formula", nd, bad, n);
    }
}

/// The serial greedy thinning (the oracle of thin_greedy): points visited by descending
/// priority, then index; dropped when a kept point of the row lies within the radius.
std::vector<uint8_t> thin_serial(const std::vector<double> &p, const NeighbourTable &nb,
                                 const std::vector<double> &spacing, double thin,
                                 const std::vector<double> *priority,
                                 const std::vector<uint32_t> *among) {
    size_t n = nb.n;
    std::vector<uint32_t> order;
    if (among) order = *among;
    else for (size_t i = 0; i < n; ++i) order.push_back(uint32_t(i));
    std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
        double pa = priority ? (*priority)[a] : 0.0, pb = priority ? (*priority)[b] : 0.0;
        return pa > pb || (pa == pb && a < b);
    });
    std::vector<uint8_t> keep(n, 0);
    for (uint32_t i : order) {
        double r2 = thin * thin * spacing[i] * spacing[i];
        bool redundant = false;
        for (uint32_t m = 0; m < nb.k && !redundant; ++m) {
            uint32_t j = nb.row(i)[m];
            if (!keep[j]) continue;
            double e = d2(&p[3 * size_t(j)], &p[3 * i]);
            redundant = e < r2 || e == 0.0;
        }
        keep[i] = !redundant;
    }
    return keep;
}

/// thin_greedy gives the serial visit's answer on overlapping layers (chains of points that
/// wait on each other), with priorities that tie, none, a subset, duplicates, and rows longer
/// than the parallel rounds take (k > 64), at any thread count.
void test_thinning_matches_the_serial_visit() {
    std::mt19937 g(21);
    std::uniform_real_distribution<double> U(-0.5, 0.5);
    std::vector<double> p;
    // four jittered grids of the same square, each shifted: every point has neighbours of
    // the other layers within its spacing
    for (int layer = 0; layer < 4; ++layer)
        for (int x = 0; x < 60; ++x)
            for (int y = 0; y < 60; ++y)
                p.insert(p.end(), {x + 0.3 * layer + 0.2 * U(g), y + 0.45 * layer + 0.2 * U(g),
                                   0.05 * U(g)});
    for (int c = 0; c < 30; ++c) p.insert(p.end(), p.begin() + 3 * c, p.begin() + 3 * c + 3);
    size_t n = p.size() / 3;
    std::vector<double> spacing(n), smooth(n), tied(n);
    for (size_t i = 0; i < n; ++i) {
        spacing[i] = 0.9 + 0.2 * (U(g) + 0.5);
        smooth[i] = std::cos(0.05 * p[3 * i]) * std::cos(0.03 * p[3 * i + 1]);  // long chains
        tied[i] = std::floor(4 * (U(g) + 0.5));  // four values only
    }
    std::vector<uint32_t> subset;
    for (size_t i = 0; i < n; ++i)
        if (U(g) < 0.2) subset.push_back(uint32_t(i));
    KnnTree tree(p.data(), n, 2);
    for (uint32_t k : {31u, 70u}) {
        NeighbourTable nb = knn_all(tree, p.data(), k, 2);
        using Prio = const std::vector<double> *;
        using Among = const std::vector<uint32_t> *;
        for (Prio prio : {Prio(&smooth), Prio(&tied), Prio(nullptr)})
            for (Among among : {Among(nullptr), Among(&subset)}) {
                std::vector<uint8_t> want = thin_serial(p, nb, spacing, 0.75, prio, among);
                size_t kept = std::count(want.begin(), want.end(), uint8_t(1));
                CHECK(kept > 0 && kept < (among ? among->size() : n) * 3 / 4,
                      "k %u: the layers should thin (%zu kept)", k, kept);
                for (int threads : {1, 2, 4}) {
                    std::vector<uint8_t> got = thin_greedy(
                        p.data(), nb, spacing.data(), 0.75, prio ? prio->data() : nullptr,
                        among ? among->data() : nullptr, among ? among->size() : 0, threads);
                    CHECK(got == want, "k %u, %d threads, %s priority, %s: kept points differ "
                          "from the serial visit", k, threads, prio == &smooth ? "smooth" :
                          prio ? "tied" : "no", among ? "a subset" : "all points");
                }
            }
    }
}

}  // namespace

/// The search's inner loops of every instruction set this CPU runs (knn_kernels.h) give the
/// portable ones' answers bit for bit: the kernels on their own (every leaf size 1-17, points
/// at the radius and at equal distances, the point itself among them; the selection of up to 64
/// candidates with ties), and the tables of knn_all / knn_each (sorted and not, 1 and 3
/// threads) on a cloud with duplicates and a grid's equal distances, sorted ones against brute
/// force too.
void test_knn_kernels_agree_with_the_portable_ones() {
    const KnnKernels &base = knn_kernels(Isa::Base);
    std::mt19937 g(17);
    std::uniform_real_distribution<double> U(-1.0, 1.0);
    for (Isa isa : {Isa::Avx2, Isa::Avx512}) {
        if (!knn_kernels_available(isa)) {
            std::printf("preprocess_tests: no %s knn kernels in this build or on this CPU, not "
                        "tested\n", isa_name(isa));
            continue;
        }
        const KnnKernels &kk = knn_kernels(isa);
        CHECK(kk.isa == isa, "kernels of set %d: asked %d", int(kk.isa), int(isa));
        // near: 40 points on a small grid (equal distances, some exactly at the radius)
        const uint32_t n = 40;
        std::vector<double> x(n), y(n), z(n);
        std::vector<uint32_t> id(n);
        for (uint32_t s = 0; s < n; ++s) {
            x[s] = double(s % 4) * 0.25, y[s] = double((s / 4) % 4) * 0.25;
            z[s] = double(s / 16) * 0.25;
            id[s] = 1000 + 7 * s;
        }
        size_t bad = 0;
        for (uint32_t b = 0; b < 20; ++b)
            for (uint32_t e = b; e <= b + 17 && e <= n; ++e)
                for (double rq : {0.0, 0.0625, 0.125, 0.3, 10.0}) {
                    const double q[3] = {x[b], y[b], z[b]};
                    std::vector<double> d0(n + 8, -1), d1(n + 8, -1);
                    std::vector<uint32_t> i0(n + 8, 0), i1(n + 8, 0);
                    size_t c0 = base.near(x.data(), y.data(), z.data(), id.data(), b, e, q, rq,
                                          id[b], d0.data(), i0.data(), 3);
                    size_t c1 = kk.near(x.data(), y.data(), z.data(), id.data(), b, e, q, rq,
                                        id[b], d1.data(), i1.data(), 3);
                    bad += c0 != c1 || std::memcmp(d0.data() + 3, d1.data() + 3, 8 * (c0 - 3)) ||
                           !std::equal(i0.begin() + 3, i0.begin() + long(c0), i1.begin() + 3);
                }
        CHECK(bad == 0, "set %d: %zu near() calls differ from the portable kernel's", int(isa),
              bad);
        // rank: 1-64 candidates, distances from a few values (ties) or all distinct
        bad = 0;
        for (size_t cnt = 1; cnt <= 64; ++cnt)
            for (int ties : {0, 1})
                for (uint32_t k = 1; k <= cnt; k += (k < 4 ? 1 : 7)) {
                    std::vector<double> d(cnt + 8);
                    std::vector<uint32_t> ids(cnt);
                    for (size_t a = 0; a < cnt; ++a) {
                        d[a] = ties ? double(g() % 5) * 0.5 : U(g) * U(g);
                        d[a] = d[a] < 0 ? -d[a] : d[a];
                        ids[a] = uint32_t(cnt - a) * 3 + uint32_t(g() % 3);
                    }
                    std::vector<double> d0 = d, d1 = d;
                    std::vector<uint32_t> r0(k, 0), r1(k, 0);
                    double k0 = base.rank(d0.data(), ids.data(), cnt, k, r0.data());
                    double k1 = kk.rank(d1.data(), ids.data(), cnt, k, r1.data());
                    bad += k0 != k1 || r0 != r1;
                }
        CHECK(bad == 0, "set %d: %zu rank() calls differ from the portable kernel's", int(isa),
              bad);
        // whole tables
        std::vector<double> p = sphere_points(3000, 23, 0.01);
        for (int c = 0; c < 20; ++c) p.insert(p.end(), p.begin(), p.begin() + 3);
        for (int a = 0; a < 6; ++a)
            for (int b = 0; b < 6; ++b) p.insert(p.end(), {3.0 + a, 3.0 + b, 0.0});
        const size_t m = p.size() / 3;
        KnnTree tree(p.data(), m, 2);
        for (uint32_t k : {1u, 8u, 15u, 31u, 33u, 70u})
            for (int threads : {1, 3}) {
                NeighbourTable t0 = knn_all(tree, p.data(), k, threads, nullptr, Isa::Base);
                NeighbourTable t1 = knn_all(tree, p.data(), k, threads, nullptr, isa);
                CHECK(t0.index == t1.index, "set %d, k %u, %d threads: table differs", int(isa), k,
                      threads);
                size_t wrong = 0;
                for (size_t i = 0; i < m; i += 7) {
                    std::vector<uint32_t> want = brute_row(p, i, k);
                    wrong += !std::equal(want.begin(), want.end(), t1.row(i));
                }
                CHECK(wrong == 0, "set %d, k %u: %zu rows differ from brute force", int(isa), k,
                      wrong);
                std::vector<uint32_t> u0(m * t0.k), u1(m * t0.k);
                knn_each(tree, p.data(), k, false, threads, nullptr,
                         [&](uint32_t i, const uint32_t *row) {
                             std::copy(row, row + t0.k, u0.begin() + long(i) * t0.k);
                         }, Isa::Base);
                knn_each(tree, p.data(), k, false, threads, nullptr,
                         [&](uint32_t i, const uint32_t *row) {
                             std::copy(row, row + t0.k, u1.begin() + long(i) * t0.k);
                         }, isa);
                CHECK(u0 == u1, "set %d, k %u, %d threads: unsorted rows differ", int(isa), k,
                      threads);
            }
    }
    bool threw = false;
    try {
        knn_kernels(Isa::Sse42);
    } catch (const std::invalid_argument &) {
        threw = true;
    }
    CHECK(threw, "knn_kernels(Sse42): no such kernels, expected invalid_argument");
}

/// orient_above on ground around a box (roof, four walls): every normal of the ground and roof
/// faces up, nearly every wall's faces out (an analytic oracle), the same for 1 and 3 threads;
/// and the radii with the non-surface and sparse bounds on (a volume of scattered points above
/// the ground): identical for 1 and 3 threads and through the table or the tree, the volume's
/// at most the surface model's, and the ground's unchanged.
void test_orientation_from_above_and_volume_radii() {
    std::mt19937 g(5);
    std::uniform_real_distribution<double> U(-1.0, 1.0);
    std::vector<double> p, want;  // points and their outward normals
    auto add = [&](double x, double y, double z, double nx, double ny, double nz) {
        p.insert(p.end(), {x, y, z});
        want.insert(want.end(), {nx, ny, nz});
    };
    for (int i = 0; i < 6000; ++i) {
        double x = 15 * U(g), y = 15 * U(g);
        if (std::fabs(x) > 5 || std::fabs(y) > 5) add(x, y, 0, 0, 0, 1);
    }
    for (int i = 0; i < 400; ++i) add(5 * U(g), 5 * U(g), 6, 0, 0, 1);
    for (int side = 0; side < 4; ++side)
        for (int i = 0; i < 240; ++i) {
            double s = 5 * U(g), h = 3 + 3 * U(g), sg = side & 1 ? 1.0 : -1.0;
            if (side < 2) add(5 * sg, s, h, sg, 0, 0);
            else add(s, 5 * sg, h, 0, sg, 0);
        }
    const size_t n_surface = p.size() / 3;
    for (int i = 0; i < 1500; ++i) add(9 + 2 * U(g), 9 + 2 * U(g), 10 + 2 * U(g), 0, 0, 0);
    const size_t n = p.size() / 3;
    KnnTree tree(p.data(), n, 2);
    NeighbourTable t = knn_all(tree, p.data(), 31, 2);
    NormalOptions no;
    NormalResult est = estimate_normals(p.data(), t, no);
    OrientOptions oo;
    oo.has_up = oo.from_above = true;
    std::vector<float> one = est.normals, three = est.normals;
    OrientResult r1 = orient_above(p.data(), one.data(), t, oo, 1);
    OrientResult r3 = orient_above(p.data(), three.data(), t, oo, 3);
    CHECK(std::memcmp(one.data(), three.data(), 4 * one.size()) == 0 && r1.flipped == r3.flipped,
          "orient_above differs between 1 and 3 threads");
    CHECK(r1.steep > 0, "the walls are steep: %zu", r1.steep);
    size_t flat_wrong = 0, walls = 0, walls_out = 0;
    for (size_t i = 0; i < n_surface; ++i) {
        double d = one[3 * i] * want[3 * i] + one[3 * i + 1] * want[3 * i + 1] +
                   one[3 * i + 2] * want[3 * i + 2];
        if (want[3 * i + 2] == 1) flat_wrong += d <= 0;
        else ++walls, walls_out += d > 0;
    }
    CHECK(flat_wrong * 1000 <= n_surface, "%zu ground and roof normals face down", flat_wrong);
    CHECK(walls_out * 100 >= walls * 95, "%zu of %zu wall normals face out", walls_out, walls);
    CoverOptions plain, co;
    co.volume_factor = 1.0;
    co.typical_cap = 3.0;
    NeighbourTable t10 = knn_all(tree, p.data(), 10, 2);
    std::vector<float> base = coverage_radii(p.data(), one.data(), t10, plain);
    co.threads = 1;
    std::vector<float> a = coverage_radii(p.data(), one.data(), t10, co);
    co.threads = 3;
    std::vector<float> b = coverage_radii(p.data(), one.data(), tree, 10, co);
    CHECK(std::memcmp(a.data(), b.data(), 4 * n) == 0,
          "volume radii differ between 1 and 3 threads or the table and the tree");
    size_t larger = 0, shrunk = 0;
    for (size_t i = 0; i < n; ++i) {
        larger += a[i] > base[i];
        shrunk += i >= n_surface && a[i] < base[i];
    }
    CHECK(larger == 0, "%zu radii grew with the bounds on", larger);
    CHECK(shrunk * 2 > n - n_surface, "only %zu of %zu volume points bounded", shrunk,
          n - n_surface);
}

/// With the volume bound on, a one-sided point (on a plane's edge: some direction meets no
/// bisector) leaves out the directions whose bisector lies beyond its own neighbour; interior
/// points keep the surface model's radius exactly.
void test_open_directions_of_one_sided_points() {
    std::mt19937 g(5);
    std::uniform_real_distribution<double> U(-0.3, 0.3);
    std::vector<double> p;
    for (int y = 0; y < 30; ++y)
        for (int x = 0; x < 30; ++x) p.insert(p.end(), {x + U(g), y + U(g), 0.0});
    const size_t n = p.size() / 3;
    std::vector<float> nrm(3 * n, 0.f);
    for (size_t i = 0; i < n; ++i) nrm[3 * i + 2] = 1.f;
    KnnTree tree(p.data(), n, 2);
    NeighbourTable t = knn_all(tree, p.data(), 10, 2);
    CoverOptions plain, co;
    co.volume_factor = 1.0;
    std::vector<float> base = coverage_radii(p.data(), nrm.data(), t, plain);
    std::vector<float> vol = coverage_radii(p.data(), nrm.data(), t, co);
    size_t larger = 0, interior_changed = 0, edge = 0, edge_smaller = 0;
    for (size_t i = 0; i < n; ++i) {
        const double x = p[3 * i], y = p[3 * i + 1];
        larger += vol[i] > base[i];
        if (x > 4 && x < 25 && y > 4 && y < 25) interior_changed += vol[i] != base[i];
        if (x < 0.5 || y < 0.5 || x > 28.5 || y > 28.5) ++edge, edge_smaller += vol[i] < base[i];
    }
    CHECK(larger == 0, "%zu radii grew with the open directions", larger);
    CHECK(interior_changed == 0, "%zu interior radii changed", interior_changed);
    CHECK(edge_smaller * 10 > edge, "only %zu of %zu edge points lost a grazing direction",
          edge_smaller, edge);
}

int main() {
    test_knn_matches_brute_force();
    test_knn_kernels_agree_with_the_portable_ones();
    test_unsorted_rows_and_fused_radii();
    test_radii_from_rows_equal_the_members_own();
    test_knn_within_groups_matches_brute_force();
    test_grid_neighbours_match_brute_force_within_scan();
    test_view_grid_neighbours_match_brute_force();
    test_tiny_clouds();
    test_stray_clusters_match_an_oracle();
    test_normal_sizes_follow_the_growth();
    test_identical_for_any_thread_count();
    test_cancel_stops_every_step();
    test_degenerate_neighbourhoods_give_finite_output();
    test_radii_match_the_scalar_formula();
    test_thinning_matches_the_serial_visit();
    test_orientation_from_above_and_volume_radii();
    test_open_directions_of_one_sided_points();
    std::printf("preprocess_tests: %d checks, %d failures\n", pointviz_tests::g_checks,
                pointviz_tests::g_failures);
    return pointviz_tests::g_failures == 0 ? 0 : 1;
}
