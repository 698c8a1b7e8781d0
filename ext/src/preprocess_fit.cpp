// pointviz — robust local surface fit and thinning of overlapping scans (see surface_fit.h).
#include "pointviz/surface_fit.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>

#include "pointviz/default_init.h"
#include "pointviz/parallel.h"
#include "pointviz/pca.h"

namespace pointviz {

namespace {

/// Spatial weight (1 - d^2 / h^2)^2 with h = kFitReach x the farthest fitted neighbour's
/// distance (as for the normals: the farthest keeps 31% weight).
constexpr double kFitReach = 1.5;
/// Neighbours whose normal makes more than acos(kSameSideCos) = 90 degrees with the point's
/// take no part in its fit: the two sides of a claw 1 mm thick are within one neighbourhood of
/// the dragon's scans, and their normals point apart.
constexpr double kSameSideCos = 0.0;
/// The plane passes' pull (below) is averaged over this many of each point's neighbours, the
/// nearest first: it varies with the curvature, slowly, while each point's own estimate carries
/// the noise of its quadric's second-order terms.
constexpr uint32_t kPullSupport = 32;
/// With more than one pass, the points the last pass fits: those a thinning at this fraction
/// of FitOptions::thin keeps, on the previous pass's positions (a smaller radius than the final
/// thinning's, so that the final one, on the last pass's positions, finds its points among
/// them).
constexpr double kEarlyThin = 0.8;
/// Largest number of unknowns of a fit.
constexpr int kMaxTerms = 6;
/// A Cholesky pivot below this fraction of the matrix's largest diagonal entry means the
/// neighbourhood does not determine the fit (its points lie on a curve in the tangent plane).
constexpr double kPivotFloor = 1e-10;

/// Solves the symmetric positive definite system m x = r of size t in place (Cholesky).
bool solve_spd(double m[kMaxTerms][kMaxTerms], double *r, int t) {
    double scale = 0;
    for (int a = 0; a < t; ++a) scale = std::max(scale, m[a][a]);
    if (!(scale > 0)) return false;
    for (int j = 0; j < t; ++j) {
        double d = m[j][j];
        for (int q = 0; q < j; ++q) d -= m[j][q] * m[j][q];
        if (!(d > kPivotFloor * scale)) return false;
        m[j][j] = std::sqrt(d);
        for (int i = j + 1; i < t; ++i) {
            double s = m[i][j];
            for (int q = 0; q < j; ++q) s -= m[i][q] * m[j][q];
            m[i][j] = s / m[j][j];
        }
    }
    for (int i = 0; i < t; ++i) {  // L y = r
        double s = r[i];
        for (int q = 0; q < i; ++q) s -= m[i][q] * r[q];
        r[i] = s / m[i][i];
    }
    for (int i = t - 1; i >= 0; --i) {  // L^T x = y
        double s = r[i];
        for (int q = i + 1; q < t; ++q) s -= m[q][i] * r[q];
        r[i] = s / m[i][i];
    }
    return true;
}

/// A neighbour's tangential coordinates (u, v) and height z in the frame of the point's normal;
/// the fit's features are (1, u, v, u^2, uv, v^2).
struct FitRow {
    double u, v, z;
};

/// The normal equations of a weighted least-squares fit: m (symmetric, both halves filled) and
/// the right-hand side r.
struct NormalEquations {
    double m[kMaxTerms][kMaxTerms];
    double r[kMaxTerms];
};

/// Exponents (of u, of v) of the features.
constexpr int kPowU[kMaxTerms] = {0, 1, 0, 2, 1, 0};
constexpr int kPowV[kMaxTerms] = {0, 0, 1, 0, 1, 2};

/// Accumulates the normal equations of the first `T` features (3: a plane, 6: a quadric) over
/// the rows, in the order of the points. Each entry of m is a weighted moment sum w u^p v^q
/// (p + q <= 4 for the quadric: 15 distinct sums for its 21 entries), each product formed
/// from the previous one (w, w u, w u^2, ...). Points of weight 0 add exactly nothing.
template <int T>
void accumulate(const FitRow *rows, const double *w, uint32_t k, NormalEquations &eq) {
    // mom[p][q] = sum of w u^p v^q
    double mom[5][5] = {};
    double r[kMaxTerms] = {};
    for (uint32_t j = 0; j < k; ++j) {
        const double wj = w[j];
        if (wj == 0.0) continue;
        const double u = rows[j].u, v = rows[j].v, z = rows[j].z;
        const double wu = wj * u, wv = wj * v;
        mom[0][0] += wj, mom[1][0] += wu, mom[0][1] += wv;
        const double wuu = wu * u, wuv = wu * v, wvv = wv * v;
        mom[2][0] += wuu, mom[1][1] += wuv, mom[0][2] += wvv;
        r[0] += wj * z, r[1] += wu * z, r[2] += wv * z;
        if constexpr (T == kMaxTerms) {
            const double wuuu = wuu * u, wuuv = wuu * v, wuvv = wuv * v, wvvv = wvv * v;
            mom[3][0] += wuuu, mom[2][1] += wuuv, mom[1][2] += wuvv, mom[0][3] += wvvv;
            mom[4][0] += wuuu * u, mom[3][1] += wuuu * v, mom[2][2] += wuuv * v;
            mom[1][3] += wuvv * v, mom[0][4] += wvvv * v;
            r[3] += wuu * z, r[4] += wuv * z, r[5] += wvv * z;
        }
    }
    for (int a = 0; a < T; ++a) {
        eq.r[a] = r[a];
        for (int b = 0; b < T; ++b) eq.m[a][b] = mom[kPowU[a] + kPowU[b]][kPowV[a] + kPowV[b]];
    }
}

/// Solves the normal equations of `T` features (on a copy: `eq` is kept) into `coef`.
template <int T>
bool solve_terms(const NormalEquations &eq, double *coef) {
    double m[kMaxTerms][kMaxTerms], r[kMaxTerms];
    for (int a = 0; a < T; ++a) {
        r[a] = eq.r[a];
        for (int b = 0; b < T; ++b) m[a][b] = eq.m[a][b];
    }
    if (!solve_spd(m, r, T)) return false;
    for (int a = 0; a < T; ++a) {
        if (!std::isfinite(r[a])) return false;
        coef[a] = r[a];
    }
    return true;
}

/// Weighted least squares of z on the first `T` features; `eq` keeps the normal equations of
/// these weights (whether or not they could be solved).
template <int T>
bool fit_terms(const FitRow *rows, const double *w, uint32_t k, NormalEquations &eq,
               double *coef) {
    accumulate<T>(rows, w, k, eq);
    return solve_terms<T>(eq, coef);
}

bool fit_terms(const FitRow *rows, const double *w, uint32_t k, int t, NormalEquations &eq,
               double *coef) {
    return t == kMaxTerms ? fit_terms<kMaxTerms>(rows, w, k, eq, coef)
                          : fit_terms<3>(rows, w, k, eq, coef);
}

/// z minus the fit of `T` features.
template <int T>
double residual(const double *c, const FitRow &row) {
    double s = c[0] + c[1] * row.u + c[2] * row.v;
    if constexpr (T == kMaxTerms)
        s += c[3] * row.u * row.u + c[4] * row.u * row.v + c[5] * row.v * row.v;
    return row.z - s;
}

double dist2(const double *a, const double *b) {
    return (a[0] - b[0]) * (a[0] - b[0]) + (a[1] - b[1]) * (a[1] - b[1]) +
           (a[2] - b[2]) * (a[2] - b[2]);
}

/// Scratch space of one worker, grown to the largest neighbourhood it fits.
struct FitScratch {
    std::vector<FitRow> rows;
    std::vector<double> ws, w, res;
    void reserve(uint32_t k) {
        if (rows.size() >= k) return;
        rows.resize(k), ws.resize(k), w.resize(k), res.resize(k);
    }
};

/// The robust reweighting passes of a fit of `T` terms (coefficients `c`, updated in place);
/// `eq` ends with the normal equations of the final weights `w`.
template <int T>
void reweight(const FitRow *rows, const double *ws, double *w, double *res, uint32_t k,
              const FitOptions &opt, NormalEquations &eq, double *c) {
    for (int pass = 0; pass < opt.robust_passes; ++pass) {
        double sr = 0, sw = 0;
        for (uint32_t j = 0; j < k; ++j) {
            double r = res[j] = residual<T>(c, rows[j]);
            sr += w[j] * r * r;
            sw += w[j];
        }
        double s2 = sr / sw * opt.robust_width * opt.robust_width;
        if (!(s2 > 0)) break;
        for (uint32_t j = 0; j < k; ++j) {
            double r = res[j];
            w[j] = ws[j] == 0.0 ? 0.0 : ws[j] * std::exp(-r * r / s2);
        }
        double prev[kMaxTerms];
        std::copy(c, c + T, prev);
        if (!fit_terms<T>(rows, w, k, eq, c)) std::copy(prev, prev + T, c);
    }
}

/// Fits point i of `points` (normals `normals`) over itself and its first k - 1 neighbours,
/// reweighted against outliers when `robust`; writes the projected position and the fit's
/// normal. With `out_pull` and a quadric fit, also
/// the pull of one plane fit of this neighbourhood (below; left as it was otherwise). False:
/// the fit failed or asked for a move beyond the neighbourhood.
bool fit_point(const double *points, const float *normals, size_t i, const uint32_t *row,
               uint32_t k, const FitOptions &opt, bool quadric, bool robust, FitScratch &s,
               double *out_p, float *out_n, double *out_pull) {
    const double *p = points + 3 * i;
    double h2 = kFitReach * kFitReach * dist2(points + 3 * size_t(row[k - 2]), p);
    if (!(h2 > 0)) return false;
    double h = std::sqrt(h2), inv_h = 1.0 / h;
    double nn[3] = {normals[3 * i], normals[3 * i + 1], normals[3 * i + 2]}, t1[3], t2[3];
    tangent_basis(nn, t1, t2);
    s.reserve(k);
    FitRow *rows = s.rows.data();
    double *ws = s.ws.data(), *w = s.w.data();
    rows[0] = FitRow{0.0, 0.0, 0.0};  // entry 0 is the point itself
    ws[0] = 1.0;
    for (uint32_t m = 0; m + 1 < k; ++m) {
        const double *q = points + 3 * size_t(row[m]);
        double d[3] = {q[0] - p[0], q[1] - p[1], q[2] - p[2]};
        rows[m + 1] = FitRow{(d[0] * t1[0] + d[1] * t1[1] + d[2] * t1[2]) * inv_h,
                             (d[0] * t2[0] + d[1] * t2[1] + d[2] * t2[2]) * inv_h,
                             (d[0] * nn[0] + d[1] * nn[1] + d[2] * nn[2]) * inv_h};
        double t = 1.0 - (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]) / h2;
        // a neighbour facing the other way lies on the far side of a thin part (or is
        // misoriented): fitting it would pull the point into the part
        const float *qn = normals + 3 * size_t(row[m]);
        bool same_side = qn[0] * nn[0] + qn[1] * nn[1] + qn[2] * nn[2] > kSameSideCos;
        ws[m + 1] = same_side ? t * t : 0.0;
    }
    std::copy(ws, ws + k, w);
    int terms = quadric && k >= 2 * kMaxTerms ? kMaxTerms : 3;
    double c[kMaxTerms];
    NormalEquations eq;
    bool ok = fit_terms(rows, w, k, terms, eq, c);
    if (!ok && terms == kMaxTerms) ok = fit_terms(rows, w, k, terms = 3, eq, c);
    if (ok && robust) {
        if (terms == kMaxTerms) reweight<kMaxTerms>(rows, ws, w, s.res.data(), k, opt, eq, c);
        else reweight<3>(rows, ws, w, s.res.data(), k, opt, eq, c);
    }
    // the fit at the point's own tangential position: height a, slopes (b, c)
    if (!ok || !(std::fabs(c[0]) <= 1.0 / kFitReach)) return false;
    // A plane fitted to a curved neighbourhood lies below it (on the concave side) by its own
    // fit of the quadratic part: curvature x support^2 / 4 on a sphere. The quadric has the
    // surface's curvature, so that pull is the plane fit, with the same weights, of its
    // quadratic terms alone: the height of that plane at the point. Its normal equations are
    // the quadric's first three rows: the plane's block of m, and on the right the quadratic
    // columns times the quadric's second-order coefficients.
    if (out_pull && terms == kMaxTerms) {
        NormalEquations pe;
        for (int a = 0; a < 3; ++a) {
            for (int b = 0; b < 3; ++b) pe.m[a][b] = eq.m[a][b];
            pe.r[a] = c[3] * eq.m[a][3] + c[4] * eq.m[a][4] + c[5] * eq.m[a][5];
        }
        double pc[3];
        if (solve_terms<3>(pe, pc)) *out_pull = pc[0] * h;
    }
    double g[3];
    for (int a = 0; a < 3; ++a) g[a] = nn[a] - c[1] * t1[a] - c[2] * t2[a];
    double gl = std::sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]);
    for (int a = 0; a < 3; ++a) {
        out_p[a] = p[a] + c[0] * h * nn[a];
        out_n[a] = float(g[a] / gl);
    }
    return true;
}

