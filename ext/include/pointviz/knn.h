// pointviz — k nearest neighbours of points in double precision: a balanced KD-tree (median
// splits on the widest axis, implicit heap layout, a tight box per node: on a sampled surface
// most of a cell is empty, so boxes prune far more than split planes) and the all-points query that preprocessing
// (normals, orientation, radii, surface fit) is built on.
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <vector>

#include "pointviz/default_init.h"
#include "pointviz/isa.h"
#include "pointviz/progress.h"

namespace pointviz {

/// Marks "no index" (e.g. no point to leave out of a query).
constexpr uint32_t kNoIndex = 0xffffffffu;

struct NeighbourTable;

/// The k best (squared distance, index) pairs seen so far, kept sorted: k is small (<= 64), so
/// insertion into a sorted array beats a binary heap. Distances are squared (never negative).
struct KnnHeap {
    uint32_t k = 0, size = 0;
    double *d2;
    uint32_t *idx;
    /// The squared distance a candidate must not exceed to matter.
    double bound() const {
        return size < k ? std::numeric_limits<double>::infinity() : d2[k - 1];
    }
    /// Inserts (d, i) if it is among the k best; whether it was. The distances are compared as
    /// their bits (non-negative doubles order as their bits do): integer compares, with no
    /// unordered case to branch on.
    bool push(double d, uint32_t i) {
        const uint64_t b = bits(d);
        if (size == k) {
            uint64_t e = bits(d2[k - 1]);
            if (b > e || (b == e && i > idx[k - 1])) return false;
        } else {
            ++size;
        }
        uint32_t j = size - 1;
        while (j > 0) {
            uint64_t e = bits(d2[j - 1]);
            if (!(b < e || (b == e && i < idx[j - 1]))) break;
            d2[j] = d2[j - 1];
            idx[j] = idx[j - 1];
            --j;
        }
        d2[j] = d;
        idx[j] = i;
        return true;
    }
    static uint64_t bits(double d) {
        uint64_t u;
        std::memcpy(&u, &d, sizeof u);
        return u;
    }
};

/// Static KD-tree over n points. Neighbours are ordered by (squared distance, index), so results
/// do not depend on the tree's shape, the thread count or the order of the queries.
class KnnTree {
public:
    /// Points per leaf: a leaf's distances are one short loop over contiguous memory; smaller
    /// leaves mean deeper trees and more box tests per query. CPU seconds of the 10 nearest
    /// neighbours of 1M points on a sphere at 6 / 8 / 12 / 16 / 24 / 32 points per leaf:
    /// 1.58 / 1.57 / 1.51 / 1.23 / 1.45 / 1.45.
    static constexpr uint32_t kLeafSize = 16;

    /// `points`: (n, 3) row-major, finite. Copied (reordered) into the tree; n < 2^32 - 1.
    KnnTree(const double *points, size_t n, int threads = 0, Progress *progress = nullptr);

    size_t size() const { return ids_.size(); }
    /// Up to k nearest points of `q`, leaving out point `skip` (kNoIndex: none). Writes their
    /// indices and squared distances in ascending order; returns how many were found.
    uint32_t query(const double q[3], uint32_t k, uint32_t skip, uint32_t *idx, double *d2) const;
    /// The same, starting from the leaf that holds stored position `start` (order()[start] is a
    /// point near q): the search is bounded from its first step.
    uint32_t query_near(const double q[3], uint32_t start, uint32_t k, uint32_t skip,
                        uint32_t *idx, double *d2) const;
    /// Input index of the point stored at position r: visiting points in this order keeps
    /// neighbouring queries close in memory.
    const UnfilledVector<uint32_t> &order() const { return ids_; }
    /// The points in tree order ((n, 3)).
    const UnfilledVector<double> &stored_points() const { return pts_; }
    /// Makes every query answer with stored positions instead of input indices: the tree then
    /// indexes stored_points(), which keeps a point's neighbours close to it in memory.
    void renumber_in_tree_order();

private:
    friend void knn_each(const KnnTree &, const double *, uint32_t, bool, int, Progress *,
                         const std::function<void(uint32_t, const uint32_t *)> &, Isa);
    /// first[l], first[l + 1]: the stored positions of leaf l (leaves numbered left to right).
    std::vector<uint32_t> leaf_ranges() const;
    /// Appends the leaves whose box lies within squared distance r2 of the box `b` (lo, hi).
    void gather_leaves(uint32_t node, uint32_t depth, const double *b, double r2,
                       std::vector<uint32_t> &leaves) const;
    void build(struct KnnRecord *rec, uint32_t node, uint32_t begin, uint32_t end, uint32_t depth,
               int spawn);
    void search(uint32_t node, uint32_t begin, uint32_t end, uint32_t depth, const double *q,
                KnnHeap &heap, uint32_t done_leaf) const;
    UnfilledVector<double> pts_;    ///< (n, 3) points in tree order
    UnfilledVector<uint32_t> ids_;  ///< input index of each stored point
    std::vector<double> split_;   ///< split coordinate per inner node (heap layout)
    std::vector<uint8_t> dim_;    ///< split axis per inner node
    std::vector<double> box_;     ///< (lo, hi) bounding box of every node's points (heap layout)
    uint32_t depth_ = 0;          ///< levels of inner nodes; nodes at this depth are leaves
};

/// The k nearest neighbours of every point of a cloud, the point itself excluded (exact
/// duplicates of it are neighbours at distance 0). Row i lists `k` indices (ascending distance)
/// when the cloud has more than k points, else n - 1 (then `k` is n - 1).
struct NeighbourTable {
    size_t n = 0;
    uint32_t k = 0;
    /// (n, k); `resize` leaves the rows unwritten for the search's workers to fill
    UnfilledVector<uint32_t> index;
    const uint32_t *row(size_t i) const { return index.data() + i * k; }
};

/// Fills a NeighbourTable for `points` (the same array the tree was built from), on `threads`
/// workers. Polls `progress` (advancing it by the points done); throws Cancelled. `isa`: the
/// instruction set of the search's inner loops (knn_kernels.h; Auto: the best available); the
/// table is the same for every one.
NeighbourTable knn_all(const KnnTree &tree, const double *points, uint32_t k, int threads,
                       Progress *progress = nullptr, Isa isa = Isa::Auto);

/// The rows of knn_all (k is min(k, n - 1) as there) handed to `visit(i, row)` one point at a
/// time instead of stored: a step that needs each point's neighbours once never holds the
/// (n, k) table. `sorted` false: each row holds the same neighbours in no particular order
/// (the selection skips its final sort). Calls come from `threads` workers at once, each point
/// once; `row` is valid during the call only. Polls `progress`; throws Cancelled. `isa` as for
/// knn_all.
void knn_each(const KnnTree &tree, const double *points, uint32_t k, bool sorted, int threads,
              Progress *progress, const std::function<void(uint32_t, const uint32_t *)> &visit,
              Isa isa = Isa::Auto);

}  // namespace pointviz
