// pointviz — coverage radii (see radii.h).
#include "pointviz/radii.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#if defined(__SSE2__) && !defined(POINTVIZ_NO_SIMD)
#include <emmintrin.h>
#endif

#include "pointviz/parallel.h"
#include "pointviz/pca.h"

namespace pointviz {

namespace {

/// Most directions sampled per cell.
constexpr uint32_t kMaxDirections = 64;
/// Directions are processed in groups of this many (one AVX register of floats; divides
/// kMaxDirections).
constexpr uint32_t kLanes = 8;

/// Linear-interpolated quantile (numpy's default) of the positive values of `v`.
double quantile(std::vector<float> v, double q) {
    if (v.empty()) return 0.0;
    double pos = q * double(v.size() - 1);
    size_t lo = size_t(pos);
    std::nth_element(v.begin(), v.begin() + lo, v.end());
    double a = v[lo];
    if (lo + 1 >= v.size()) return a;
    double b = *std::min_element(v.begin() + lo + 1, v.end());
    return a + (pos - double(lo)) * (b - a);
}

/// The sampled directions of a cell, in float: the cell along each is a min over neighbours of
/// one division, which runs 4 directions at a time. Padded to whole SIMD lanes with proj = 0
/// directions, which never get a bisector.
struct Directions {
    uint32_t nd = 0, nd_lanes = 0;
    alignas(32) float cs[kMaxDirections] = {}, sn[kMaxDirections] = {};
    explicit Directions(uint32_t wanted) {
        nd = std::min<uint32_t>(std::max<uint32_t>(wanted, 3), kMaxDirections);
        nd_lanes = (nd + kLanes - 1) / kLanes * kLanes;
        for (uint32_t a = 0; a < nd; ++a) {
            double t = 2.0 * M_PI * a / nd;
            cs[a] = float(std::cos(t));
            sn[a] = float(std::sin(t));
        }
    }
};

/// A point's radius and whether its neighbourhood is a surface (see CoverOptions::volume_*).
struct Cell {
    float radius = 0.f;
    bool surface = true;
    /// margin x the cell's median extent over the sampled directions that have a bisector
    /// (its radius is the largest): large for an isolated return, small for an elongated cell
    /// (scan lines far apart, samples close along them).
    float extent = 0.f;
    float spacing = 0.f;  ///< the nearest neighbour's distance (with the volume bound on)
};

/// The radius of point i from its k neighbours `row` (in any order: the cell is a min over
/// them, the cap a max, the fallback a min).
Cell cell_radius(const double *points, const float *normals, size_t i, const uint32_t *row,
                  uint32_t k, const Directions &dir, const CoverOptions &opt) {
    alignas(32) float edge[kMaxDirections];
    const float *cs = dir.cs, *sn = dir.sn;
    const uint32_t nd = dir.nd, nd_lanes = dir.nd_lanes;
    const double *p = points + 3 * i;
    double nn[3] = {normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]}, t1[3], t2[3];
    double l = std::sqrt(nn[0] * nn[0] + nn[1] * nn[1] + nn[2] * nn[2]);
    for (int a = 0; a < 3; ++a) nn[a] /= l;
    tangent_basis(nn, t1, t2);
    const float inf = std::numeric_limits<float>::infinity();
    double d1 = inf, dk = 0;
    uint32_t in_plane = 0, counted = 0;  // neighbours within the tangent plane's band
    for (uint32_t a = 0; a < nd_lanes; ++a) edge[a] = inf;
    // with the volume bound: the cosine between each direction and the neighbour whose
    // bisector bounds it
    const bool opens = opt.volume_factor > 0;
    alignas(32) float wcos[kMaxDirections] = {};
    // along each direction the cell ends at the nearest perpendicular bisector
    for (uint32_t m = 0; m < k; ++m) {
        const double *q = points + 3 * size_t(row[m]);
        double d[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
        float x = float(d[0] * t1[0] + d[1] * t1[1] + d[2] * t1[2]);
        float y = float(d[0] * t2[0] + d[1] * t2[1] + d[2] * t2[2]);
        float r2 = x * x + y * y;
        double dist = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        d1 = std::min(d1, dist);
        dk = std::max(dk, dist);
        const double h = d[0] * nn[0] + d[1] * nn[1] + d[2] * nn[2];
        if (dist > 0) {
            ++counted;
            in_plane += std::fabs(h) <= opt.volume_band * std::sqrt(double(r2));
        }
        if (!(r2 > 0.f)) continue;
        float floor_ = 1e-6f * std::sqrt(r2);  // a bisector nearly along the direction
        // with opens: the cosine of the neighbour whose bisector is the nearest so far
        const float inv = opens ? 1.f / std::sqrt(r2) : 0.f;
        // four directions at a time over whole lanes (the padding directions have
        // proj = 0: never a bisector); every lane rounds as the scalar loop does
#if defined(__SSE2__) && !defined(POINTVIZ_NO_SIMD)
        const __m128 vx = _mm_set1_ps(x), vy = _mm_set1_ps(y), vr2 = _mm_set1_ps(r2),
                     vfloor = _mm_set1_ps(floor_), vinf = _mm_set1_ps(inf),
                     vinv = _mm_set1_ps(inv);
        for (uint32_t a = 0; a < nd_lanes; a += 4) {
            __m128 proj = _mm_add_ps(_mm_mul_ps(vx, _mm_load_ps(cs + a)),
                                     _mm_mul_ps(vy, _mm_load_ps(sn + a)));
            __m128 s = _mm_div_ps(vr2, _mm_add_ps(proj, proj));
            __m128 ok = _mm_cmpgt_ps(proj, vfloor);
            s = _mm_or_ps(_mm_and_ps(ok, s), _mm_andnot_ps(ok, vinf));
            const __m128 old = _mm_load_ps(edge + a);
            if (opens) {
                const __m128 nearer = _mm_cmplt_ps(s, old);
                _mm_store_ps(wcos + a,
                             _mm_or_ps(_mm_and_ps(nearer, _mm_mul_ps(proj, vinv)),
                                       _mm_andnot_ps(nearer, _mm_load_ps(wcos + a))));
            }
            _mm_store_ps(edge + a, _mm_min_ps(s, old));
        }
#else
        for (uint32_t a = 0; a < nd_lanes; ++a) {
            float proj = x * cs[a] + y * sn[a];
            float s = proj > floor_ ? r2 / (2.f * proj) : inf;
            if (opens && s < edge[a]) wcos[a] = proj * inv;
            edge[a] = std::min(edge[a], s);
        }
#endif
    }
    double cell = 0.0, closed = 0.0;
    uint32_t bounded = 0;
    const float graze = float(opt.open_cos);
    for (uint32_t a = 0; a < nd; ++a)
        if (edge[a] < inf) {
            cell = std::max(cell, double(edge[a]));
            if (opens && wcos[a] >= graze) closed = std::max(closed, double(edge[a]));
            edge[bounded++] = edge[a];
        }
    // a one-sided point's grazing directions left out (opens only)
    if (bounded < nd && closed > 0) cell = closed;
    double r = std::min(opt.margin * cell, opt.cap * dk);
    // isolated or degenerate (no bisector anywhere): from the neighbour distances
    if (!(r > 0)) r = std::max(0.5 * d1, opt.cap * dk);
    Cell out;
    out.spacing = d1 < inf ? float(d1) : 0.f;
    if (opt.typical_cap > 0) {
        double e = r;
        if (bounded) {
            std::nth_element(edge, edge + bounded / 2, edge + bounded);
            e = std::min(opt.margin * double(edge[bounded / 2]), r);
        }
        out.extent = float(e);
    }
    if (opt.volume_factor > 0 && counted > 0 && r > 0) {
        const double f = double(in_plane) / double(counted);
        const double s = std::clamp((opt.volume_surface - f) /
                                        std::max(opt.volume_surface - opt.volume_volume, 1e-12),
                                    0.0, 1.0);
        const double bound = std::min(r, opt.volume_factor * d1);
        if (s > 0 && bound > 0) {
            r = s >= 1 ? bound : std::exp((1 - s) * std::log(r) + s * std::log(bound));
            out.surface = false;
        }
    }
    float rf = float(r);
    // rounding to float must not turn a tiny positive radius into 0
    out.radius = r > 0 ? std::max(rf, std::numeric_limits<float>::min()) : 0.f;
    return out;
}

/// A point taken for a surface among neighbours most of which are not (a few returns of a
/// canopy that happen to lie in a plane, all to one side: a petal reaching out to its k-th
/// neighbour) is bounded as they are: at most volume_factor x its nearest neighbour's distance.
/// Reads the first pass's flags only (the same for any thread count); marks those points.
template <class RowOf>
void bound_surface_among_volume(std::vector<float> &out, std::vector<Cell> &cells, uint32_t k,
                                const CoverOptions &opt, RowOf row_of) {
    const size_t n = out.size();
    std::vector<uint8_t> demote(n, 0);
    parallel_for(n, 4096, opt.threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            if (!cells[i].surface) continue;
            const uint32_t *row = row_of(i);
            uint32_t volume = 0;
            for (uint32_t m = 0; m < k; ++m) volume += !cells[row[m]].surface;
            if (2 * volume > k) demote[i] = 1;
        }
    });
    for (size_t i = 0; i < n; ++i)
        if (demote[i]) {
            const float bound = float(opt.volume_factor) * cells[i].spacing;
            if (bound > 0) out[i] = std::min(out[i], bound), cells[i].surface = false;
        }
}

