// pointviz — normal orientation (see orient.h).
#include "pointviz/orient.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <numeric>
#include <vector>

#include "pointviz/parallel.h"

namespace pointviz {

size_t orient_toward(const double *points, float *normals, size_t n, const double *viewpoints,
                     size_t n_viewpoints, int threads) {
    std::atomic<size_t> flipped{0};
    parallel_for(n, size_t(1) << 15, threads, [&](size_t b, size_t e, int) {
        size_t c = 0;
        for (size_t i = b; i < e; ++i) {
            const double *v = viewpoints + (n_viewpoints == 1 ? 0 : 3 * i);
            const double *p = points + 3 * i;
            float *nn = normals + 3 * i;
            double d = nn[0] * (v[0] - p[0]) + nn[1] * (v[1] - p[1]) + nn[2] * (v[2] - p[2]);
            if (d < 0) {
                nn[0] = -nn[0], nn[1] = -nn[1], nn[2] = -nn[2];
                ++c;
            }
        }
        flipped.fetch_add(c, std::memory_order_relaxed);
    });
    return flipped.load();
}

namespace {

struct Edge {
    float cost;
    uint32_t a, b;   // a < b
    bool operator<(const Edge &o) const {
        if (cost != o.cost) return cost < o.cost;
        if (a != o.a) return a < o.a;
        return b < o.b;
    }
};

uint32_t find(std::vector<uint32_t> &parent, uint32_t x) {
    while (parent[x] != x) {
        parent[x] = parent[parent[x]];  // path halving
        x = parent[x];
    }
    return x;
}

double dot3(const float *a, const float *b) {
    return double(a[0]) * b[0] + double(a[1]) * b[1] + double(a[2]) * b[2];
}

}  // namespace

OrientResult orient_above(const double *points, float *normals, const NeighbourTable &nb,
                          const OrientOptions &opt, int threads, Progress *progress) {
    (void)points;
    OrientResult res;
    const size_t n = nb.n;
    if (n == 0) return res;
    const uint32_t k = std::min(opt.k, nb.k);
    const float up[3] = {float(opt.up[0]), float(opt.up[1]), float(opt.up[2])};
    auto up_dot = [&](size_t i) {
        const float *v = normals + 3 * i;
        return v[0] * up[0] + v[1] * up[1] + v[2] * up[2];
    };
    // state: 1 oriented, 0 not yet; the steep ones are listed (in index order)
    std::vector<uint8_t> done(n, 0);
    std::vector<uint8_t> flip(n, 0);
    constexpr size_t kGrain = size_t(1) << 14;
    // gathered per chunk of kGrain points, so that the list comes out in index order
    const size_t chunks = (n + kGrain - 1) / kGrain;
    std::vector<std::vector<uint32_t>> steep_chunk(chunks);
    std::vector<size_t> flips_chunk(chunks, 0);
    parallel_for(n, kGrain, threads, [&](size_t b, size_t e, int) {
        std::vector<uint32_t> &st = steep_chunk[b / kGrain];
        size_t c = 0;
        for (size_t i = b; i < e; ++i) {
            const float d = up_dot(i);
            // the up decides a normal near vertical, or one tilted further that lies in its
            // neighbours' plane: one that does not (a corner's, tilted up between two walls)
            // waits for their votes instead
            bool decided = std::fabs(d) >= opt.flat;
            if (!decided && std::fabs(d) >= opt.steep) {
                uint32_t agree = 0;
                const uint32_t *row = nb.row(i);
                for (uint32_t m = 0; m < k; ++m)
                    agree += std::fabs(dot3(normals + 3 * i, normals + 3 * size_t(row[m]))) >=
                             opt.agree;
                decided = 2 * agree >= k;
            }
            if (decided) {
                done[i] = 1;
                if (d < 0) flip[i] = 1, ++c;
            } else {
                st.push_back(uint32_t(i));
            }
        }
        flips_chunk[b / kGrain] = c;
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    std::vector<uint32_t> steep;
    for (auto &v : steep_chunk) steep.insert(steep.end(), v.begin(), v.end());
    for (size_t c : flips_chunk) res.flipped += c;
    res.steep = steep.size();
    // the sign of a normal as oriented so far
    auto oriented = [&](size_t i, int a) {
        return flip[i] ? -normals[3 * i + a] : normals[3 * i + a];
    };
    std::vector<int8_t> vote(steep.size(), 0);
    for (uint32_t round = 0; round < opt.rounds && !steep.empty(); ++round) {
        // every steep point votes with the state of the round before
        parallel_for(steep.size(), 1024, threads, [&](size_t b, size_t e, int) {
            for (size_t s = b; s < e; ++s) {
                const uint32_t i = steep[s];
                const uint32_t *row = nb.row(i);
                double sum = 0;
                for (uint32_t m = 0; m < k; ++m) {
                    const uint32_t j = row[m];
                    if (j == i || !done[j]) continue;
                    // weighted by the agreement itself: a neighbour at right angles (the
                    // roof or ground beside a wall) says nothing about the wall's sign
                    const double c = normals[3 * size_t(i)] * oriented(j, 0) +
                                     normals[3 * size_t(i) + 1] * oriented(j, 1) +
                                     normals[3 * size_t(i) + 2] * oriented(j, 2);
                    sum += c * std::fabs(c);
                }
                vote[s] = int8_t(sum > 0 ? 1 : sum < 0 ? -1 : 0);
            }
        }, progress ? &progress->cancel : nullptr);
        check_cancel(progress);
        size_t left = 0;
        for (size_t s = 0; s < steep.size(); ++s) {
            const uint32_t i = steep[s];
            if (vote[s]) {
                done[i] = 1;
                if (vote[s] < 0) flip[i] = 1, ++res.flipped;
            } else {
                steep[left] = i, vote[left] = 0, ++left;
            }
        }
        if (left == steep.size()) break;  // nothing reached: no later round would
        steep.resize(left);
    }
    // unreached: face up by their own sign (ties keep theirs)
    res.unreached = steep.size();
    for (uint32_t i : steep)
        if (up_dot(i) < 0) flip[i] = 1, ++res.flipped;
    parallel_for(n, kGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i)
            if (flip[i])
                for (int a = 0; a < 3; ++a) normals[3 * i + a] = -normals[3 * i + a];
    });
    return res;
}

OrientResult orient_mst(const double *points, float *normals, const NeighbourTable &nb,
                        const OrientOptions &opt, Progress *progress) {
    OrientResult res;
    size_t n = nb.n;
    if (n == 0) return res;
    uint32_t k = std::min(opt.k, nb.k);
    auto dist = [&](uint32_t i, uint32_t j) {
        const double *p = points + 3 * size_t(i), *q = points + 3 * size_t(j);
        return std::sqrt((p[0] - q[0]) * (p[0] - q[0]) + (p[1] - q[1]) * (p[1] - q[1]) +
                         (p[2] - q[2]) * (p[2] - q[2]));
    };
    // edges i -> row neighbour, each unordered pair once
    std::vector<Edge> edges;
    edges.reserve(n * k);
    std::vector<double> lengths;
    lengths.reserve(n * k);
    for (size_t i = 0; i < n; ++i) {
        const uint32_t *row = nb.row(i);
        for (uint32_t m = 0; m < k; ++m) {
            uint32_t j = row[m];
            if (j == i) continue;
            bool mutual_dup = false;
            if (j < i) {  // listed from j's side too? then keep only that copy
                const uint32_t *rj = nb.row(j);
                mutual_dup = std::find(rj, rj + k, uint32_t(i)) != rj + k;
            }
            if (mutual_dup) continue;
            edges.push_back({0.f, uint32_t(std::min<size_t>(i, j)), uint32_t(std::max<size_t>(i, j))});
            double d = dist(uint32_t(i), j);
            if (d > 0) lengths.push_back(d);
        }
        if ((i & 0xffff) == 0) check_cancel(progress);
    }
    double scale = 1.0;
    if (!lengths.empty()) {
        auto mid = lengths.begin() + lengths.size() / 2;
        std::nth_element(lengths.begin(), mid, lengths.end());
        scale = *mid;
    }
    for (Edge &e : edges) {
        double c = 1.0 - std::fabs(dot3(normals + 3 * size_t(e.a), normals + 3 * size_t(e.b)));
        e.cost = float(std::max(c, 0.0) + opt.distance_weight * dist(e.a, e.b) / scale);
    }
    check_cancel(progress);
    std::sort(edges.begin(), edges.end());
    check_cancel(progress);
    // Kruskal: the spanning forest as adjacency lists
    std::vector<uint32_t> parent(n);
    std::iota(parent.begin(), parent.end(), 0u);
    std::vector<uint32_t> deg(n + 1, 0), tree_a, tree_b;
    for (const Edge &e : edges) {
        uint32_t ra = find(parent, e.a), rb = find(parent, e.b);
        if (ra == rb) continue;
        parent[std::max(ra, rb)] = std::min(ra, rb);
        tree_a.push_back(e.a);
        tree_b.push_back(e.b);
        ++deg[e.a + 1];
        ++deg[e.b + 1];
    }
    std::partial_sum(deg.begin(), deg.end(), deg.begin());
    std::vector<uint32_t> adj(deg[n]), fill(deg.begin(), deg.end() - 1);
    for (size_t t = 0; t < tree_a.size(); ++t) {
        adj[fill[tree_a[t]]++] = tree_b[t];
        adj[fill[tree_b[t]]++] = tree_a[t];
    }
    check_cancel(progress);
    // breadth-first from the smallest index of each part: signs relative to the parent
    std::vector<int8_t> sign(n, 0);
    std::vector<uint32_t> label(n), queue;
    queue.reserve(n);
    uint32_t comp = 0;
    for (size_t s = 0; s < n; ++s) {
        if (sign[s]) continue;
        sign[s] = 1;
        label[s] = comp;
        queue.clear();
        queue.push_back(uint32_t(s));
        for (size_t h = 0; h < queue.size(); ++h) {
            uint32_t u = queue[h];
            for (uint32_t a = deg[u]; a < deg[u + 1]; ++a) {
                uint32_t v = adj[a];
                if (sign[v]) continue;
                bool same = dot3(normals + 3 * size_t(u), normals + 3 * size_t(v)) >= 0;
                sign[v] = int8_t(same ? sign[u] : -sign[u]);
                label[v] = comp;
                queue.push_back(v);
            }
        }
        ++comp;
    }
    for (size_t i = 0; i < n; ++i)
        if (sign[i] < 0)
            for (int a = 0; a < 3; ++a) normals[3 * i + a] = -normals[3 * i + a];
    res.components = comp;
    // one sign per part: most normals point away from the part's centroid
    std::vector<double> cen(3 * size_t(comp), 0.0), mean(3, 0.0);
    std::vector<size_t> count(comp, 0);
    for (size_t i = 0; i < n; ++i) {
        ++count[label[i]];
        for (int a = 0; a < 3; ++a) {
            cen[3 * size_t(label[i]) + a] += points[3 * i + a];
            mean[a] += points[3 * i + a];
        }
    }
    for (uint32_t c = 0; c < comp; ++c)
        for (int a = 0; a < 3; ++a)
            // a few stray points: their own centroid says nothing, use the whole cloud's
            cen[3 * size_t(c) + a] =
                count[c] < opt.k ? mean[a] / double(n) : cen[3 * size_t(c) + a] / double(count[c]);
    std::vector<double> out(comp, 0.0), decided(comp, 0.0), facing(comp, 0.0);
    for (size_t i = 0; i < n; ++i) {
        uint32_t c = label[i];
        const float *nn = normals + 3 * i;
        double o = 0;
        for (int a = 0; a < 3; ++a) o += nn[a] * (points[3 * i + a] - cen[3 * size_t(c) + a]);
        out[c] += o > 0;
        decided[c] += o != 0;
        facing[c] += (nn[0] * opt.up[0] + nn[1] * opt.up[1] + nn[2] * opt.up[2]) > 0;
    }
    std::vector<uint8_t> flip(comp, 0);
    for (uint32_t c = 0; c < comp; ++c) {
        double frac = decided[c] > 0 ? out[c] / decided[c] : 0.5;
        bool f = frac < 0.5;
        if (opt.has_up && std::fabs(frac - 0.5) <= opt.undecided_margin)
            f = facing[c] < double(count[c]) / 2.0;
        flip[c] = f;
    }
    for (size_t i = 0; i < n; ++i) {
        bool f = flip[label[i]] != (sign[i] < 0);
        if (flip[label[i]])
            for (int a = 0; a < 3; ++a) normals[3 * i + a] = -normals[3 * i + a];
        res.flipped += f;
    }
    return res;
}

}  // namespace pointviz
