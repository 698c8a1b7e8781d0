// pointviz — planes over pixel patches of a depth-camera frame (see depth_planes.h). Each step
// follows pointviz/depth_steps.py's numpy version (patch_planes_numpy) operation for operation,
// in the same order, so that the results differ only by libm's arccos / cos against numpy's.
#include "pointviz/depth_planes.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pointviz/parallel.h"

namespace pointviz {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr size_t kGrain = 2048;
/// Moments per pixel: 1, x, y, z, xx, xy, xz, yy, yz, zz (centred coordinates).
constexpr int kMoments = 10;
/// The covariance's upper triangle, in the order of the moments' products.
constexpr int kPairs[6][2] = {{0, 0}, {0, 1}, {0, 2}, {1, 1}, {1, 2}, {2, 2}};
/// FLYING_SPANS: (pixels to one side, pixels to the other) of the two surfaces around a pixel.
constexpr int kSpans[3][2] = {{1, 1}, {1, 2}, {2, 1}};
constexpr int kReach = 3;  // max over the spans of max(a, b) + 1

/// numpy.maximum: NaN when either is NaN.
double np_max(double a, double b) {
    if (std::isnan(a) || std::isnan(b)) return kNaN;
    return a > b ? a : b;
}
/// numpy.minimum.
double np_min(double a, double b) {
    if (std::isnan(a) || std::isnan(b)) return kNaN;
    return a < b ? a : b;
}

/// numpy.median of `v` (reordered): the middle value, or the mean of the two middle ones; NaN
/// when any is NaN.
double np_median(std::vector<double> &v) {
    if (v.empty()) return kNaN;
    for (double x : v)
        if (std::isnan(x)) return kNaN;
    size_t k = v.size() / 2;
    std::nth_element(v.begin(), v.begin() + ptrdiff_t(k), v.end());
    double hi = v[k];
    if (v.size() % 2) return hi;
    double lo = *std::max_element(v.begin(), v.begin() + ptrdiff_t(k));
    return (lo + hi) / 2.0;
}

void poll(Progress *progress) { check_cancel(progress); }
const std::atomic<bool> *stop_flag(Progress *progress) {
    return progress ? &progress->cancel : nullptr;
}

/// A summed-area table (hh + 1, ww + 1, kMoments) of the moment images over a window of the
/// frame, zero first row and column.
struct SumTable {
    size_t hh = 0, ww = 0;
    std::vector<double> s;
    const double *at(size_t r, size_t c) const { return s.data() + (r * (ww + 1) + c) * kMoments; }
};

/// Builds `t` over the window (r0, c0, hh, ww) of the frame (width `w`) from the moments of the
/// point at each pixel (`pix`: the frame's pixel -> point, -1: none), only of points whose
/// `label` is `seg` when `label` is given. As numpy sums it: down the columns (each row plus
/// the one above), then along each row.
void build_table(SumTable &t, size_t r0, size_t c0, size_t hh, size_t ww, size_t w,
                 const int64_t *pix, const double *mom, const int32_t *label, int32_t seg,
                 int threads, Progress *progress) {
    t.hh = hh;
    t.ww = ww;
    const size_t stride = (ww + 1) * kMoments;
    t.s.resize((hh + 1) * stride);
    double *s = t.s.data();
    std::fill(s, s + stride, 0.0);
    for (size_t i = 1; i <= hh; ++i) std::fill(s + i * stride, s + i * stride + kMoments, 0.0);
    // down the columns, in blocks of columns
    constexpr size_t kCols = 64;
    parallel_for((ww + kCols - 1) / kCols, 1, threads, [&](size_t b, size_t e, int) {
        for (size_t blk = b; blk < e; ++blk) {
            size_t j0 = blk * kCols, j1 = std::min(ww, j0 + kCols);
            for (size_t i = 0; i < hh; ++i) {
                const int64_t *prow = pix + (r0 + i) * w + c0;
                const double *above = s + i * stride;
                double *row = s + (i + 1) * stride;
                for (size_t j = j0; j < j1; ++j) {
                    const double *up = above + (j + 1) * kMoments;
                    double *out = row + (j + 1) * kMoments;
                    int64_t p = prow[j];
                    if (p >= 0 && (!label || label[p] == seg)) {
                        const double *m = mom + size_t(p) * kMoments;
                        if (i == 0)
                            for (int k = 0; k < kMoments; ++k) out[k] = m[k];
                        else
                            for (int k = 0; k < kMoments; ++k) out[k] = m[k] + up[k];
                    } else {
                        for (int k = 0; k < kMoments; ++k) out[k] = up[k];
                    }
                }
            }
        }
    }, stop_flag(progress));
    poll(progress);
    // along the rows
    parallel_for(hh, 64, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b + 1; i <= e; ++i) {
            double *row = s + i * stride;
            for (size_t j = 2; j <= ww; ++j) {
                double *out = row + j * kMoments;
                const double *left = out - kMoments;
                for (int k = 0; k < kMoments; ++k) out[k] = left[k] + out[k];
            }
        }
    }, stop_flag(progress));
    poll(progress);
}

