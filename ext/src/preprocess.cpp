// pointviz — the preprocessing steps composed (see preprocess.h).
#include "pointviz/preprocess.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <thread>

#include "pointviz/parallel.h"


namespace pointviz {

KnnOutput knn_points(const PointsView &in, uint32_t k, int threads, Progress &progress) {
    KnnTree tree(in.points, in.n, threads, &progress);
    KnnOutput out;
    out.table = knn_all(tree, in.points, k, threads, &progress);
    const NeighbourTable &t = out.table;
    out.dist.resize(t.n * t.k);
    for (size_t i = 0; i < t.n; ++i)
        for (uint32_t m = 0; m < t.k; ++m) {
            const double *p = in.points + 3 * i, *q = in.points + 3 * size_t(t.row(i)[m]);
            out.dist[i * t.k + m] = std::sqrt((p[0] - q[0]) * (p[0] - q[0]) +
                                              (p[1] - q[1]) * (p[1] - q[1]) +
                                              (p[2] - q[2]) * (p[2] - q[2]));
        }
    return out;
}

NearestOutput nearest_points(const PointsView &in, const double *queries, size_t m, int threads,
                             Progress &progress) {
    KnnTree tree(in.points, in.n, threads, &progress);
    NearestOutput out;
    out.index.resize(m);
    out.dist.resize(m);
    constexpr size_t kGrain = 4096;
    parallel_for(m, kGrain, threads, [&](size_t b, size_t e, int) {
        for (size_t i = b; i < e; ++i) {
            double d2 = 0;
            tree.query(queries + 3 * i, 1, kNoIndex, &out.index[i], &d2);
            out.dist[i] = std::sqrt(d2);
        }
        progress.advance(e - b);
    }, &progress.cancel);
    progress.check();  // stopped between chunks: Cancelled
    return out;
}

namespace {

/// Median of `v` as numpy computes it (the mean of the two middle values of an even count).
double median(std::vector<double> v) {
    if (v.empty()) return 0.0;
    const size_t h = v.size() / 2;
    std::nth_element(v.begin(), v.begin() + h, v.end());
    const double hi = v[h];
    if (v.size() % 2) return hi;
    const double lo = *std::max_element(v.begin(), v.begin() + h);
    return (lo + hi) / 2.0;
}

/// A cloud's points (and viewpoints, scans) in the order of a KD-tree built on them, and that
/// tree answering with positions in this order. Each point's neighbours are then close to it in
/// memory: the per-point steps (normals, fit, radii) read neighbours from cache instead of from
/// anywhere in the input (2x faster on scans stored scan by scan).
struct Spatial {
    UnfilledVector<uint32_t> perm;       ///< perm[r]: input index of the point stored at r
    std::vector<double> viewpoints;
    std::vector<int32_t> group, cell;
    PointsView view;
    KnnTree tree;
    int threads;