/// Caps `out` at opt.global_cap x its 99th percentile (clouds of at least 100 points). With
/// opt.typical_cap, the `cells` of the points: a point whose cell's median extent exceeds
/// typical_cap x the median of the surface points' is an isolated return, and its radius is
/// capped at typical_cap x their median radius.
void apply_global_cap(std::vector<float> &out, const CoverOptions &opt,
                      const std::vector<Cell> &cells = {}) {
    constexpr size_t kMinForQuantile = 100;  // too few points for a meaningful percentile
    if (out.size() < kMinForQuantile) return;
    float cap = float(opt.global_cap * quantile(out, 0.99));
    if (cap > 0)
        for (float &r : out) r = std::min(r, cap);
    if (opt.typical_cap > 0 && cells.size() == out.size()) {
        std::vector<float> radius, extent;
        for (size_t i = 0; i < out.size(); ++i)
            if (cells[i].surface) radius.push_back(out[i]), extent.push_back(cells[i].extent);
        if (radius.size() < kMinForQuantile) return;  // hardly any surface: nothing typical
        const float r_cap = float(opt.typical_cap * quantile(radius, 0.5));
        const float e_cap = float(opt.typical_cap * quantile(extent, 0.5));
        if (!(r_cap > 0) || !(e_cap > 0)) return;
        for (size_t i = 0; i < out.size(); ++i)
            if (cells[i].extent > e_cap) out[i] = std::min(out[i], r_cap);
    }
}

}  // namespace