/// Moment sums of the (2r+1)^2 patch around (row, col) (window coordinates), clipped at the
/// window's border: four reads, combined as numpy does.
void patch_sums(const SumTable &t, int64_t row, int64_t col, int r, double out[kMoments]) {
    auto clip = [](int64_t v, size_t hi) { return size_t(std::min<int64_t>(std::max<int64_t>(v, 0), int64_t(hi))); };
    size_t ra = clip(row - r, t.hh), rb = clip(row + r + 1, t.hh);
    size_t ca = clip(col - r, t.ww), cb = clip(col + r + 1, t.ww);
    const double *a = t.at(rb, cb), *b = t.at(ra, cb), *c = t.at(rb, ca), *d = t.at(ra, ca);
    for (int k = 0; k < kMoments; ++k) out[k] = ((a[k] - b[k]) - c[k]) + d[k];
}

}  // namespace

void smallest_eigen(const double a[6], double &smallest, double &middle, double vec[3]) {
    const double a00 = a[0], a01 = a[1], a02 = a[2], a11 = a[3], a12 = a[4], a22 = a[5];
    double m = (a00 + a11 + a22) / 3.0;
    double b00 = a00 - m, b11 = a11 - m, b22 = a22 - m;
    double p = (b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) /
               6.0;
    double det = (b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) +
                  a02 * (a01 * a12 - b11 * a02));
    double sp = std::sqrt(p);
    double q = det / (2.0 * p * sp);
    if (!std::isnan(q)) q = std::min(std::max(q, -1.0), 1.0);
    double phi = std::acos(q) / 3.0;
    if (std::isnan(phi)) phi = 0.0;  // numpy.nan_to_num
    constexpr double kThird = 2.0943951023931953;  // 2 pi / 3
    double largest = m + 2.0 * sp * std::cos(phi);
    smallest = m + 2.0 * sp * std::cos(phi + kThird);
    middle = 3.0 * m - largest - smallest;
    double d0 = a00 - smallest, d1 = a11 - smallest, d2 = a22 - smallest;
    const double cand[3][3] = {
        {a01 * a12 - a02 * d1, a02 * a01 - d0 * a12, d0 * d1 - a01 * a01},
        {a01 * d2 - a02 * a12, a02 * a02 - d0 * d2, d0 * a12 - a01 * a02},
        {d1 * d2 - a12 * a12, a12 * a02 - a01 * d2, a01 * a12 - d1 * a02}};
    double norm[3];
    for (int k = 0; k < 3; ++k)
        norm[k] = std::sqrt(cand[k][0] * cand[k][0] + cand[k][1] * cand[k][1] +
                            cand[k][2] * cand[k][2]);
    int best = 0;  // numpy.argmax: the first largest, or the first NaN
    for (int k = 1; k < 3 && !std::isnan(norm[best]); ++k)
        if (std::isnan(norm[k]) || norm[k] > norm[best]) best = k;
    for (int i = 0; i < 3; ++i) vec[i] = cand[best][i] / norm[best];
}

