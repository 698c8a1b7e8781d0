// pointviz — neighbours within each scan (see scan_neighbours.h).
#include "pointviz/scan_neighbours.h"

#include "pointviz/parallel.h"

#include <algorithm>
#include <atomic>
#include <map>
#include <stdexcept>
#include <vector>

namespace pointviz {

namespace {

/// The members of each group with more than k points, in index order (the caller's order keeps
/// them spatially coherent), the largest group first; the rows of the points of smaller groups
/// are filled here from `all` (neighbours among all points).
std::vector<std::vector<uint32_t>> large_groups(const double *points, size_t n,
                                                const int32_t *group, uint32_t k,
                                                const KnnTree &all, NeighbourTable &out) {
    if (all.size() != n || n <= k)
        throw std::invalid_argument("neighbours within scans: need a tree over more than k points");
    out.n = n;
    out.k = k;
    out.index.resize(n * size_t(k));
    std::map<int32_t, std::vector<uint32_t>> members;
    for (size_t i = 0; i < n; ++i) members[group[i]].push_back(uint32_t(i));
    std::vector<std::vector<uint32_t>> scans;
    std::vector<double> d2(k);
    for (auto &[g, ids] : members) {
        (void)g;
        if (ids.size() > k) {
            scans.push_back(std::move(ids));
            continue;
        }
        for (uint32_t i : ids)
            all.query(points + 3 * size_t(i), k, i, out.index.data() + size_t(i) * k, d2.data());
    }
    // largest first: the workers take scans in this order, and a large scan taken last would
    // leave the other workers idle while it runs (each scan fills its own rows: the table does
    // not depend on the order)
    std::stable_sort(scans.begin(), scans.end(),
                     [](const std::vector<uint32_t> &a, const std::vector<uint32_t> &b) {
                         return a.size() > b.size();
                     });
    return scans;
}

/// Rows of the points `ids[r]`, r in `which` (null: every member), from a KD-tree over the
/// scan's points `ids`, built and searched on the calling thread (a scan of a few ten thousand
/// points is too small to split).
void scan_tree_rows(const double *points, const std::vector<uint32_t> &ids,
                    const std::vector<uint32_t> *which, uint32_t k, NeighbourTable &out) {
    std::vector<double> sub(3 * ids.size());
    for (size_t r = 0; r < ids.size(); ++r)
        for (int a = 0; a < 3; ++a) sub[3 * r + a] = points[3 * size_t(ids[r]) + a];
    KnnTree tree(sub.data(), ids.size(), 1);
    auto copy_row = [&](size_t r, const uint32_t *src) {
        uint32_t *dst = out.index.data() + size_t(ids[r]) * k;
        for (uint32_t m = 0; m < k; ++m) dst[m] = ids[src[m]];
    };
    if (!which) {
        NeighbourTable t = knn_all(tree, sub.data(), k, 1);
        for (size_t r = 0; r < ids.size(); ++r) copy_row(r, t.row(r));
        return;
    }
    std::vector<uint32_t> idx(k);
    std::vector<double> d2(k);
    for (uint32_t r : *which) {
        tree.query(sub.data() + 3 * size_t(r), k, r, idx.data(), d2.data());
        copy_row(r, idx.data());
    }
}

/// One scan's points by grid cell, with a border of kGridMaxRing empty cells on every side (a
/// ring search never leaves the array): at[o], o = (row - row0 + pad) * stride + col - col0 + pad,
/// is the index of the point in that cell, or kNoIndex, and xyz[3 o ..] its coordinates. The
/// ring searches read the scan's coordinates in grid order, row by row, instead of from all
/// scans' points (in the KD-tree's order a scan's points are interleaved with the other
/// scans'): a ring's rows are contiguous, and consecutive queries share their rings.
struct CellMap {
    static constexpr int32_t pad = kGridMaxRing;
    int32_t row0 = 0, col0 = 0;
    size_t stride = 0;
    std::vector<uint32_t> at;
    std::vector<double> xyz;