std::vector<float> coverage_radii(const double *points, const float *normals,
                                  const NeighbourTable &nb, const CoverOptions &opt,
                                  Progress *progress) {
    size_t n = nb.n;
    uint32_t k = nb.k;
    std::vector<float> out(n, 0.f);
    if (n == 0 || k == 0) return out;
    const Directions dir(opt.directions);
    if (progress) progress->total.fetch_add(n, std::memory_order_relaxed);
    constexpr size_t kGrain = 4096;
    std::vector<Cell> cells(opt.typical_cap > 0 || opt.volume_factor > 0 ? n : 0);
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            const Cell c = cell_radius(points, normals, i, nb.row(i), k, dir, opt);
            out[i] = c.radius;
            if (!cells.empty()) cells[i] = c;
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    if (opt.volume_factor > 0)
        bound_surface_among_volume(out, cells, k, opt, [&](size_t i) { return nb.row(i); });
    apply_global_cap(out, opt, cells);
    return out;
}

std::vector<float> coverage_radii(const double *points, const float *normals,
                                  const KnnTree &tree, uint32_t k, const CoverOptions &opt,
                                  Progress *progress) {
    size_t n = tree.size();
    std::vector<float> out(n, 0.f);
    if (n < 2 || k == 0) return out;
    k = uint32_t(std::min<size_t>(k, n - 1));
    if (opt.volume_factor > 0) {  // the second pass reads every point's row again
        const NeighbourTable t = knn_all(tree, points, k, opt.threads, progress);
        return coverage_radii(points, normals, t, opt, progress);
    }
    const Directions dir(opt.directions);
    std::vector<Cell> cells(opt.typical_cap > 0 ? n : 0);
    knn_each(tree, points, k, false, opt.threads, progress,
             [&](uint32_t i, const uint32_t *row) {
                 const Cell c = cell_radius(points, normals, i, row, k, dir, opt);
                 out[i] = c.radius;
                 if (!cells.empty()) cells[i] = c;
             });
    apply_global_cap(out, opt, cells);
    return out;
}

