// pointviz — neighbours within each scan (see scan_neighbours.h).
#include "pointviz/scan_neighbours.h"

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
    std::vector<double> sub;
    for (const auto &[g, ids] : members) {
        (void)g;
        if (ids.size() <= k) {  // too few in the scan: neighbours among all points
            std::vector<double> d2(k);
            for (uint32_t i : ids) {
                uint32_t *dst = out.index.data() + size_t(i) * k;
                all.query(points + 3 * size_t(i), k, i, dst, d2.data());
            }
            continue;
        }
        sub.resize(3 * ids.size());
        for (size_t r = 0; r < ids.size(); ++r)
            for (int a = 0; a < 3; ++a) sub[3 * r + a] = points[3 * size_t(ids[r]) + a];
        KnnTree tree(sub.data(), ids.size(), threads, progress);
        NeighbourTable t = knn_all(tree, sub.data(), k, threads, progress);
        for (size_t r = 0; r < ids.size(); ++r) {
            uint32_t *dst = out.index.data() + size_t(ids[r]) * k;
            const uint32_t *src = t.row(r);
            for (uint32_t m = 0; m < k; ++m) dst[m] = ids[src[m]];
        }
    }
    return out;
}

}  // namespace pointviz
