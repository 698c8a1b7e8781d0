// pointviz — KD-tree k-nearest-neighbour queries (see knn.h).
#include "pointviz/knn.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <thread>

#include "pointviz/parallel.h"

namespace pointviz {

/// The k best (squared distance, index) pairs seen so far, kept sorted: k is small (<= 64), so
/// insertion into a sorted array beats a binary heap.
struct KnnHeap {
    uint32_t k = 0, size = 0;
    double *d2;
    uint32_t *idx;
    /// The squared distance a candidate must not exceed to matter.
    double bound() const {
        return size < k ? std::numeric_limits<double>::infinity() : d2[k - 1];
    }
    void push(double d, uint32_t i) {
        if (size == k) {
            if (d > d2[k - 1] || (d == d2[k - 1] && i > idx[k - 1])) return;
        } else {
            ++size;
        }
        uint32_t j = size - 1;
        while (j > 0 && (d < d2[j - 1] || (d == d2[j - 1] && i < idx[j - 1]))) {
            d2[j] = d2[j - 1];
            idx[j] = idx[j - 1];
            --j;
        }
        d2[j] = d;
        idx[j] = i;
    }
};

namespace {

/// Nodes at depth `depth_` are leaves: the fewest levels that bring every leaf to kLeafSize.
uint32_t tree_depth(size_t n) {
    uint32_t d = 0;
    size_t largest = n;
    while (largest > KnnTree::kLeafSize) {
        largest = (largest + 1) / 2;
        ++d;
    }
    return d;
}

/// Subtrees below this many points are built on the calling thread.
constexpr uint32_t kSpawnMinPoints = 1u << 15;

}  // namespace

/// A point and its input index, moved as one record while the tree is built.
struct KnnRecord {
    double p[3];
    uint32_t id;
};

KnnTree::KnnTree(const double *points, size_t n, int threads, Progress *progress) {
    if (n >= size_t(kNoIndex)) throw std::invalid_argument("points: too many for the KD-tree");
    depth_ = tree_depth(n);
    size_t inner = (size_t(1) << depth_) - 1;
    split_.assign(inner, 0.0);
    dim_.assign(inner, 0);
    box_.assign(6 * (2 * inner + 1), 0.0);
    check_cancel(progress);
    std::vector<KnnRecord> rec(n);
    for (size_t i = 0; i < n; ++i) rec[i] = {{points[3 * i], points[3 * i + 1], points[3 * i + 2]}, uint32_t(i)};
    int spawn = 0;
    for (int t = resolve_threads(threads); t > 1; t /= 2) ++spawn;
    if (n) build(rec.data(), 0, 0, uint32_t(n), 0, spawn);
    check_cancel(progress);
    pts_.resize(3 * n);
    ids_.resize(n);
    for (size_t r = 0; r < n; ++r) {
        for (int a = 0; a < 3; ++a) pts_[3 * r + a] = rec[r].p[a];
        ids_[r] = rec[r].id;
    }
}

void KnnTree::build(KnnRecord *rec, uint32_t node, uint32_t begin, uint32_t end, uint32_t depth,
                   int spawn) {
    double *lo = &box_[6 * size_t(node)], *hi = lo + 3;
    if (depth == depth_) {
        for (int a = 0; a < 3; ++a) lo[a] = hi[a] = begin < end ? rec[begin].p[a] : 0.0;
        for (uint32_t r = begin + 1; r < end; ++r)
            for (int a = 0; a < 3; ++a) {
                lo[a] = std::min(lo[a], rec[r].p[a]);
                hi[a] = std::max(hi[a], rec[r].p[a]);
            }
        return;
    }
    // the widest axis of the points' extent, sampled (every 64th point) above 4096 points
    uint32_t step = end - begin > 4096 ? 64 : 1;
    double slo[3], shi[3];
    for (int a = 0; a < 3; ++a) slo[a] = shi[a] = rec[begin].p[a];
    for (uint32_t r = begin + step; r < end; r += step)
        for (int a = 0; a < 3; ++a) {
            slo[a] = std::min(slo[a], rec[r].p[a]);
            shi[a] = std::max(shi[a], rec[r].p[a]);
        }
    int axis = 0;
    for (int a = 1; a < 3; ++a)
        if (shi[a] - slo[a] > shi[axis] - slo[axis]) axis = a;
    uint32_t mid = begin + (end - begin) / 2;
    std::nth_element(rec + begin, rec + mid, rec + end,
                     [axis](const KnnRecord &a, const KnnRecord &b) { return a.p[axis] < b.p[axis]; });
    dim_[node] = uint8_t(axis);
    split_[node] = rec[mid].p[axis];
    if (spawn > 0 && end - begin >= kSpawnMinPoints) {
        std::thread left([&] { build(rec, 2 * node + 1, begin, mid, depth + 1, spawn - 1); });
        build(rec, 2 * node + 2, mid, end, depth + 1, spawn - 1);
        left.join();
    } else {
        build(rec, 2 * node + 1, begin, mid, depth + 1, 0);
        build(rec, 2 * node + 2, mid, end, depth + 1, 0);
    }
    const double *l = &box_[6 * size_t(2 * node + 1)], *r = &box_[6 * size_t(2 * node + 2)];
    for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(l[a], r[a]);
        hi[a] = std::max(l[3 + a], r[3 + a]);
    }
}