RowRadii coverage_radii_from_rows(const double *points, const float *normals, size_t n,
                                  const uint8_t *member, const NeighbourTable &rows, uint32_t k,
                                  const CoverOptions &opt, Progress *progress) {
    RowRadii out;
    std::vector<uint32_t> members;
    for (size_t i = 0; i < n; ++i)
        if (member[i]) members.push_back(uint32_t(i));
    const size_t m = members.size();
    out.radii.assign(m, 0.f);
    if (m < 2 || k == 0) return out;
    k = uint32_t(std::min<size_t>(k, m - 1));
    const Directions dir(opt.directions);
    if (progress) progress->total.fetch_add(m, std::memory_order_relaxed);
    constexpr size_t kGrain = 4096;
    // from the rows: the k nearest members among each row's, by (squared distance, index) on
    // `points` as the tree's search orders them; a row with fewer is marked for the search
    std::vector<uint8_t> search(m, 0);
    parallel_for(m, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        // (squared distance, index) of a row's members: the k smallest are the neighbours
        std::vector<std::pair<double, uint32_t>> cand(rows.k);
        std::vector<uint32_t> idx(rows.k);
        for (size_t a = b; a < e; ++a) {
            const uint32_t i = members[a];
            const uint32_t *row = rows.row(i);
            uint32_t c = 0;
            for (uint32_t r = 0; r < rows.k; ++r) idx[c] = row[r], c += member[row[r]] != 0;
            if (c < k) {
                search[a] = 1;
                continue;
            }
            if (c > k) {  // the cell is the same for its neighbours in any order: select only
                const double *p = points + 3 * size_t(i);
                for (uint32_t r = 0; r < c; ++r) {
                    const double *q = points + 3 * size_t(idx[r]);
                    const double dx = q[0] - p[0], dy = q[1] - p[1], dz = q[2] - p[2];
                    cand[r] = {dx * dx + dy * dy + dz * dz, idx[r]};
                }
                std::nth_element(cand.begin(), cand.begin() + (k - 1), cand.begin() + c);
                for (uint32_t r = 0; r < k; ++r) idx[r] = cand[r].second;
            }
            out.radii[a] = cell_radius(points, normals, i, idx.data(), k, dir, opt).radius;
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    std::vector<uint32_t> rest;
    for (size_t a = 0; a < m; ++a)
        if (search[a]) rest.push_back(uint32_t(a));
    out.searched = rest.size();
    if (!rest.empty()) {
        // a tree of the members (on `points`) answering with their positions in `members`
        std::vector<double> sub(3 * m);
        for (size_t a = 0; a < m; ++a)
            for (int c = 0; c < 3; ++c) sub[3 * a + c] = points[3 * size_t(members[a]) + c];
        const KnnTree tree(sub.data(), m, opt.threads, progress);
        std::vector<uint32_t> stored(m);
        for (size_t r = 0; r < m; ++r) stored[tree.order()[r]] = uint32_t(r);
        parallel_for(rest.size(), 256, opt.threads, [&](size_t b, size_t e, int) {
            std::vector<double> d2(k);
            std::vector<uint32_t> idx(k);
            for (size_t r = b; r < e; ++r) {
                const uint32_t a = rest[r];
                uint32_t got = tree.query_near(sub.data() + 3 * size_t(a), stored[a], k, a,
                                               idx.data(), d2.data());
                for (uint32_t c = 0; c < got; ++c) idx[c] = members[idx[c]];
                out.radii[a] =
                    cell_radius(points, normals, members[a], idx.data(), got, dir, opt).radius;
            }
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
    }
    apply_global_cap(out.radii, opt);
    return out;
}

}  // namespace pointviz
