// pointviz — neighbours within each scan (see scan_neighbours.h).
#include "pointviz/scan_neighbours.h"

#include "pointviz/parallel.h"

#include <algorithm>
#include <map>
#include <stdexcept>
#include <vector>

namespace pointviz {

NeighbourTable knn_within_groups(const double *points, size_t n, const int32_t *group,
                                 uint32_t k, const KnnTree &all, int threads,
                                 Progress *progress) {
    if (all.size() != n || n <= k)
        throw std::invalid_argument("knn_within_groups: need a tree over more than k points");
    NeighbourTable out;
    out.n = n;
    out.k = k;
    out.index.resize(n * size_t(k));
    // members of each group in index order (the caller's order keeps them spatially coherent)
    std::map<int32_t, std::vector<uint32_t>> members;
    for (size_t i = 0; i < n; ++i) members[group[i]].push_back(uint32_t(i));
    std::vector<const std::vector<uint32_t> *> scans;
    for (const auto &[g, ids] : members) {
        (void)g;
        if (ids.size() > k) {
            scans.push_back(&ids);
            continue;
        }
        std::vector<double> d2(k);  // too few in the scan: neighbours among all points
        for (uint32_t i : ids) {
            uint32_t *dst = out.index.data() + size_t(i) * k;
            all.query(points + 3 * size_t(i), k, i, dst, d2.data());
        }
    }
    // one scan per worker at a time: a scan's tree and queries on one thread, the scans side by
    // side (a scan of a few ten thousand points is too small to split its tree build)
    size_t queries = 0;
    for (const std::vector<uint32_t> *ids : scans) queries += ids->size();
    if (progress) progress->total.fetch_add(queries, std::memory_order_relaxed);
    parallel_for(scans.size(), 1, threads, [&](size_t b, size_t e, int) {
        std::vector<double> sub;
        for (size_t s = b; s < e; ++s) {
            const std::vector<uint32_t> &ids = *scans[s];
            sub.resize(3 * ids.size());
            for (size_t r = 0; r < ids.size(); ++r)
                for (int a = 0; a < 3; ++a) sub[3 * r + a] = points[3 * size_t(ids[r]) + a];
            KnnTree tree(sub.data(), ids.size(), 1);
            NeighbourTable t = knn_all(tree, sub.data(), k, 1);
            for (size_t r = 0; r < ids.size(); ++r) {
                uint32_t *dst = out.index.data() + size_t(ids[r]) * k;
                const uint32_t *src = t.row(r);
                for (uint32_t m = 0; m < k; ++m) dst[m] = ids[src[m]];
            }
            if (progress) progress->advance(ids.size());
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    return out;
}

}  // namespace pointviz
