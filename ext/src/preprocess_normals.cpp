// pointviz — adaptive weighted-PCA normals (see normals.h).
#include "pointviz/normals.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "pointviz/parallel.h"
#include "pointviz/pca.h"

namespace pointviz {

namespace {

/// The weight of a neighbour at distance d in a neighbourhood whose farthest member is at
/// d_k is (1 - d^2 / h^2)^2 with h = kWeightReach * d_k: the farthest member keeps 31% weight,
/// so a neighbourhood of k points does not shrink to far fewer effective samples.
constexpr double kWeightReach = 1.5;

struct Fit {
    Principal axes;
    double sigma2 = 0;  ///< residual variance about the plane (degrees-of-freedom corrected)
    double gain = 0;    ///< squared angular standard error of the normal per unit sigma2
    double spread = 0;  ///< RMS distance from the plane
    uint32_t distinct = 1;  ///< distinct positions (distinct distances from the point)
};

/// A plane through a few positions fits them exactly whatever the surface does: a
/// neighbourhood needs this many distinct positions to count (stacks of duplicates can fill
/// the smallest neighbourhoods with two or three).
constexpr uint32_t kMinDistinct = 6;

/// A neighbour's position relative to the point and its squared distance.
struct Rel {
    double x[3];
    double d2;
};

/// Point i's first `m` neighbours relative to it (`out` holds m entries).
void relative(const double *points, size_t i, const uint32_t *row, uint32_t m, Rel *out) {
    const double *p = points + 3 * i;
    for (uint32_t j = 0; j < m; ++j) {
        const double *q = points + 3 * size_t(row[j]);
        Rel &r = out[j];
        r.x[0] = q[0] - p[0];
        r.x[1] = q[1] - p[1];
        r.x[2] = q[2] - p[2];
        r.d2 = r.x[0] * r.x[0] + r.x[1] * r.x[1] + r.x[2] * r.x[2];
    }
}

/// Weighted plane of a point and its first k - 1 neighbours (`rel`, from relative()).
Fit fit_plane(const Rel *rel, uint32_t k) {
    double h2 = kWeightReach * kWeightReach * rel[k - 2].d2;
    double s0 = 1.0, s1[3] = {0, 0, 0}, s2[6] = {0, 0, 0, 0, 0, 0}, sw2 = 1.0;  // the point: w = 1
    uint32_t distinct = 1;
    double prev[3] = {0.0, 0.0, 0.0};
    for (uint32_t m = 0; m + 1 < k; ++m) {
        const double *x = rel[m].x;
        double d2 = rel[m].d2;
        // rows are sorted by distance, then index: copies of one position are adjacent unless
        // another position lies at exactly the same distance (then this overcounts a little)
        distinct += x[0] != prev[0] || x[1] != prev[1] || x[2] != prev[2];
        prev[0] = x[0], prev[1] = x[1], prev[2] = x[2];
        double u = h2 > 0 ? 1.0 - d2 / h2 : 1.0;
        double w = u * u;
        s0 += w;
        sw2 += w * w;
        for (int a = 0; a < 3; ++a) s1[a] += w * x[a];
        s2[0] += w * x[0] * x[0];
        s2[1] += w * x[0] * x[1];
        s2[2] += w * x[0] * x[2];
        s2[3] += w * x[1] * x[1];
        s2[4] += w * x[1] * x[2];
        s2[5] += w * x[2] * x[2];
    }
    double c[3] = {s1[0] / s0, s1[1] / s0, s1[2] / s0};
    double cov[6] = {s2[0] / s0 - c[0] * c[0], s2[1] / s0 - c[0] * c[1], s2[2] / s0 - c[0] * c[2],
                     s2[3] / s0 - c[1] * c[1], s2[4] / s0 - c[1] * c[2], s2[5] / s0 - c[2] * c[2]};
    Fit f;
    f.distinct = distinct;
    f.axes = principal_axes(cov, kPlanarMinGap);
    f.axes.ok = f.axes.ok && distinct >= std::min(kMinDistinct, k);  // tiny clouds: all points
    double l0 = std::max(f.axes.l0, 0.0);
    f.spread = std::sqrt(l0);
    if (f.axes.ok) {
        // slope variance of a least-squares plane: residual variance / (n_eff * tangent spread)
        double n_eff = std::min(s0 * s0 / sw2, double(distinct));
        f.sigma2 = l0 * n_eff / std::max(n_eff - 3.0, 1.0);
        f.gain = (1.0 / f.axes.l1 + 1.0 / f.axes.l2) / n_eff;
    }
    return f;
}

/// What pass 2 of estimate_normals uses of a Fit (the smallest size's, fitted in pass 1).
struct SmallFit {
    // no initialisers: a table of them is left unfilled until pass 1 writes every entry
    double n[3];
    double gain, spread;
    bool ok;
    SmallFit() = default;
    explicit SmallFit(const Fit &f)
        : n{f.axes.n[0], f.axes.n[1], f.axes.n[2]}, gain(f.gain), spread(f.spread),
          ok(f.axes.ok) {}
    Fit fit() const {
        Fit f;
        for (int a = 0; a < 3; ++a) f.axes.n[a] = n[a];
        f.axes.ok = ok;
        f.gain = gain;
        f.spread = spread;
        return f;
    }
};

/// sin^2 of the angle between two normals that rounding alone can produce (exact planes have a
/// standard error of 0).
constexpr double kAngleRounding = 1e-12;

double sin2(const double *a, const double *b) {
    double d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
    return std::max(0.0, 1.0 - d * d);
}

}  // namespace

NormalResult estimate_normals(const double *points, const NeighbourTable &nb,
                              const NormalOptions &opt, Progress *progress,
                              const uint32_t *count) {
    size_t n = nb.n;
    if (opt.k_min < 3 || opt.k_max < opt.k_min)
        throw std::invalid_argument("normals: need 3 <= k_min <= k_max");
    if (!(opt.growth > 1.0 && opt.growth <= 1e3))
        throw std::invalid_argument("normals: need a growth factor in (1, 1000]");
    NormalResult out;
    out.normals.assign(3 * n, 0.f);
    out.support.assign(n, 0);
    out.spread.assign(n, 0.f);
    if (n == 0) return out;
    // neighbourhood sizes tried, the point included, capped by what the table holds
    uint32_t cap = std::min<uint32_t>(opt.k_max, nb.k + 1);
    std::vector<uint32_t> sizes;
    for (double s = opt.k_min; uint32_t(s) < cap; s *= opt.growth) sizes.push_back(uint32_t(s));
    sizes.push_back(cap);
    if (cap < 3) throw std::invalid_argument("normals: need at least 3 points");
    if (count)
        for (size_t i = 0; i < n; ++i)
            if (count[i] + 1 < std::min(sizes.front(), cap) || count[i] > nb.k)
                throw std::invalid_argument("normals: a row holds fewer neighbours than k_min - 1");
    std::vector<uint8_t> good(n, 0);
    if (progress) progress->total.fetch_add(n, std::memory_order_relaxed);
    constexpr size_t kGrain = 1024;
    double gamma2 = opt.confidence * opt.confidence;
    // pass 1: the residual variance of every point's smallest neighbourhood; its fit is kept
    // for pass 2, whose first size it is
    uint32_t k0 = sizes.front();
    UnfilledVector<double> sigma2(n);  // every entry written by pass 1
    UnfilledVector<SmallFit> first(n);
    if (progress) progress->total.fetch_add(n, std::memory_order_relaxed);
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        std::vector<Rel> rel(k0);
        for (size_t i = b; i < e; ++i) {
            relative(points, i, nb.row(i), k0 - 1, rel.data());
            Fit f = fit_plane(rel.data(), k0);
            sigma2[i] = f.sigma2;
            first[i] = SmallFit(f);
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    // pass 2: grow each neighbourhood while its normal agrees with every smaller one's
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        std::vector<double> local(k0);
        std::vector<Rel> rel(cap);
        for (size_t i = b; i < e; ++i) {
            const uint32_t *row = nb.row(i);
            // a shorter row: the sizes below its length, then its length
            const uint32_t cap_i = count ? std::min(cap, count[i] + 1) : cap;
            // every size's neighbours, gathered once (each size reweights them)
            relative(points, i, row, cap_i - 1, rel.data());
            // the noise level: the median residual variance around the point. One small
            // neighbourhood's own can be near 0 by chance (a few noisy samples may happen to lie
            // on a plane); the median over the first ring is not.
            local[0] = sigma2[i];
            for (uint32_t m = 0; m + 1 < k0; ++m) local[m + 1] = sigma2[row[m]];
            std::nth_element(local.begin(), local.begin() + k0 / 2, local.end());
            double noise2 = local[k0 / 2];
            Fit best;
            uint32_t best_k = 0;
            Fit accepted[16];
            int n_acc = 0;
            for (uint32_t k : sizes) {
                if (k > cap_i) k = cap_i;
                const bool last = k == cap_i;
                Fit f = k == k0 ? first[i].fit() : fit_plane(rel.data(), k);
                if (!f.axes.ok) {
                    if (n_acc == 0 && !last) continue;  // a line at small scale may become a plane
                    break;
                }
                bool agrees = true;
                for (int a = 0; a < n_acc && agrees; ++a)
                    agrees = sin2(f.axes.n, accepted[a].axes.n) <=
                             gamma2 * noise2 * (f.gain + accepted[a].gain) + kAngleRounding;
                if (!agrees) break;
                if (n_acc < 16) accepted[n_acc++] = f;
                best = f;
                best_k = k;
                if (last) break;
            }
            if (best_k) {
                for (int a = 0; a < 3; ++a) out.normals[3 * i + a] = float(best.axes.n[a]);
                out.support[i] = best_k;
                out.spread[i] = float(best.spread);
                good[i] = 1;
            }
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    // lines and stacks of duplicates: the normal of the nearest neighbour that has one; failing
    // that, a direction perpendicular to the line towards the farthest neighbour (or +z)
    for (size_t i = 0; i < n; ++i) {
        if (good[i]) continue;
        const uint32_t *row = nb.row(i);
        const uint32_t len = count ? count[i] : nb.k;
        uint32_t src = kNoIndex;
        for (uint32_t m = 0; m < len && src == kNoIndex; ++m)
            if (good[row[m]]) src = row[m];
        out.support[i] = std::min<uint32_t>(len + 1, opt.k_min);
        if (src != kNoIndex) {
            for (int a = 0; a < 3; ++a) out.normals[3 * i + a] = out.normals[3 * size_t(src) + a];
            ++out.borrowed;
            continue;
        }
        double d[3] = {0, 0, 0};
        if (len) {
            const double *q = points + 3 * size_t(row[len - 1]), *p = points + 3 * i;
            for (int a = 0; a < 3; ++a) d[a] = q[a] - p[a];
        }
        double l = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        double nrm[3] = {0, 0, 1};
        if (l > 0) {
            double u[3] = {d[0] / l, d[1] / l, d[2] / l}, t1[3], t2[3];
            tangent_basis(u, t1, t2);  // t1 is perpendicular to the line
            for (int a = 0; a < 3; ++a) nrm[a] = t1[a];
        }
        for (int a = 0; a < 3; ++a) out.normals[3 * i + a] = float(nrm[a]);
        ++out.arbitrary;
    }
    return out;
}

}  // namespace pointviz
