// pointviz — KD-tree k-nearest-neighbour queries (see knn.h).
#include "pointviz/knn.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <stdexcept>
#include <thread>

#include "pointviz/knn_kernels.h"
#include "pointviz/parallel.h"

namespace pointviz {

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
/// Points per chunk of the copies in and out of the build.
constexpr size_t kCopyGrain = size_t(1) << 15;

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
    // the copies in and out on the workers (one thread would leave the other cores idle)
    UnfilledVector<KnnRecord> rec(n);
    parallel_for(n, kCopyGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i)
            rec[i] = {{points[3 * i], points[3 * i + 1], points[3 * i + 2]}, uint32_t(i)};
    });
    int spawn = 0;
    for (int t = resolve_threads(threads); t > 1; t /= 2) ++spawn;
    if (n) build(rec.data(), 0, 0, uint32_t(n), 0, spawn);
    check_cancel(progress);
    pts_.resize(3 * n);
    ids_.resize(n);
    parallel_for(n, kCopyGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t r = b; r < e; ++r) {
            for (int a = 0; a < 3; ++a) pts_[3 * r + a] = rec[r].p[a];
            ids_[r] = rec[r].id;
        }
    });
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

std::vector<uint32_t> KnnTree::leaf_ranges() const {
    std::vector<uint32_t> first{0, uint32_t(ids_.size())}, next;
    for (uint32_t depth = 0; depth < depth_; ++depth) {
        next.assign(1, 0);
        for (size_t l = 0; l + 1 < first.size(); ++l) {
            next.push_back(first[l] + (first[l + 1] - first[l]) / 2);
            next.push_back(first[l + 1]);
        }
        first.swap(next);
    }
    return first;
}

void KnnTree::gather_leaves(uint32_t node, uint32_t depth, const double *b, double r2,
                            std::vector<uint32_t> &leaves) const {
    const double *c = &box_[6 * size_t(node)];
    double d = 0;
    for (int a = 0; a < 3; ++a) {
        double e = std::max({c[a] - b[3 + a], b[a] - c[3 + a], 0.0});
        d += e * e;
    }
    if (d > r2) return;
    if (depth == depth_) {
        leaves.push_back(node - ((1u << depth_) - 1));
        return;
    }
    gather_leaves(2 * node + 1, depth + 1, b, r2, leaves);
    gather_leaves(2 * node + 2, depth + 1, b, r2, leaves);
}

namespace {

/// A candidate neighbour as one integer ordered as the tables are, by (squared distance,
/// index): the bits of a non-negative double order as the double does.
using Candidate = unsigned __int128;
inline Candidate candidate(double d2, uint32_t id) {
    uint64_t bits;
    std::memcpy(&bits, &d2, sizeof bits);
    return (Candidate(bits) << 32) | id;
}
inline uint32_t candidate_id(Candidate c) { return uint32_t(c); }
inline double candidate_d2(Candidate c) {
    uint64_t bits = uint64_t(c >> 32);
    double d;
    std::memcpy(&d, &bits, sizeof d);
    return d;
}

/// Candidates up to which the kernels' quadratic count (KnnKernels::rank) beats a comparison
/// sort.
constexpr size_t kRankedMax = 64;

}  // namespace

NeighbourTable knn_all(const KnnTree &tree, const double *points, uint32_t k, int threads,
                       Progress *progress, Isa isa) {
    NeighbourTable t;
    t.n = tree.size();
    t.k = t.n == 0 ? 0 : uint32_t(std::min<size_t>(k, t.n - 1));
    t.index.resize(t.n * t.k);  // unfilled: each row is written once, by the worker searching it
    knn_each(tree, points, t.k, true, threads, progress, [&t](uint32_t i, const uint32_t *row) {
        std::copy(row, row + t.k, t.index.data() + size_t(i) * t.k);
    }, isa);
    return t;
}