    /// False when the scan's cells are not a grid of one point per cell (a shared cell) or the
    /// grid would be far larger than the scan (kMaxCellsPerPoint cells per point).
    bool build(const double *points, const int32_t *cell, const std::vector<uint32_t> &ids) {
        constexpr size_t kMaxCellsPerPoint = 64;
        int32_t r1 = -1, c1 = -1;
        row0 = col0 = INT32_MAX;
        for (uint32_t i : ids) {
            int32_t r = cell[2 * size_t(i)], c = cell[2 * size_t(i) + 1];
            if (r < 0 || c < 0) continue;
            row0 = std::min(row0, r), col0 = std::min(col0, c);
            r1 = std::max(r1, r), c1 = std::max(c1, c);
        }
        if (r1 < 0) return false;
        size_t rows = size_t(r1 - row0) + 1 + 2 * pad;
        stride = size_t(c1 - col0) + 1 + 2 * pad;
        if (rows * stride > kMaxCellsPerPoint * ids.size()) return false;
        at.assign(rows * stride, kNoIndex);
        xyz.assign(3 * rows * stride, 0.0);
        for (uint32_t i : ids) {
            int32_t r = cell[2 * size_t(i)], c = cell[2 * size_t(i) + 1];
            if (r < 0 || c < 0) continue;
            size_t o = offset(r, c);
            if (at[o] != kNoIndex) return false;
            at[o] = i;
            for (int a = 0; a < 3; ++a) xyz[3 * o + a] = points[3 * size_t(i) + a];
        }
        return true;
    }
    size_t offset(int32_t r, int32_t c) const {
        return size_t(r - row0 + pad) * stride + size_t(c - col0 + pad);
    }
};

/// The k nearest of the point in cell `centre` (an offset into `map`) among the samples of the
/// rings of cells around its own, into `best`; false when they were still changing at the last
/// ring (or fewer than k).
bool grid_search(const CellMap &map, size_t centre, KnnHeap &best) {
    const double *q = map.xyz.data() + 3 * centre;
    const double q0 = q[0], q1 = q[1], q2 = q[2];
    best.size = 0;
    const uint32_t *at = map.at.data();
    const double *xyz = map.xyz.data();
    const ptrdiff_t stride = ptrdiff_t(map.stride), c = ptrdiff_t(centre);
    bool any = false, entered = false;
    auto visit = [&](ptrdiff_t o) {
        uint32_t j = at[o];
        if (j == kNoIndex) return;
        const double *s = xyz + 3 * o;
        double d = (s[0] - q0) * (s[0] - q0) + (s[1] - q1) * (s[1] - q1) +
                   (s[2] - q2) * (s[2] - q2);
        any = true;
        entered |= best.push(d, j);
    };
    for (ptrdiff_t ring = 1; ring <= kGridMaxRing; ++ring) {
        any = entered = false;
        const ptrdiff_t top = c - ring * stride, bottom = c + ring * stride;
        for (ptrdiff_t dc = -ring; dc <= ring; ++dc) visit(top + dc);
        for (ptrdiff_t dr = -ring + 1; dr < ring; ++dr) {
            visit(c + dr * stride - ring);
            visit(c + dr * stride + ring);
        }
        for (ptrdiff_t dc = -ring; dc <= ring; ++dc) visit(bottom + dc);
        if (best.size == best.k && any && !entered) return true;
    }
    return false;
}

}  // namespace

NeighbourTable knn_within_groups(const double *points, size_t n, const int32_t *group,
                                 uint32_t k, const KnnTree &all, int threads,
                                 Progress *progress) {
    NeighbourTable out;
    std::vector<std::vector<uint32_t>> scans = large_groups(points, n, group, k, all, out);
    // one scan per worker at a time: a scan's tree and queries on one thread, the scans side by
    // side
    size_t queries = 0;
    for (const std::vector<uint32_t> &ids : scans) queries += ids.size();
    if (progress) progress->total.fetch_add(queries, std::memory_order_relaxed);
    parallel_for(scans.size(), 1, threads, [&](size_t b, size_t e, int) {
        for (size_t s = b; s < e; ++s) {
            scan_tree_rows(points, scans[s], nullptr, k, out);
            if (progress) progress->advance(scans[s].size());
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    return out;
}

NeighbourTable knn_within_grids(const double *points, size_t n, const int32_t *group,
                                const int32_t *cell, uint32_t k, const KnnTree &all, int threads,
                                Progress *progress, GridNeighbourStats *stats) {
    NeighbourTable out;
    std::vector<std::vector<uint32_t>> scans = large_groups(points, n, group, k, all, out);
    size_t queries = 0;
    for (const std::vector<uint32_t> &ids : scans) queries += ids.size();
    if (progress) progress->total.fetch_add(queries, std::memory_order_relaxed);
    std::atomic<size_t> from_tree{0}, from_grid{0};
    parallel_for(scans.size(), 1, threads, [&](size_t b, size_t e, int) {
        std::vector<uint32_t> hidx(k), rest;
        std::vector<double> hd2(k);
        KnnHeap heap{k, 0, hd2.data(), hidx.data()};
        for (size_t s = b; s < e; ++s) {
            const std::vector<uint32_t> &ids = scans[s];
            CellMap map;
            if (!map.build(points, cell, ids)) {
                scan_tree_rows(points, ids, nullptr, k, out);
                from_tree.fetch_add(ids.size(), std::memory_order_relaxed);
                if (progress) progress->advance(ids.size());
                continue;
            }
            // the points in grid order (each row is independent of the order)
            rest.clear();
            for (size_t p = 0; p < ids.size(); ++p) {
                uint32_t i = ids[p];
                if (cell[2 * size_t(i)] < 0 || cell[2 * size_t(i) + 1] < 0)
                    rest.push_back(uint32_t(p));
            }
            for (size_t o = 0; o < map.at.size(); ++o) {
                uint32_t i = map.at[o];
                if (i == kNoIndex) continue;
                if (!grid_search(map, o, heap)) {
                    // ids is in index order
                    rest.push_back(uint32_t(std::lower_bound(ids.begin(), ids.end(), i) -
                                            ids.begin()));
                    continue;
                }
                std::copy(hidx.begin(), hidx.end(), out.index.begin() + size_t(i) * k);
            }
            if (!rest.empty()) scan_tree_rows(points, ids, &rest, k, out);
            from_tree.fetch_add(rest.size(), std::memory_order_relaxed);
            from_grid.fetch_add(ids.size() - rest.size(), std::memory_order_relaxed);
            if (progress) progress->advance(ids.size());
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    if (stats) {
        stats->from_tree = from_tree.load();
        stats->from_grid = from_grid.load();
    }
    return out;
}

}  // namespace pointviz