/// Whether the ball around q of squared radius r2 lies strictly inside the box (lo, hi).
static inline bool ball_inside(const double *q, double r2, const double *b) {
    if (!(r2 < std::numeric_limits<double>::infinity())) return false;
    double r = std::sqrt(r2);
    for (int a = 0; a < 3; ++a)
        if (!(q[a] - r > b[a] && q[a] + r < b[3 + a])) return false;
    return true;
}

/// Squared distance from q to the box (lo, hi).
static inline double box_dist2(const double *q, const double *b) {
    double d = 0;
    for (int a = 0; a < 3; ++a) {
        double e = std::max({b[a] - q[a], q[a] - b[3 + a], 0.0});
        d += e * e;
    }
    return d;
}

void KnnTree::search(uint32_t node, uint32_t begin, uint32_t end, uint32_t depth, const double *q,
                    KnnHeap &heap, uint32_t done_leaf) const {
    if (depth == depth_) {
        if (node == done_leaf) return;
        for (uint32_t r = begin; r < end; ++r) {
            const double *p = &pts_[3 * size_t(r)];
            double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
            double d = dx * dx + dy * dy + dz * dz;
            if (d <= heap.bound()) heap.push(d, ids_[r]);
        }
        return;
    }
    uint32_t mid = begin + (end - begin) / 2;
    uint32_t a = 2 * node + 1, b = 2 * node + 2;
    double da = box_dist2(q, &box_[6 * size_t(a)]), db = box_dist2(q, &box_[6 * size_t(b)]);
    if (da <= db) {
        if (da <= heap.bound()) search(a, begin, mid, depth + 1, q, heap, done_leaf);
        if (db <= heap.bound()) search(b, mid, end, depth + 1, q, heap, done_leaf);
    } else {
        if (db <= heap.bound()) search(b, mid, end, depth + 1, q, heap, done_leaf);
        if (da <= heap.bound()) search(a, begin, mid, depth + 1, q, heap, done_leaf);
    }
}

uint32_t KnnTree::query(const double q[3], uint32_t k, uint32_t skip, uint32_t *idx,
                       double *d2) const {
    return query_near(q, kNoIndex, k, skip, idx, d2);
}