void knn_each(const KnnTree &tree, const double *points, uint32_t k_wanted, bool sorted,
              int threads, Progress *progress,
              const std::function<void(uint32_t, const uint32_t *)> &visit, Isa isa) {
    const size_t n = tree.size();
    const uint32_t k = n == 0 ? 0 : uint32_t(std::min<size_t>(k_wanted, n - 1));
    if (k == 0) return;
    if (progress) progress->total.fetch_add(n, std::memory_order_relaxed);
    const UnfilledVector<uint32_t> &ids = tree.ids_;
    const UnfilledVector<double> &pts = tree.pts_;
    const std::vector<double> &box = tree.box_;
    const std::vector<uint32_t> first = tree.leaf_ranges();
    const KnnKernels &kernels = knn_kernels(isa);
    // the points' coordinates one axis at a time (in tree order), for the kernels' vector loads
    UnfilledVector<double> xyz(3 * n);
    double *xs = xyz.data(), *ys = xs + n, *zs = ys + n;
    parallel_for(n, kCopyGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t r = b; r < e; ++r)
            xs[r] = pts[3 * r], ys[r] = pts[3 * r + 1], zs[r] = pts[3 * r + 2];
    });
    const size_t leaves = first.size() - 1;
    const uint32_t leaf0 = (1u << tree.depth_) - 1;
    // The points of one leaf share their search: the leaves within a radius of the leaf's box
    // are gathered once, and each point takes its k nearest among their points within that
    // radius (or less). When at least k are that close, no point farther away can be among
    // the k nearest (a point within the radius of q lies in a leaf whose box is within it of
    // the leaf's box), so the row is exact; otherwise the point falls back to the tree's query.
    // The leaf's radius is the largest k-th distance of the previous leaf, which lies next to
    // it, with a margin; a point's own radius is at most the previous point's k-th distance
    // plus their distance (the previous point and its neighbours are k + 1 points that close).
    // The distances are computed branch-free and the few within the radius selected at the
    // end: the per-candidate branches and insertions were most of the query's time.
    // Squared margin on the previous leaf's radius (less falls back more often): CPU seconds
    // of 31 neighbours of the dragon's 469k points / of a 500k-point sphere at 1.15 / 1.3 /
    // 1.6: 0.76 / 0.79 / 0.84 and 0.78 / 0.82 / 0.87.
    constexpr double kRadiusMargin = 1.15;
    // ~2 ms of queries per chunk at k = 32: the cancel flag is seen promptly
    constexpr size_t kGrainLeaves = 2048 / KnnTree::kLeafSize;
    parallel_for(leaves, kGrainLeaves, threads, [&](size_t lb, size_t le, int) {
        std::vector<double> d2(k);
        std::vector<uint32_t> row(k), cand, pass;
        std::vector<double> cand_box;  // the candidate leaves' boxes, one coordinate at a time
        std::vector<Candidate> near;
        std::vector<double> near_d2;
        std::vector<uint32_t> near_id;
        double r2 = -1;  // no radius yet
        const double *prev = nullptr;
        double prev_kth = 0;
        for (size_t l = lb; l < le; ++l) {
            double kth = 0;
            if (r2 >= 0) {
                cand.clear();
                tree.gather_leaves(0, 0, &box[6 * (leaf0 + l)], r2, cand);
                size_t total = 0;
                for (uint32_t c : cand) total += first[c + 1] - first[c];
                const size_t m = cand.size();
                cand_box.resize(6 * m);
                for (size_t a = 0; a < m; ++a)
                    for (int j = 0; j < 6; ++j)
                        cand_box[j * m + a] = box[6 * (leaf0 + cand[a]) + j];
                pass.resize(m + 8);
                if (near.size() < total) {
                    near.resize(total);
                    near_d2.resize(total + 8);  // + the kernels' slots past the count
                    near_id.resize(total + 8);
                }
            }
            for (uint32_t r = first[l]; r < first[l + 1]; ++r) {
                const double *q = &pts[3 * size_t(r)];
                uint32_t self = ids[r];
                size_t cnt = 0;
                double rq = r2;
                if (prev) {
                    double dx = prev[0] - q[0], dy = prev[1] - q[1], dz = prev[2] - q[2];
                    double e = std::sqrt(prev_kth) + std::sqrt(dx * dx + dy * dy + dz * dz);
                    rq = std::min(rq, e * e * (1 + 1e-9));
                }
                if (r2 >= 0) {
                    const size_t near_leaves =
                        kernels.boxes(cand_box.data(), cand.size(), q, rq, pass.data());
                    for (size_t a = 0; a < near_leaves; ++a) {
                        const uint32_t c = cand[pass[a]];
                        cnt = kernels.near(xs, ys, zs, ids.data(), first[c], first[c + 1], q, rq,
                                           self, near_d2.data(), near_id.data(), cnt);
                    }
                }
                if (r2 >= 0 && cnt >= k && sorted && cnt <= kRankedMax) {
                    prev_kth = kernels.rank(near_d2.data(), near_id.data(), cnt, k, row.data());
                } else if (r2 >= 0 && cnt >= k) {
                    for (size_t a = 0; a < cnt; ++a) near[a] = candidate(near_d2[a], near_id[a]);
                    std::nth_element(near.begin(), near.begin() + (k - 1), near.begin() + cnt);
                    if (sorted) std::sort(near.begin(), near.begin() + (k - 1));
                    for (uint32_t m = 0; m < k; ++m) row[m] = candidate_id(near[m]);
                    prev_kth = candidate_d2(near[k - 1]);
                } else {
                    tree.query_near(points + 3 * size_t(self), r, k, self, row.data(),
                                    d2.data());
                    prev_kth = d2[k - 1];
                }
                visit(self, row.data());
                kth = std::max(kth, prev_kth);
                prev = q;
            }
            r2 = kth * kRadiusMargin;
        }
        if (progress) progress->advance(first[le] - first[lb]);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
}

}  // namespace pointviz