PatchPlane patch_plane(const double s[10], const double ray[3]) {
    PatchPlane out;
    double cnt = s[0];
    for (int k = 0; k < 3; ++k) out.mean[k] = s[1 + k] / cnt;
    double cov[6];
    bool fine = cnt >= 3;
    for (int m = 0; m < 6; ++m) {
        cov[m] = s[4 + m] / cnt - out.mean[kPairs[m][0]] * out.mean[kPairs[m][1]];
        fine = fine && std::isfinite(cov[m]);
    }
    if (!fine)
        for (int m = 0; m < 6; ++m) cov[m] = kPairs[m][0] == kPairs[m][1] ? 1.0 : 0.0;
    double small, middle;
    smallest_eigen(cov, small, middle, out.normal);
    fine = fine && middle > 0;
    fine = fine && std::isfinite(out.normal[0]) && std::isfinite(out.normal[1]) &&
           std::isfinite(out.normal[2]);
    if (!fine)
        for (int k = 0; k < 3; ++k) out.normal[k] = -ray[k];
    double cos = std::fabs(out.normal[0] * ray[0] + out.normal[1] * ray[1] +
                           out.normal[2] * ray[2]);
    if (cos < 0.1) cos = 0.1;  // numpy.maximum (NaN stays NaN)
    if (small < 0.0) small = 0.0;
    out.residual = std::sqrt(small) / cos;
    out.fine = fine;
    return out;
}

std::vector<uint8_t> depth_flying_pixels(const double *R, const double *J, size_t h, size_t w,
                                         int threads) {
    std::vector<uint8_t> fly(h * w, 0);
    const int64_t H = int64_t(h), W = int64_t(w);
    parallel_for(h, 16, threads, [&](size_t b, size_t e, int) {
        for (int64_t y = int64_t(b); y < int64_t(e); ++y)
            for (int64_t x = 0; x < W; ++x) {
                const double r = R[y * W + x], j = J[y * W + x];
                const double lo = r - j, hi = r + j;
                bool out = false;
                constexpr int dirs[4][2] = {{0, 1}, {1, 0}, {1, 1}, {1, -1}};
                for (const auto &dir : dirs) {
                    double at[2 * kReach + 1];  // at[kReach + k]: k pixels along the direction
                    for (int k = -kReach; k <= kReach; ++k) {
                        int64_t yy = y + k * dir[0], xx = x + k * dir[1];
                        at[kReach + k] = (yy >= 0 && yy < H && xx >= 0 && xx < W)
                                             ? R[yy * W + xx] : kNaN;
                    }
                    auto A = [&](int k) { return at[kReach + k]; };
                    auto below = [&](int k) { return A(k) < lo; };
                    auto above = [&](int k) { return A(k) > hi; };
                    auto smooth = [&](int k) {
                        return std::fabs(A(k) - A(k + (k > 0 ? 1 : -1))) <= j;
                    };
                    for (const auto &span : kSpans) {
                        const int a = span[0], bb = span[1];
                        double near_a = A(-a), far_a = A(-(a + 1));
                        double near_b = A(bb), far_b = A(bb + 1);
                        bool between = (below(-a) && above(bb)) || (above(-a) && below(bb));
                        between = between && smooth(-a) && smooth(bb);
                        between = between &&
                                  std::fabs(r - near_a - double(a) * (near_a - far_a)) > j;
                        between = between &&
                                  std::fabs(r - near_b - double(bb) * (near_b - far_b)) > j;
                        out = out || between;
                    }
                }
                fly[size_t(y * W + x)] = out;
            }
    });
    return fly;
}