uint32_t KnnTree::query_near(const double q[3], uint32_t start, uint32_t k, uint32_t skip,
                            uint32_t *idx, double *d2) const {
    if (k == 0 || ids_.empty()) return 0;
    // room for one more, so that `skip` can be dropped afterwards
    uint32_t want = skip == kNoIndex ? k : k + 1;
    std::vector<double> dbuf;
    std::vector<uint32_t> ibuf;
    constexpr uint32_t kStack = 65;
    double dsmall[kStack];
    uint32_t ismall[kStack];
    double *dd = dsmall;
    uint32_t *ii = ismall;
    if (want > kStack) {
        dbuf.resize(want);
        ibuf.resize(want);
        dd = dbuf.data();
        ii = ibuf.data();
    }
    KnnHeap heap{want, 0, dd, ii};
    if (start == kNoIndex) {
        search(0, 0, uint32_t(ids_.size()), 0, q, heap, kNoIndex);
    } else {
        // bottom-up: the leaf holding stored position `start` first (its points bound the
        // search at once), then the sibling of each node on the way up, until the ball of the
        // current k-th distance lies inside a node's box: the cells of a KD-tree partition
        // space, so nothing outside that node can be closer
        uint32_t path[64], pb[64], pe[64];
        uint32_t node = 0, b = 0, e = uint32_t(ids_.size());
        for (uint32_t depth = 0; depth < depth_; ++depth) {
            path[depth] = node, pb[depth] = b, pe[depth] = e;
            uint32_t mid = b + (e - b) / 2;
            if (start < mid) node = 2 * node + 1, e = mid;
            else node = 2 * node + 2, b = mid;
        }
        for (uint32_t r = b; r < e; ++r) {
            const double *p = &pts_[3 * size_t(r)];
            double dx = p[0] - q[0], dy = p[1] - q[1], dz = p[2] - q[2];
            heap.push(dx * dx + dy * dy + dz * dz, ids_[r]);
        }
        for (uint32_t depth = depth_; depth-- > 0;) {
            if (ball_inside(q, heap.bound(), &box_[6 * size_t(node)])) break;
            uint32_t parent = path[depth], pbeg = pb[depth], pend = pe[depth];
            uint32_t mid = pbeg + (pend - pbeg) / 2;
            bool was_left = node == 2 * parent + 1;
            uint32_t sib = was_left ? node + 1 : node - 1;
            uint32_t sb = was_left ? mid : pbeg, se = was_left ? pend : mid;
            if (box_dist2(q, &box_[6 * size_t(sib)]) <= heap.bound())
                search(sib, sb, se, depth + 1, q, heap, kNoIndex);
            node = parent;
        }
    }
    uint32_t out = 0;
    for (uint32_t j = 0; j < heap.size && out < k; ++j) {
        if (ii[j] == skip) continue;
        idx[out] = ii[j];
        if (d2) d2[out] = dd[j];
        ++out;
    }
    return out;
}

void KnnTree::renumber_in_tree_order() { std::iota(ids_.begin(), ids_.end(), 0u); }

NeighbourTable knn_all(const KnnTree &tree, const double *points, uint32_t k, int threads,
                       Progress *progress) {
    NeighbourTable t;
    t.n = tree.size();
    t.k = t.n == 0 ? 0 : uint32_t(std::min<size_t>(k, t.n - 1));
    t.index.assign(t.n * t.k, 0);
    if (t.k == 0) return t;
    if (progress) progress->total.fetch_add(t.n, std::memory_order_relaxed);
    const std::vector<uint32_t> &order = tree.order();
    // ~2 ms of queries per chunk at k = 32: the cancel flag is seen promptly
    constexpr size_t kGrain = 2048;
    parallel_for(t.n, kGrain, threads, [&](size_t b, size_t e, int) {
        std::vector<double> d2(t.k);
        for (size_t r = b; r < e; ++r) {
            uint32_t i = order[r];
            tree.query_near(points + 3 * size_t(i), uint32_t(r), t.k, i,
                             t.index.data() + size_t(i) * t.k, d2.data());
        }
        if (progress) progress->advance(e - b);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    return t;
}

}  // namespace pointviz