/// What the last pass did to a point, for giving back the plane passes' pull.
enum LastFit : uint8_t { kNotMoved = 0, kMoved = 1, kPullEstimated = 2 };

/// Moves each point of `res` that the last pass moved outward along its normal by
/// `plane_passes` x the mean pull estimated at itself and its nearest neighbours (kPullSupport,
/// those with an estimate and facing its way); no estimate among them: not moved.
void give_back_pull(FitResult &res, const NeighbourTable &nb, const std::vector<double> &pull,
                    const std::vector<uint8_t> &last, double plane_passes, int threads,
                    Progress *progress) {
    size_t n = nb.n;
    std::vector<double> mean(n, 0.0);
    parallel_for(n, 1024, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            if (last[i] == kNotMoved) continue;
            const float *ni = &res.normals[3 * i];
            const uint32_t *row = nb.row(i);
            double sum = last[i] == kPullEstimated ? pull[i] : 0.0;
            uint32_t cnt = last[i] == kPullEstimated ? 1 : 0;
            for (uint32_t m = 0; m < std::min(nb.k, kPullSupport - 1); ++m) {
                uint32_t j = row[m];
                const float *nj = &res.normals[3 * size_t(j)];
                if (last[j] != kPullEstimated ||
                    ni[0] * nj[0] + ni[1] * nj[1] + ni[2] * nj[2] <= kSameSideCos)
                    continue;
                sum += pull[j];
                ++cnt;
            }
            mean[i] = cnt ? sum / double(cnt) : 0.0;
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    parallel_for(n, 1024, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            const float *ni = &res.normals[3 * i];
            for (int a = 0; a < 3; ++a)
                res.points[3 * i + a] -= plane_passes * mean[i] * double(ni[a]);
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
}

/// Greedy thinning of the fitted points `res` (positions and normals as fitted so far): visiting
/// the points seen most head-on first (then by index), a point is dropped when a kept point
/// lies within `thin` x its spacing (thin_greedy). `among` (null: every point): only these
/// points are visited; the others are dropped. Sets res.keep and res.kept.
void thin_points(FitResult &res, const NeighbourTable &nb, const double *viewpoints,
                 size_t n_viewpoints, double thin, const std::vector<uint32_t> *among,
                 int threads, Progress *progress) {
    size_t n = nb.n;
    std::vector<double> priority;
    if (viewpoints) {
        priority.assign(n, 0.0);
        const size_t count = among ? among->size() : n;
        parallel_for(count, 4096, threads, [&](size_t b, size_t e, int) {
            for (size_t a = b; a < e; ++a) {
                size_t i = among ? (*among)[a] : a;
                const double *vp = viewpoints + (n_viewpoints == 1 ? 0 : 3 * i);
                const double *q = res.points.data() + 3 * i;
                const float *nn = res.normals.data() + 3 * i;
                double d[3] = {vp[0] - q[0], vp[1] - q[1], vp[2] - q[2]};
                double l = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
                priority[i] = l > 0 ? (nn[0] * d[0] + nn[1] * d[1] + nn[2] * d[2]) / l : 0.0;
            }
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
    }
    res.keep = thin_greedy(res.points.data(), nb, res.spacing.data(), thin,
                           viewpoints ? priority.data() : nullptr,
                           among ? among->data() : nullptr, among ? among->size() : 0, threads,
                           progress);
    res.kept = size_t(std::count(res.keep.begin(), res.keep.end(), uint8_t(1)));
}

}  // namespace

std::vector<uint8_t> thin_greedy(const double *points, const NeighbourTable &nb,
                                 const double *spacing, double thin, const double *priority,
                                 const uint32_t *among, size_t n_among, int threads,
                                 Progress *progress) {
    const size_t n = nb.n;
    const uint32_t k = nb.k;
    std::vector<uint8_t> keep(n, 0);
    const size_t count = among ? n_among : n;
    if (count == 0) return keep;
    // Point i's fate depends only on the points of its row that come before it (higher
    // priority, then lower index) and lie within its radius: it is kept when none of them is
    // kept. Every point whose such neighbours are all decided can be decided, in any order and
    // on any thread, and gets the serial visit's answer; rounds of this settle most points,
    // and the rest are visited in order. State per point: open, kept, dropped (points outside
    // `among` start dropped, as the serial visit never keeps them).
    enum : uint8_t { kOpen = 0, kKept = 1, kDropped = 2 };
    constexpr size_t kFillGrain = size_t(1) << 15;
    std::unique_ptr<std::atomic<uint8_t>[]> state(new std::atomic<uint8_t>[n]);
    parallel_for(n, kFillGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i)
            state[i].store(among ? kDropped : kOpen, std::memory_order_relaxed);
    });
    if (among)
        parallel_for(count, kFillGrain, threads, [&](size_t b, size_t e, int) {
            for (size_t a = b; a < e; ++a) state[among[a]].store(kOpen, std::memory_order_relaxed);
        });
    auto before = [priority](uint32_t j, uint32_t i) {
        if (!priority) return j < i;
        return priority[j] > priority[i] || (priority[j] == priority[i] && j < i);
    };
    // an open point and the row positions of its open earlier neighbours within its radius
    struct Open {
        uint32_t i;
        uint64_t wait;
    };
    // Decides `o` if it can: whether it did.
    auto settle = [&](Open &o) {
        const uint32_t *row = nb.row(o.i);
        for (uint64_t w = o.wait; w; w &= w - 1) {
            const int m = __builtin_ctzll(w);
            const uint8_t s = state[row[m]].load(std::memory_order_relaxed);
            if (s == kKept) {
                state[o.i].store(kDropped, std::memory_order_relaxed);
                return true;
            }
            if (s == kDropped) o.wait &= ~(uint64_t(1) << m);
        }
        if (o.wait) return false;
        state[o.i].store(kKept, std::memory_order_relaxed);
        return true;
    };
    // first round: every point's earlier neighbours within its radius (the serial visit's
    // test: closer than the radius, or at the same position)
    std::vector<Open> open;
    const bool masked = k <= 64;
    if (masked) {
        constexpr size_t kGrain = 4096;
        std::vector<std::vector<Open>> parts((count + kGrain - 1) / kGrain);
        parallel_for(count, kGrain, threads, [&](size_t b, size_t e, int) {
            std::vector<Open> &part = parts[b / kGrain];
            for (size_t a = b; a < e; ++a) {
                const uint32_t i = among ? among[a] : uint32_t(a);
                const double r2 = thin * thin * spacing[i] * spacing[i];
                const uint32_t *row = nb.row(i);
                const double *q = points + 3 * size_t(i);
                const double pi = priority ? priority[i] : 0.0;
                // every neighbour tested without a branch (the priorities' order is random:
                // branching on it mispredicted about every other neighbour): the earlier ones
                // within the radius, kept or open
                uint64_t kept = 0, open_near = 0;
                for (uint32_t m = 0; m < k; ++m) {
                    const uint32_t j = row[m];
                    const uint8_t s = state[j].load(std::memory_order_relaxed);
                    const double pj = priority ? priority[j] : 0.0;
                    const bool earlier = (pj > pi) | ((pj == pi) & (j < i));
                    const double d2 = dist2(points + 3 * size_t(j), q);
                    const bool hit = earlier & ((d2 < r2) | (d2 == 0.0));
                    kept |= uint64_t(hit & (s == kKept)) << m;
                    open_near |= uint64_t(hit & (s == kOpen)) << m;
                }
                Open o{i, open_near};
                if (kept) state[i].store(kDropped, std::memory_order_relaxed);
                else if (!settle(o)) part.push_back(o);
            }
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
        size_t total = 0;
        for (const auto &part : parts) total += part.size();
        open.reserve(total);
        for (const auto &part : parts) open.insert(open.end(), part.begin(), part.end());
        // further rounds while they settle a good share of what is open
        constexpr size_t kSerialBelow = 2048;
        while (open.size() >= kSerialBelow) {
            std::vector<uint8_t> done(open.size(), 0);
            parallel_for(open.size(), kGrain, threads, [&](size_t b, size_t e, int) {
                for (size_t a = b; a < e; ++a) done[a] = settle(open[a]);
            }, progress ? &progress->cancel : nullptr);
            check_cancel(progress);
            size_t w = 0;
            for (size_t a = 0; a < open.size(); ++a)
                if (!done[a]) open[w++] = open[a];
            const size_t settled = open.size() - w;
            open.resize(w);
            if (settled * 8 < w) break;
        }
    } else {
        open.reserve(count);
        for (size_t a = 0; a < count; ++a) open.push_back(Open{among ? among[a] : uint32_t(a), 0});
    }
    // the rest in the serial visit's order: each point's earlier neighbours are decided by then
    std::sort(open.begin(), open.end(), [&](const Open &a, const Open &b) { return before(a.i, b.i); });
    for (Open &o : open) {
        if (masked) {
            settle(o);
            continue;
        }
        const uint32_t i = o.i;
        const double r2 = thin * thin * spacing[i] * spacing[i];
        const uint32_t *row = nb.row(i);
        const double *q = points + 3 * size_t(i);
        bool redundant = false;
        for (uint32_t m = 0; m < k && !redundant; ++m) {
            const uint32_t j = row[m];
            if (state[j].load(std::memory_order_relaxed) != kKept) continue;
            const double d2 = dist2(points + 3 * size_t(j), q);
            redundant = d2 < r2 || d2 == 0.0;
        }
        state[i].store(redundant ? kDropped : kKept, std::memory_order_relaxed);
    }
    parallel_for(n, kFillGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) keep[i] = state[i].load(std::memory_order_relaxed) == kKept;
    });
    return keep;
}

FitResult fit_surface(const double *points, const float *normals, const uint32_t *support,
                      const NeighbourTable &nb, const int32_t *group, const double *viewpoints,
                      size_t n_viewpoints, const FitOptions &opt, Progress *progress) {
    size_t n = nb.n;
    FitResult res;
    res.points.resize(3 * n);
    res.normals.resize(3 * n);
    parallel_for(n, size_t(1) << 15, opt.threads, [&](size_t b, size_t e, int) {
        std::copy(points + 3 * b, points + 3 * e, res.points.begin() + 3 * b);
        std::copy(normals + 3 * b, normals + 3 * e, res.normals.begin() + 3 * b);
    });
    res.keep.assign(n, 1);
    res.shift.assign(n, 0.f);
    res.spacing.assign(n, 0.0);
    res.kept = n;
    if (n == 0 || nb.k < 2) return res;
    constexpr size_t kGrain = 1024;
    // each point's spacing within its own scan (its nearest neighbour from the same scan)
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            const uint32_t *row = nb.row(i);
            uint32_t j = row[0];
            for (uint32_t m = 0; m < nb.k; ++m)
                if (!group || group[row[m]] == group[i]) {
                    j = row[m];
                    break;
                }
            res.spacing[i] = std::sqrt(dist2(points + 3 * size_t(j), points + 3 * i));
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    std::vector<uint8_t> moved(n, 0);
    // each pass fits the previous pass's positions and normals (the first: the input's): the
    // noise left after one fit is ~1/sqrt(support) of the input's, so the next fit's normals
    // are that much better, and the surface is fitted over a wider effective support
    UnfilledVector<double> src_p;
    UnfilledVector<float> src_n;
    constexpr size_t kCopyGrain = size_t(1) << 15;
    int passes = std::max(opt.passes, 1);
    // the plane passes before a last quadric pass each pull the points toward the concave
    // side; the quadric estimates that pull and it is given back after the last pass
    const bool unpull = opt.quadric && passes > 1;
    std::vector<double> pull(unpull ? n : 0, 0.0);
    std::vector<uint8_t> last(unpull ? n : 0, kNotMoved);
    // With more than one pass a first thinning (at kEarlyThin x the radius) runs before the
    // last pass, on the previous pass's positions and normals, and the last pass fits only the
    // points it keeps (over all points' positions): where scans overlap most points are
    // dropped, and their last fit would be thrown away. The thinning proper then runs among
    // those points on their final positions and normals.
    const bool thin = opt.thin > 0;
    const bool thin_early = thin && passes > 1;
    std::vector<uint32_t> active;  // the points the last pass fits (thin_early)
    for (int pass = 0; pass < passes; ++pass) {
        const double *sp = points;
        const float *sn = normals;
        if (pass > 0) {
            // copied on the workers (one thread would leave the other cores idle)
            src_p.resize(3 * n);
            src_n.resize(3 * n);
            parallel_for(n, kCopyGrain, opt.threads, [&](size_t b, size_t e, int) {
                std::copy(res.points.begin() + 3 * b, res.points.begin() + 3 * e,
                          src_p.begin() + 3 * b);
                std::copy(res.normals.begin() + 3 * b, res.normals.begin() + 3 * e,
                          src_n.begin() + 3 * b);
            });
            sp = src_p.data();
            sn = src_n.data();
        }
        bool final_pass = pass == passes - 1;
        bool quadric = opt.quadric && final_pass;
        if (final_pass && thin_early) {
            thin_points(res, nb, viewpoints, n_viewpoints, kEarlyThin * opt.thin, nullptr,
                        opt.threads, progress);
            active.reserve(res.kept);
            for (size_t i = 0; i < n; ++i)
                if (res.keep[i]) active.push_back(uint32_t(i));
        }
        const bool subset = final_pass && thin_early;
        const size_t count = subset ? active.size() : n;
        if (progress) progress->total.fetch_add(count, std::memory_order_relaxed);
        parallel_for(count, kGrain, opt.threads, [&](size_t b, size_t e, int) {
            FitScratch scratch;
            for (size_t a = b; a < e; ++a) {
                size_t i = subset ? active[a] : a;
                uint32_t k = std::max<uint32_t>(support ? support[i] : opt.min_support,
                                                opt.min_support);
                k = std::min<uint32_t>(k, nb.k + 1);
                double *out_pull = unpull && quadric ? &pull[i] : nullptr;
                if (out_pull) *out_pull = std::nan("");
                if (fit_point(sp, sn, i, nb.row(i), k, opt, quadric, final_pass, scratch,
                              &res.points[3 * i], &res.normals[3 * i], out_pull)) {
                    moved[i] |= 1;
                    if (out_pull) last[i] = std::isfinite(*out_pull) ? kPullEstimated : kMoved;
                }
            }
            if (progress) progress->advance(e - b);
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
    }
    if (unpull) give_back_pull(res, nb, pull, last, double(passes - 1), opt.threads, progress);
    res.unmoved = n - size_t(std::count(moved.begin(), moved.end(), uint8_t(1)));
    // how far each point moved
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i)
            res.shift[i] = float(std::sqrt(dist2(&res.points[3 * i], points + 3 * i)));
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    if (thin)
        thin_points(res, nb, viewpoints, n_viewpoints, opt.thin, thin_early ? &active : nullptr,
                    opt.threads, progress);
    return res;
}

}  // namespace pointviz