namespace {

uint32_t find_root(std::vector<uint32_t> &parent, uint32_t i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

void join(std::vector<uint32_t> &parent, uint32_t a, uint32_t b) {
    a = find_root(parent, a);
    b = find_root(parent, b);
    if (a < b) parent[b] = a;
    else if (b < a) parent[a] = b;
}

}  // namespace

size_t depth_segment_labels(const double *R, const double *J, const uint8_t *valid, size_t h,
                            size_t w, std::vector<int32_t> &labels) {
    const size_t n = h * w;
    std::vector<uint32_t> parent(n);
    for (size_t i = 0; i < n; ++i) parent[i] = uint32_t(i);
    auto linked = [&](size_t a, size_t b) {
        return valid[a] && valid[b] && std::fabs(R[a] - R[b]) <= np_min(J[a], J[b]);
    };
    for (size_t y = 0; y < h; ++y)
        for (size_t x = 0; x < w; ++x) {
            size_t i = y * w + x;
            if (!valid[i]) continue;
            if (x + 1 < w && linked(i, i + 1)) join(parent, uint32_t(i), uint32_t(i + 1));
            if (y + 1 < h && linked(i, i + w)) join(parent, uint32_t(i), uint32_t(i + w));
        }
    labels.assign(n, -1);
    std::vector<int32_t> number(n, -1);
    size_t count = 0;
    for (size_t i = 0; i < n; ++i) {
        if (!valid[i]) continue;
        uint32_t r = find_root(parent, uint32_t(i));
        if (number[r] < 0) number[r] = int32_t(count++);
        labels[i] = number[r];
    }
    return count;
}

DepthPlaneResult depth_patch_planes(const double *pts, size_t n, const int32_t *grid,
                                    const double vp[3], const double *step,
                                    const DepthPlaneOptions &opt, Progress *progress) {
    DepthPlaneResult res;
    res.points.assign(pts, pts + 3 * n);
    res.normals.assign(3 * n, 0.0f);
    res.radius.assign(n, 0);
    res.flying.assign(n, 0);
    if (n == 0) return res;
    const int threads = opt.threads;
    const size_t levels = opt.radii.size();
    size_t h = 0, w = 0;
    for (size_t i = 0; i < n; ++i) {
        h = std::max(h, size_t(grid[2 * i]) + 1);
        w = std::max(w, size_t(grid[2 * i + 1]) + 1);
    }
    const size_t pixels = h * w;
    if (progress) progress->total.fetch_add(3 * n + pixels, std::memory_order_relaxed);
    auto pixel = [&](size_t i) { return size_t(grid[2 * i]) * w + size_t(grid[2 * i + 1]); };

    // rays, ranges; a point at the camera (or beyond the doubles' range) is no measurement
    std::vector<double> rel(3 * n), rng(n), ray(3 * n);
    std::vector<uint8_t> seen(n);
    parallel_for(n, 16384, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            double *q = &rel[3 * i];
            for (int k = 0; k < 3; ++k) q[k] = pts[3 * i + k] - vp[k];
            double r = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]);
            if (!(r > 0)) r = kInf;
            rng[i] = r;
            seen[i] = std::isfinite(r);
            for (int k = 0; k < 3; ++k) ray[3 * i + k] = q[k] / r;
            if (std::isinf(r)) ray[3 * i] = 0.0, ray[3 * i + 1] = 0.0, ray[3 * i + 2] = 1.0;
        }
    });
    // each pixel's point (the last one given there, as numpy's scatter keeps): of all points
    // (the rays' angle), and of the seen ones (the moment tables, the range image)
    std::vector<int64_t> pix_all(pixels, -1), pix_seen(pixels, -1);
    for (size_t i = 0; i < n; ++i) {
        pix_all[pixel(i)] = int64_t(i);
        if (seen[i]) pix_seen[pixel(i)] = int64_t(i);
    }
    // the angle between neighbouring pixels' rays (median along the rows)
    {
        std::vector<double> gaps;
        gaps.reserve(n);
        for (size_t y = 0; y < h; ++y)
            for (size_t x = 0; x + 1 < w; ++x) {
                int64_t a = pix_all[y * w + x], b = pix_all[y * w + x + 1];
                if (a < 0 || b < 0) continue;
                double g = 0.0;
                for (int k = 0; k < 3; ++k) {
                    double d = ray[3 * size_t(a) + k] - ray[3 * size_t(b) + k];
                    g += d * d;
                }
                gaps.push_back(std::sqrt(g));
            }
        res.angle = gaps.empty() ? 0.0 : np_median(gaps);
    }
    poll(progress);
    // the moments of each point, centred on the frame's mean point (numpy's mean along the
    // points: summed in order, then divided)
    double centre[3] = {0.0, 0.0, 0.0};
    for (size_t i = 0; i < n; ++i)
        for (int k = 0; k < 3; ++k) centre[k] += pts[3 * i + k];
    for (int k = 0; k < 3; ++k) centre[k] /= double(n);
    std::vector<double> mom(kMoments * n), cen(3 * n);
    parallel_for(n, 16384, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            double *c = &cen[3 * i], *m = &mom[kMoments * i];
            for (int k = 0; k < 3; ++k) c[k] = pts[3 * i + k] - centre[k];
            m[0] = 1.0;
            for (int k = 0; k < 3; ++k) m[1 + k] = c[k];
            for (int q = 0; q < 6; ++q) m[4 + q] = c[kPairs[q][0]] * c[kPairs[q][1]];
        }
    });
    poll(progress);

    // the frame's noise in steps: the median over every noise_sample-th seen point of its
    // noise_radius patch's residual over its step
    SumTable table;
    build_table(table, 0, 0, h, w, w, pix_seen.data(), mom.data(), nullptr, 0, threads,
                progress);
    std::vector<size_t> sample;
    {
        size_t seen_count = 0;
        for (size_t i = 0; i < n; ++i)
            if (seen[i]) {
                if (seen_count % size_t(std::max(opt.noise_sample, 1)) == 0) sample.push_back(i);
                ++seen_count;
            }
    }
    std::vector<double> ratio(sample.size(), kNaN);
    std::vector<uint8_t> sample_fine(sample.size(), 0);
    parallel_for(sample.size(), kGrain, threads, [&](size_t b, size_t e, int) {
        double sums[kMoments];
        for (size_t s = b; s < e; ++s) {
            size_t i = sample[s];
            patch_sums(table, grid[2 * i], grid[2 * i + 1], opt.noise_radius, sums);
            PatchPlane pl = patch_plane(sums, &ray[3 * i]);
            sample_fine[s] = pl.fine;
            ratio[s] = pl.residual / step[i];
        }
        if (progress) progress->advance(e - b);
    }, stop_flag(progress));
    poll(progress);
    {
        std::vector<double> fine_ratio;
        fine_ratio.reserve(sample.size());
        for (size_t s = 0; s < sample.size(); ++s)
            if (sample_fine[s]) fine_ratio.push_back(ratio[s]);
        res.noise = fine_ratio.empty() ? 0.0 : np_median(fine_ratio);
    }
    const double floor_noise = 1.0 / std::sqrt(12.0);
    const double noise = floor_noise > res.noise ? floor_noise : res.noise;  // Python's max
    // per point: sigma, the residual limit, the starting patch
    std::vector<double> sigma(n), limit(n), foot(n);
    std::vector<int> choice(n);
    std::vector<double> width(levels), spread(levels);
    for (size_t l = 0; l < levels; ++l) {
        double rr = double(opt.radii[l]);
        width[l] = 2 * rr + 1;
        spread[l] = std::sqrt(rr * (rr + 1) / 3.0);
    }
    parallel_for(n, 16384, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            sigma[i] = step[i] * noise;
            limit[i] = np_max(opt.residual_steps * step[i], opt.residual_sigmas * sigma[i]);
            foot[i] = (std::isfinite(rng[i]) ? rng[i] : 0.0) * res.angle;
            double fp = np_max(foot[i], 1e-300);
            int c = int(levels) - 1;
            for (size_t l = 0; l + 1 < levels; ++l)
                if (sigma[i] / (width[l] * fp * spread[l]) <= opt.slope_error) {
                    c = int(l);
                    break;
                }
            choice[i] = c;
        }
    });

    std::vector<double> normal(3 * n, 0.0), mean(3 * n, 0.0);
    std::vector<uint8_t> stays(n, 0);
    std::vector<int> final_level(n, -1);
    // from each point's chosen patch down: the first whose residual says one surface (the
    // smallest is taken even when it spans two: the point then stays)
    auto fit_point = [&](const SumTable &t, size_t i, int64_t r0, int64_t c0) {
        double sums[kMoments];
        for (int level = choice[i]; level >= 0; --level) {
            patch_sums(t, grid[2 * i] - r0, grid[2 * i + 1] - c0, opt.radii[size_t(level)], sums);
            PatchPlane pl = patch_plane(sums, &ray[3 * i]);
            bool one = pl.fine && pl.residual <= limit[i];
            if (one || (level == 0 && pl.fine)) {
                for (int k = 0; k < 3; ++k) normal[3 * i + k] = pl.normal[k], mean[3 * i + k] = pl.mean[k];
                final_level[i] = level;
                stays[i] = !one;
                return;
            }
        }
    };

    if (!opt.edges) {
        parallel_for(n, kGrain, threads, [&](size_t b, size_t e, int) {
            for (size_t i = b; i < e; ++i)
                if (seen[i]) fit_point(table, i, 0, 0);
            if (progress) progress->advance(e - b);
        }, stop_flag(progress));
        poll(progress);
    } else {
        // depth edges and flying pixels, on the range image
        std::vector<double> jump(n), rimg(pixels, kNaN), jimg(pixels, kNaN);
        for (size_t i = 0; i < n; ++i)
            jump[i] = np_max(np_max(opt.edge_steps * step[i], opt.edge_sigmas * sigma[i]),
                             opt.edge_footprints * foot[i]);
        for (size_t p = 0; p < pixels; ++p)
            if (pix_seen[p] >= 0) {
                rimg[p] = rng[size_t(pix_seen[p])];
                jimg[p] = jump[size_t(pix_seen[p])];
            }
        std::vector<uint8_t> fly = depth_flying_pixels(rimg.data(), jimg.data(), h, w, threads);
        if (progress) progress->advance(pixels);
        poll(progress);
        std::vector<uint8_t> valid(pixels);
        for (size_t p = 0; p < pixels; ++p) valid[p] = std::isfinite(rimg[p]) && !fly[p];
        std::vector<int32_t> labels;
        size_t count = depth_segment_labels(rimg.data(), jimg.data(), valid.data(), h, w, labels);
        res.segments = count;
        poll(progress);
        std::vector<int32_t> label(n, -1);
        std::vector<uint32_t> size(count, 0);
        for (size_t i = 0; i < n; ++i) {
            res.flying[i] = fly[pixel(i)] && seen[i];
            if (seen[i] && !res.flying[i]) {
                label[i] = labels[pixel(i)];
                if (label[i] >= 0) ++size[size_t(label[i])];
            }
        }
        // small segments: one plane over each (its points' moments summed in order)
        std::vector<double> seg_sums;
        std::vector<int32_t> small_index(count, -1);
        size_t smalls = 0;
        for (size_t g = 0; g < count; ++g)
            if (size[g] < opt.small_segment) small_index[g] = int32_t(smalls++);
        seg_sums.assign(smalls * kMoments, 0.0);
        for (size_t i = 0; i < n; ++i)
            if (label[i] >= 0 && small_index[size_t(label[i])] >= 0) {
                double *s = &seg_sums[size_t(small_index[size_t(label[i])]) * kMoments];
                for (int k = 0; k < kMoments; ++k) s[k] += mom[kMoments * i + size_t(k)];
            }
        // the points of each segment, in index order
        std::vector<size_t> start(count + 1, 0);
        for (size_t g = 0; g < count; ++g) start[g + 1] = start[g] + size[g];
        std::vector<uint32_t> order(start[count]);
        {
            std::vector<size_t> fill(start.begin(), start.end() - 1);
            for (size_t i = 0; i < n; ++i)
                if (label[i] >= 0) order[fill[size_t(label[i])]++] = uint32_t(i);
        }
        parallel_for(n, kGrain, threads, [&](size_t b, size_t e, int) {
            for (size_t i = b; i < e; ++i) {
                if (label[i] < 0 || small_index[size_t(label[i])] < 0) continue;
                const double *s = &seg_sums[size_t(small_index[size_t(label[i])]) * kMoments];
                PatchPlane pl = patch_plane(s, &ray[3 * i]);
                if (!pl.fine) continue;
                for (int k = 0; k < 3; ++k) normal[3 * i + k] = pl.normal[k], mean[3 * i + k] = pl.mean[k];
                final_level[i] = 0;
                stays[i] = pl.residual > limit[i];
            }
        }, stop_flag(progress));
        poll(progress);
        // large segments: square patches over the segment's own pixels
        for (size_t g = 0; g < count; ++g) {
            if (size[g] < opt.small_segment) continue;
            const uint32_t *sel = order.data() + start[g];
            const size_t m = size[g];
            int64_t rlo = INT64_MAX, rhi = -1, clo = INT64_MAX, chi = -1;
            for (size_t s = 0; s < m; ++s) {
                int64_t r = grid[2 * size_t(sel[s])], c = grid[2 * size_t(sel[s]) + 1];
                rlo = std::min(rlo, r), rhi = std::max(rhi, r);
                clo = std::min(clo, c), chi = std::max(chi, c);
            }
            build_table(table, size_t(rlo), size_t(clo), size_t(rhi + 1 - rlo),
                        size_t(chi + 1 - clo), w, pix_seen.data(), mom.data(), label.data(),
                        int32_t(g), threads, progress);
            parallel_for(m, kGrain, threads, [&](size_t b, size_t e, int) {
                for (size_t s = b; s < e; ++s) fit_point(table, sel[s], rlo, clo);
                if (progress) progress->advance(e - b);
            }, stop_flag(progress));
            poll(progress);
        }
    }
    // normals toward the camera; each point onto its plane along its ray
    parallel_for(n, 16384, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            double *nr = &normal[3 * i];
            const double *q = &rel[3 * i], *r = &ray[3 * i], *c = &cen[3 * i], *mu = &mean[3 * i];
            double f = nr[0] * q[0] + nr[1] * q[1] + nr[2] * q[2];
            double sign = f > 0 ? -1.0 : 1.0;
            for (int k = 0; k < 3; ++k) nr[k] *= sign;
            double dn = nr[0] * r[0] + nr[1] * r[1] + nr[2] * r[2];
            double off[3] = {c[0] - mu[0], c[1] - mu[1], c[2] - mu[2]};
            double dist = nr[0] * off[0] + nr[1] * off[1] + nr[2] * off[2];
            double t = -dist / dn;
            double cap = np_max(opt.move_steps * step[i], opt.residual_sigmas * sigma[i]);
            bool move = final_level[i] >= 0 && !stays[i] && std::fabs(dn) > 0.1 &&
                        std::fabs(t) <= cap;
            double tt = move ? t : 0.0;
            for (int k = 0; k < 3; ++k) res.points[3 * i + k] = pts[3 * i + k] + tt * r[k];
            if (final_level[i] < 0)
                for (int k = 0; k < 3; ++k) nr[k] = -r[k];
            for (int k = 0; k < 3; ++k) res.normals[3 * i + k] = float(nr[k]);
            res.radius[i] = final_level[i] >= 0 ? opt.radii[size_t(final_level[i])] : 0;
        }
        if (progress) progress->advance(e - b);
    }, stop_flag(progress));
    poll(progress);
    return res;
}

}  // namespace pointviz
