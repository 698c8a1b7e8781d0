// pointviz — the preprocessing steps composed (see preprocess.h).
#include "pointviz/preprocess.h"

#include <algorithm>
#include <cmath>

namespace pointviz {

KnnOutput knn_points(const PointsView &in, uint32_t k, int threads, Progress &progress) {
    KdTree tree(in.points, in.n, threads, &progress);
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

namespace {

NormalsOutput normals_from_table(const PointsView &in, const NeighbourTable &t,
                                 const NormalOptions &nopt, const OrientOptions &oopt,
                                 Progress &progress) {
    NormalsOutput out;
    out.est = estimate_normals(in.points, t, nopt, &progress);
    if (in.viewpoints)
        out.toward_viewpoint_flips = orient_toward(in.points, out.est.normals.data(), in.n,
                                                   in.viewpoints, in.n_viewpoints);
    else
        out.orient = orient_mst(in.points, out.est.normals.data(), t, oopt, &progress);
    return out;
}

}  // namespace

NormalsOutput normals_points(const PointsView &in, const NormalOptions &nopt,
                             const OrientOptions &oopt, Progress &progress) {
    KdTree tree(in.points, in.n, nopt.threads, &progress);
    uint32_t k = std::max(nopt.k_max - 1, oopt.k);
    NeighbourTable t = knn_all(tree, in.points, k, nopt.threads, &progress);
    return normals_from_table(in, t, nopt, oopt, progress);
}

OrientResult orient_points(const PointsView &in, float *normals, const OrientOptions &oopt,
                           int threads, Progress &progress) {
    OrientResult r;
    if (in.viewpoints) {
        r.flipped = orient_toward(in.points, normals, in.n, in.viewpoints, in.n_viewpoints);
        return r;
    }
    KdTree tree(in.points, in.n, threads, &progress);
    NeighbourTable t = knn_all(tree, in.points, oopt.k, threads, &progress);
    return orient_mst(in.points, normals, t, oopt, &progress);
}

std::vector<float> radii_points(const PointsView &in, const float *normals, uint32_t k,
                                const CoverOptions &opt, Progress &progress) {
    KdTree tree(in.points, in.n, opt.threads, &progress);
    NeighbourTable t = knn_all(tree, in.points, k, opt.threads, &progress);
    return coverage_radii(in.points, normals, t, opt, &progress);
}

FitOutput fit_points(const PointsView &in, const float *normals, const NormalOptions &nopt,
                     const OrientOptions &oopt, const FitOptions &fopt, Progress &progress) {
    KdTree tree(in.points, in.n, fopt.threads, &progress);
    uint32_t k = std::max({nopt.k_max - 1, oopt.k, fopt.min_support - 1});
    NeighbourTable t = knn_all(tree, in.points, k, fopt.threads, &progress);
    FitOutput out;
    const float *nrm = normals;
    const uint32_t *support = nullptr;
    if (!nrm) {
        out.normals = normals_from_table(in, t, nopt, oopt, progress);
        nrm = out.normals.est.normals.data();
        support = out.normals.est.support.data();
    }
    out.fit = fit_surface(in.points, nrm, support, t, in.group, in.viewpoints, in.n_viewpoints,
                          fopt, &progress);
    return out;
}

}  // namespace pointviz