    Spatial(const PointsView &in, int threads_, Progress &progress)
        : tree(in.points, in.n, threads_, &progress), threads(threads_) {
        perm = tree.order();
        tree.renumber_in_tree_order();
        view = in;
        view.points = tree.stored_points().data();  // the tree's own copy, in its order
        if (in.viewpoints && in.n_viewpoints == in.n && in.n > 1) {
            viewpoints = to_tree(in.viewpoints, 3);
            view.viewpoints = viewpoints.data();
        }
        if (in.group) {
            group = to_tree(in.group);
            view.group = group.data();
        }
        if (in.cell) {
            cell = to_tree(in.cell, 2);
            view.cell = cell.data();
        }
    }
    /// `rows` values per point, from tree order to input order (on the workers: one thread
    /// would leave the other cores idle).
    template <class T>
    std::vector<T> to_input(const std::vector<T> &v, size_t rows = 1) const {
        std::vector<T> out(v.size());
        parallel_for(perm.size(), kGrain, threads, [&](size_t b, size_t e, int) {
            for (size_t r = b; r < e; ++r)
                for (size_t a = 0; a < rows; ++a)
                    out[rows * size_t(perm[r]) + a] = v[rows * r + a];
        });
        return out;
    }
    /// `rows` values per point, from input order to tree order.
    template <class T>
    std::vector<T> to_tree(const T *v, size_t rows = 1) const {
        std::vector<T> out(rows * perm.size());
        parallel_for(perm.size(), kGrain, threads, [&](size_t b, size_t e, int) {
            for (size_t r = b; r < e; ++r)
                for (size_t a = 0; a < rows; ++a)
                    out[rows * r + a] = v[rows * size_t(perm[r]) + a];
        });
        return out;
    }
    /// Points per chunk of the reorderings.
    static constexpr size_t kGrain = size_t(1) << 15;
};

void normals_to_input(const Spatial &sp, NormalsOutput &o) {
    if (!o.radii.empty()) o.radii = sp.to_input(o.radii);
    o.est.normals = sp.to_input(o.est.normals, 3);
    o.est.support = sp.to_input(o.est.support);
    o.est.spread = sp.to_input(o.est.spread);
}

/// Normals from the neighbour table `t` of all points (null: only needed when in.group is null
/// or there are no viewpoints; then it is computed on `tree` here). With scans (in.group), each
/// normal comes from its own scan's neighbours (see scan_neighbours.h).
NormalsOutput normals_from_table(const PointsView &in, const KnnTree &tree,
                                 const NeighbourTable *t, const NormalOptions &nopt,
                                 const OrientOptions &oopt, Progress &progress,
                                 const CoverOptions *cover = nullptr, uint32_t cover_k = 0) {
    NormalsOutput out;
    NeighbourTable own;
    uint32_t k = std::min<uint64_t>(std::max(nopt.k_max - 1, oopt.k), in.n - 1);
    bool need_all = !in.group || !in.viewpoints;
    if (need_all && !t) t = &(own = knn_all(tree, in.points, k, nopt.threads, &progress));
    if (in.group && in.n > 1) {
        uint32_t ks = std::min<uint64_t>(nopt.k_max - 1, in.n - 1);
        if (t && (in.cell || in.viewpoints)) {
            // a row of the table across scans that holds kScanRowsLeast or more of the point's
            // own scan gives its nearest within the scan (up to ks; in the order a search
            // there gives them): only the other points are searched
            ScanRows rows = knn_within_grids_reusing(
                in.points, in.n, in.group, in.cell, in.viewpoints, in.n_viewpoints, ks,
                std::min(ks, kScanRowsLeast), *t, tree, nopt.threads, &progress, &out.grid);
            out.est = estimate_normals(in.points, rows.table, nopt, &progress, rows.count.data());
        } else {
            NeighbourTable scan =
                in.cell || in.viewpoints
                    ? knn_within_grids(in.points, in.n, in.group, in.cell, in.viewpoints,
                                       in.n_viewpoints, ks, tree, nopt.threads, &progress,
                                       &out.grid)
                    : knn_within_groups(in.points, in.n, in.group, ks, tree, nopt.threads,
                                        &progress);
            out.est = estimate_normals(in.points, scan, nopt, &progress);
        }
    } else {
        out.est = estimate_normals(in.points, *t, nopt, &progress);
    }
    if (in.viewpoints)
        out.toward_viewpoint_flips = orient_toward(in.points, out.est.normals.data(), in.n,
                                                   in.viewpoints, in.n_viewpoints, nopt.threads);
    else if (oopt.from_above && oopt.has_up)
        out.orient = orient_above(in.points, out.est.normals.data(), *t, oopt, nopt.threads,
                                  &progress);
    else
        out.orient = orient_mst(in.points, out.est.normals.data(), *t, oopt, &progress);
    cover_k = uint32_t(std::min<uint64_t>(cover_k, in.n - 1));
    if (cover && cover_k > 0 && !in.viewpoints && t && t->k >= cover_k) {
        // the table's rows are sorted: their first cover_k columns are the radii's search
        NeighbourTable sub;
        sub.n = t->n;
        sub.k = cover_k;
        sub.index.resize(sub.n * size_t(cover_k));
        parallel_for(sub.n, size_t(1) << 15, nopt.threads, [&](size_t b, size_t e, int) {
            for (size_t i = b; i < e; ++i)
                std::copy_n(t->row(i), cover_k, sub.index.data() + i * size_t(cover_k));
        });
        out.radii = coverage_radii(in.points, out.est.normals.data(), sub, *cover, &progress);
    }
    return out;
}

}  // namespace

NormalsOutput normals_points(const PointsView &in, const NormalOptions &nopt,
                             const OrientOptions &oopt, Progress &progress,
                             const CoverOptions *cover, uint32_t cover_k) {
    Spatial sp(in, nopt.threads, progress);
    NormalsOutput out = normals_from_table(sp.view, sp.tree, nullptr, nopt, oopt, progress,
                                           cover, cover_k);
    normals_to_input(sp, out);
    return out;
}

OrientResult orient_points(const PointsView &in, float *normals, const OrientOptions &oopt,
                           int threads, Progress &progress) {
    OrientResult r;
    if (in.viewpoints) {
        r.flipped = orient_toward(in.points, normals, in.n, in.viewpoints, in.n_viewpoints,
                                  threads);
        return r;
    }
    KnnTree tree(in.points, in.n, threads, &progress);
    NeighbourTable t = knn_all(tree, in.points, oopt.k, threads, &progress);
    if (oopt.from_above && oopt.has_up)
        return orient_above(in.points, normals, t, oopt, threads, &progress);
    return orient_mst(in.points, normals, t, oopt, &progress);
}

std::vector<float> radii_points(const PointsView &in, const float *normals, uint32_t k,
                                const CoverOptions &opt, Progress &progress) {
    Spatial sp(in, opt.threads, progress);
    std::vector<float> nrm = sp.to_tree(normals, 3);
    return sp.to_input(coverage_radii(sp.view.points, nrm.data(), sp.tree, k, opt, &progress));
}

StrayResult stray_points(const PointsView &in, uint32_t k, const StrayOptions &opt,
                         Progress &progress) {
    Spatial sp(in, opt.threads, progress);
    NeighbourTable t = knn_all(sp.tree, sp.view.points, k, opt.threads, &progress);
    StrayResult r = find_stray_clusters(sp.view.points, t, sp.view.group, opt, &progress);
    r.stray = sp.to_input(r.stray);
    r.label = sp.to_input(r.label);
    return r;
}

FitOutput fit_points(const PointsView &in, const float *normals, const NormalOptions &nopt,
                     const OrientOptions &oopt, const FitOptions &fopt, Progress &progress,
                     const StrayOptions *sopt, const CoverOptions *copt, uint32_t cover_k) {
    Spatial sp(in, fopt.threads, progress);
    uint32_t k = std::max({nopt.k_max - 1, oopt.k, fopt.min_support - 1});
    NeighbourTable t = knn_all(sp.tree, sp.view.points, k, fopt.threads, &progress);
    FitOutput out;
    const PointsView &v = sp.view;
    std::vector<float> nrm;
    const uint32_t *support = nullptr;
    if (normals) {
        nrm = sp.to_tree(normals, 3);
    } else {
        out.normals = normals_from_table(sp.view, sp.tree, &t, nopt, oopt, progress);
        nrm = out.normals.est.normals;
        support = out.normals.est.support.data();
    }
    // the stray clusters (the components of the input's neighbour graph: the fit moves points
    // apart) on a thread of their own beside the fit: mostly a serial union-find, which would
    // otherwise leave the other cores idle after the fit. Started after the normals, so that it
    // runs while the fit's thinning (serial too) leaves a core free.
    std::exception_ptr stray_error;
    std::thread stray_worker;
    if (sopt)
        stray_worker = std::thread([&] {
            try {
                StrayOptions so = *sopt;
                so.threads = 1;
                out.stray = find_stray_clusters(v.points, t, v.group, so, &progress);
            } catch (...) {
                stray_error = std::current_exception();
            }
        });
    struct Join {
        std::thread &t;
        ~Join() {
            if (t.joinable()) t.join();
        }
    } join{stray_worker};
    out.fit = fit_surface(v.points, nrm.data(), support, t, v.group, v.viewpoints, v.n_viewpoints,
                          fopt, &progress);
    if (!normals) normals_to_input(sp, out.normals);
    FitResult &f = out.fit;
    if (sopt) {
        stray_worker.join();
        if (stray_error) std::rethrow_exception(stray_error);
        std::atomic<size_t> kept{0};
        parallel_for(v.n, Spatial::kGrain, fopt.threads, [&](size_t b, size_t e, int) {
            size_t c = 0;
            for (size_t i = b; i < e; ++i) {
                f.keep[i] &= uint8_t(!out.stray.stray[i]);
                c += f.keep[i];
            }
            kept.fetch_add(c, std::memory_order_relaxed);
        });
        f.kept = kept.load();
        out.stray.stray = sp.to_input(out.stray.stray);
        out.stray.label = sp.to_input(out.stray.label);
    }
    if (copt) {
        // the kept points' radii on their fitted positions, their neighbours from the rows
        RowRadii rr = coverage_radii_from_rows(f.points.data(), f.normals.data(), v.n,
                                               f.keep.data(), t, cover_k, *copt, &progress);
        out.radii.assign(v.n, 0.f);
        for (size_t i = 0, a = 0; i < v.n; ++i)
            if (f.keep[i]) out.radii[i] = rr.radii[a++];
        out.radii = sp.to_input(out.radii);
        out.radii_searched = rr.searched;
    }
    out.median_spacing = median(f.spacing);
    f.points = sp.to_input(f.points, 3);
    f.normals = sp.to_input(f.normals, 3);
    f.keep = sp.to_input(f.keep);
    f.shift = sp.to_input(f.shift);
    f.spacing = sp.to_input(f.spacing);
    return out;
}

}  // namespace pointviz
