// pointviz — connected components of the spacing-limited neighbour graph and the stray clusters
// among them (see components.h).
#include "pointviz/components.h"

#include <algorithm>
#include <cmath>

#include "pointviz/parallel.h"

namespace pointviz {

namespace {

double distance(const double *a, const double *b) {
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
}

/// Whether two points `d2` (squared distance) apart are within `limit`: distance(a, b) <=
/// limit, decided as that test does (the correctly rounded root compared), without the root
/// unless d2 lies within 1e-12 of limit^2 (beyond that margin the root's rounding cannot change
/// the answer).
bool within(double d2, double limit) {
    const double l2 = limit * limit;
    if (!(l2 > 1e-290 && l2 < 1e290)) return std::sqrt(d2) <= limit;  // squares out of range
    if (d2 < l2 * (1.0 - 1e-12)) return true;
    if (d2 > l2 * (1.0 + 1e-12)) return false;
    return std::sqrt(d2) <= limit;
}

double distance2(const double *a, const double *b) {
    double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]};
    return d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
}

/// Root of i, halving the path on the way (each visited node then points to its grandparent).
uint32_t find_root(std::vector<uint32_t> &parent, uint32_t i) {
    while (parent[i] != i) {
        parent[i] = parent[parent[i]];
        i = parent[i];
    }
    return i;
}

}  // namespace

StrayResult find_stray_clusters(const double *points, const NeighbourTable &nb,
                                const int32_t *group, const StrayOptions &opt,
                                Progress *progress) {
    size_t n = nb.n;
    StrayResult res;
    res.stray.assign(n, 0);
    res.label.assign(n, 0);
    if (n == 0) return res;
    constexpr size_t kGrain = 4096;
    if (progress) progress->total.fetch_add(2 * n, std::memory_order_relaxed);
    // spacing: the rank-th nearest distinct neighbour in the point's own scan (duplicates and
    // the other scans' layers lie closer, and would cut a scan's grid apart); the farthest
    // listed neighbour when the row holds fewer of its scan
    std::vector<double> spacing(n, 0.0);
    uint32_t rank = std::max<uint32_t>(opt.rank, 1);
    parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            const uint32_t *row = nb.row(i);
            double s = 0;
            uint32_t own = 0;
            for (uint32_t m = 0; m < nb.k && own < rank; ++m) {
                double d = distance(points + 3 * size_t(row[m]), points + 3 * i);
                if (d > 0) s = d;
                if (d > 0 && (!group || group[row[m]] == group[i])) ++own;
            }
            spacing[i] = s;
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    // links: each point to the neighbours within reach, then joined in index order. With more
    // than one thread the links are found in parallel first (a byte per table entry); on one
    // (the fit's stray thread) each is tested as the union-find meets it: no table of them.
    auto linked = [&](size_t i, uint32_t j) {
        return within(distance2(points + 3 * size_t(j), points + 3 * i),
                      opt.reach * std::min(spacing[i], spacing[j]));
    };
    const bool inline_links = resolve_threads(opt.threads) <= 1;
    std::vector<uint8_t> link(inline_links ? 0 : n * size_t(nb.k), 0);
    if (!inline_links) {
        parallel_for(n, kGrain, opt.threads, [&](size_t b, size_t e, int) {
            for (size_t i = b; i < e; ++i) {
                const uint32_t *row = nb.row(i);
                for (uint32_t m = 0; m < nb.k; ++m) link[i * nb.k + m] = linked(i, row[m]);
            }
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
    }
    std::vector<uint32_t> parent(n);
    for (size_t i = 0; i < n; ++i) parent[i] = uint32_t(i);
    for (size_t b = 0; b < n; b += kGrain) {
        size_t e = std::min(n, b + kGrain);
        for (size_t i = b; i < e; ++i) {
            // i's root, kept current as its neighbours' components join it (the root of a
            // component is its smallest index)
            uint32_t a = find_root(parent, uint32_t(i));
            const uint32_t *row = nb.row(i);
            for (uint32_t m = 0; m < nb.k; ++m) {
                if (inline_links ? !linked(i, row[m]) : !link[i * nb.k + m]) continue;
                uint32_t c = find_root(parent, row[m]);
                if (c > a) {
                    parent[c] = a;
                } else if (c < a) {
                    parent[a] = c;
                    a = c;
                }
            }
        }
        if (progress) progress->advance(e - b);
        check_cancel(progress);
    }
    // number the components by their first point; count their sizes
    std::vector<uint32_t> size;
    std::vector<uint32_t> number(n, kNoIndex);
    for (size_t i = 0; i < n; ++i) {
        uint32_t r = find_root(parent, uint32_t(i));
        if (number[r] == kNoIndex) {
            number[r] = uint32_t(size.size());
            size.push_back(0);
        }
        res.label[i] = number[r];
        ++size[number[r]];
    }
    res.components = size.size();
    size_t largest = size_t(std::max_element(size.begin(), size.end()) - size.begin());
    double below = std::max(double(opt.min_points), opt.fraction * double(n));
    std::vector<uint8_t> stray(size.size(), 0);
    for (size_t c = 0; c < size.size(); ++c)
        if (c != largest && double(size[c]) < below) {
            stray[c] = 1;
            ++res.clusters;
            res.points += size[c];
        }
    for (size_t i = 0; i < n; ++i) res.stray[i] = stray[res.label[i]];
    return res;
}

}  // namespace pointviz
