// pointviz — neighbours within each scan (see scan_neighbours.h).
#include "pointviz/scan_neighbours.h"

#include "pointviz/parallel.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <stdexcept>
#include <utility>
#include <vector>

namespace pointviz {

namespace {

/// The members of each group with more than k points, in index order (the caller's order keeps
/// them spatially coherent), the largest group first; the rows of the points of smaller groups
/// are filled here from `all` (neighbours among all points).
/// The distinct values of a cloud's scan numbers, ascending, and each point's place among them:
/// the scans numbered 0 .. count - 1 in the order a std::map of them iterates in, without a map
/// lookup per point (1M lookups of 8 scans' numbers: ~50 ms, every other one mispredicted).
struct DenseGroups {
    std::vector<int32_t> value;  ///< the distinct scan numbers, ascending
    std::vector<uint32_t> of;    ///< (n,) each point's place in `value`
};

DenseGroups dense_groups(const int32_t *group, size_t n) {
    DenseGroups d;
    d.of.resize(n);
    if (n == 0) return d;
    int32_t lo = group[0], hi = group[0];
    for (size_t i = 1; i < n; ++i) lo = std::min(lo, group[i]), hi = std::max(hi, group[i]);
    const uint64_t range = uint64_t(int64_t(hi) - int64_t(lo)) + 1;
    if (range <= 2 * uint64_t(n) + 1024) {  // a table over the numbers' range
        std::vector<uint32_t> place(range, 0);
        for (size_t i = 0; i < n; ++i) place[size_t(int64_t(group[i]) - lo)] = 1;
        uint32_t next = 0;
        for (uint64_t v = 0; v < range; ++v)
            if (place[v]) {
                d.value.push_back(int32_t(int64_t(lo) + int64_t(v)));
                place[v] = next++;
            }
        for (size_t i = 0; i < n; ++i) d.of[i] = place[size_t(int64_t(group[i]) - lo)];
    } else {  // sparse numbers: sorted and searched
        d.value.assign(group, group + n);
        std::sort(d.value.begin(), d.value.end());
        d.value.erase(std::unique(d.value.begin(), d.value.end()), d.value.end());
        for (size_t i = 0; i < n; ++i)
            d.of[i] = uint32_t(std::lower_bound(d.value.begin(), d.value.end(), group[i]) -
                               d.value.begin());
    }
    return d;
}

std::vector<std::vector<uint32_t>> large_groups(const double *points, size_t n,
                                                const int32_t *group, uint32_t k,
                                                const KnnTree &all, NeighbourTable &out,
                                                const DenseGroups &dense) {
    if (all.size() != n || n <= k)
        throw std::invalid_argument("neighbours within scans: need a tree over more than k points");
    out.n = n;
    out.k = k;
    out.index.resize(n * size_t(k));  // unfilled (or as the caller filled it): rows written below
    // each scan's points in index order, the scans in ascending order of their numbers
    std::vector<std::vector<uint32_t>> members(dense.value.size());
    {
        std::vector<size_t> size(members.size(), 0);
        for (size_t i = 0; i < n; ++i) ++size[dense.of[i]];
        for (size_t g = 0; g < members.size(); ++g) members[g].reserve(size[g]);
    }
    for (size_t i = 0; i < n; ++i) members[dense.of[i]].push_back(uint32_t(i));
    std::vector<std::vector<uint32_t>> scans;
    std::vector<double> d2(k);
    for (auto &ids : members) {
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

/// The viewpoint of the scan `ids` when its points share one (`viewpoints`: 1 or n rows), else
/// null.
const double *scan_viewpoint(const double *viewpoints, size_t n_viewpoints,
                             const std::vector<uint32_t> &ids) {
    if (!viewpoints || n_viewpoints == 0) return nullptr;
    if (n_viewpoints == 1) return viewpoints;
    const double *eye = viewpoints + 3 * size_t(ids[0]);
    for (uint32_t i : ids) {
        const double *e = viewpoints + 3 * size_t(i);
        if (e[0] != eye[0] || e[1] != eye[1] || e[2] != eye[2]) return nullptr;
    }
    return eye;
}

/// One scan's points binned by their direction from the scan's viewpoint (see
/// knn_within_grids): each point's image on the plane one unit in front of the viewpoint,
/// perpendicular to the points' mean direction, in square cells of side h with a border of
/// kViewMaxRing empty cells on every side. The points are stored by cell (slots
/// start[o] .. start[o + 1] of cell o), with their coordinates, images, ranges and indices in
/// that order: a ring's cells are read from a few contiguous runs, and consecutive queries
/// (taken in slot order) share their rings.
struct ViewGrid {
    static constexpr int32_t pad = kViewMaxRing;
    /// Points may lie at most this far off the mean direction (cos 60 degrees): beyond, the
    /// plane stretches directions by more than 4x and the search would need many rings.
    static constexpr double kMinCos = 0.5;
    /// Samples per cell the cell size aims at. CPU seconds of the 15 nearest within each of 8
    /// scans of 125k points of a sphere at 1 / 1.5 / 2: 0.70-0.71 / 0.71-0.73 / 0.73-0.74 (the
    /// scans' KD-trees: 0.92-0.98 in the same runs).
    static constexpr double kSamplesPerCell = 1.5;
    /// The grid may have at most this many cells per point (its occupied part being small).
    static constexpr double kMaxCellsPerPoint = 16.0;

    double h = 0;        ///< cell side on the image plane
    double x0 = 0, y0 = 0;  ///< image of cell (0, 0)'s corner
    double stretch = 1;  ///< cos^2 of the widest angle of a point off the mean direction
    size_t stride = 0;   ///< cells per row
    std::vector<uint32_t> start;  ///< (cells + 1) first slot of each cell
    std::vector<uint32_t> cell;   ///< cell of each slot
    std::vector<uint32_t> index;  ///< point index of each slot
    std::vector<uint32_t> member; ///< position in the scan's ids of each slot
    std::vector<double> xyz;      ///< (slots, 3)
    std::vector<double> img;      ///< (slots, 2) image on the plane
    std::vector<double> range;    ///< distance from the viewpoint

    /// False when the points do not all lie within 60 degrees of their mean direction from
    /// `eye` (or on it), or their images span no area.
    bool build(const double *points, const std::vector<uint32_t> &ids, const double *eye) {
        const size_t m = ids.size();
        double a[3] = {0, 0, 0};
        for (uint32_t i : ids) {
            const double *p = points + 3 * size_t(i);
            double d[3] = {p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]};
            double r = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            if (!(r > 0)) return false;
            for (int c = 0; c < 3; ++c) a[c] += d[c] / r;
        }
        double len = std::sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
        if (!(len > 0)) return false;
        for (double &c : a) c /= len;
        // u, v: perpendicular to a, u away from a's smallest component
        int least = std::fabs(a[0]) <= std::fabs(a[1]) ? (std::fabs(a[0]) <= std::fabs(a[2]) ? 0 : 2)
                                                       : (std::fabs(a[1]) <= std::fabs(a[2]) ? 1 : 2);
        double e[3] = {0, 0, 0};
        e[least] = 1;
        double u[3] = {a[1] * e[2] - a[2] * e[1], a[2] * e[0] - a[0] * e[2],
                       a[0] * e[1] - a[1] * e[0]};
        double ul = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
        for (double &c : u) c /= ul;
        double v[3] = {a[1] * u[2] - a[2] * u[1], a[2] * u[0] - a[0] * u[2],
                       a[0] * u[1] - a[1] * u[0]};
        std::vector<double> im(2 * m), rg(m);
        double cos_min = 1, xlo = INFINITY, xhi = -INFINITY, ylo = INFINITY, yhi = -INFINITY;
        for (size_t t = 0; t < m; ++t) {
            const double *p = points + 3 * size_t(ids[t]);
            double d[3] = {p[0] - eye[0], p[1] - eye[1], p[2] - eye[2]};
            double r = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
            double z = d[0] * a[0] + d[1] * a[1] + d[2] * a[2];
            if (!(z >= kMinCos * r)) return false;
            cos_min = std::min(cos_min, z / r);
            double x = (d[0] * u[0] + d[1] * u[1] + d[2] * u[2]) / z;
            double y = (d[0] * v[0] + d[1] * v[1] + d[2] * v[2]) / z;
            im[2 * t] = x, im[2 * t + 1] = y, rg[t] = r;
            xlo = std::min(xlo, x), xhi = std::max(xhi, x);
            ylo = std::min(ylo, y), yhi = std::max(yhi, y);
        }
        const double w = xhi - xlo, ht = yhi - ylo;
        if (!(w > 0 && ht > 0)) return false;
        stretch = cos_min * cos_min;
        // the cell size from the area the images occupy: counted in cells of about 4 x 4
        // samples (of their box's sampling), which a scan covers well inside its outline and
        // which leave few in part on it (a scan rarely fills its box)
        {
            const double coarse = 4.0 * std::sqrt(w * ht / double(m));
            const size_t cols = size_t(w / coarse) + 1, rows = size_t(ht / coarse) + 1;
            std::vector<uint8_t> used(cols * rows, 0);
            size_t occupied = 0;
            for (size_t t = 0; t < m; ++t) {
                size_t cx = std::min(cols - 1, size_t((im[2 * t] - xlo) / coarse));
                size_t cy = std::min(rows - 1, size_t((im[2 * t + 1] - ylo) / coarse));
                occupied += !used[cy * cols + cx];
                used[cy * cols + cx] = 1;
            }
            const double spacing = std::sqrt(double(occupied) * coarse * coarse / double(m));
            h = std::max(std::sqrt(w * ht / (kMaxCellsPerPoint * double(m))),
                         std::sqrt(kSamplesPerCell) * spacing);
        }
        const size_t inner_cols = size_t(w / h) + 1, inner_rows = size_t(ht / h) + 1;
        stride = inner_cols + 2 * pad;
        const size_t cells = (inner_rows + 2 * pad) * stride;
        x0 = xlo - pad * h, y0 = ylo - pad * h;
        std::vector<uint32_t> of(m);
        start.assign(cells + 1, 0);
        for (size_t t = 0; t < m; ++t) {
            size_t cx = std::min(inner_cols - 1, size_t((im[2 * t] - xlo) / h)) + pad;
            size_t cy = std::min(inner_rows - 1, size_t((im[2 * t + 1] - ylo) / h)) + pad;
            of[t] = uint32_t(cy * stride + cx);
            ++start[of[t] + 1];
        }
        for (size_t o = 0; o < cells; ++o) start[o + 1] += start[o];
        std::vector<uint32_t> fill(start.begin(), start.end() - 1);
        cell.resize(m), index.resize(m), member.resize(m);
        xyz.resize(3 * m), img.resize(2 * m), range.resize(m);
        for (size_t t = 0; t < m; ++t) {  // in index order within each cell
            uint32_t sl = fill[of[t]]++;
            cell[sl] = of[t], index[sl] = ids[t], member[sl] = uint32_t(t);
            for (int c = 0; c < 3; ++c) xyz[3 * sl + c] = points[3 * size_t(ids[t]) + c];
            img[2 * sl] = im[2 * t], img[2 * sl + 1] = im[2 * t + 1];
            range[sl] = rg[t];
        }
        return true;
    }

    /// The k nearest of the point in slot `s` within its scan, into `best`, and the last ring
    /// read; -1 when the rings up to kViewMaxRing do not settle them (the point is to be
    /// searched in the scan's tree).
    /// (Skipping the cells of a ring that lie wholly in front of or behind the k nearest found,
    /// by their range, read fewer points but cost more than it saved: 1.09 s instead of 0.90 s
    /// on the sphere scans above, at 2 samples per cell and 6 rings.)
    int search(uint32_t s, KnnHeap &best) const {
        const double *q = xyz.data() + 3 * size_t(s);
        const double q0 = q[0], q1 = q[1], q2 = q[2];
        const ptrdiff_t c = ptrdiff_t(cell[s]), st = ptrdiff_t(stride);
        // the image relative to its own cell's corner
        const double fx = img[2 * size_t(s)] - x0 - double(c % st) * h;
        const double fy = img[2 * size_t(s) + 1] - y0 - double(c / st) * h;
        const double margin = std::max(0.0, std::min({fx, h - fx, fy, h - fy}));
        const double rq = range[s];
        best.size = 0;
        const uint32_t *first = start.data();
        const double *pts = xyz.data();
        auto visit_run = [&](ptrdiff_t o0, ptrdiff_t o1) {  // cells o0 .. o1 (inclusive)
            for (uint32_t t = first[o0], e = first[o1 + 1]; t < e; ++t) {
                if (t == s) continue;
                const double *p = pts + 3 * size_t(t);
                double d = (p[0] - q0) * (p[0] - q0) + (p[1] - q1) * (p[1] - q1) +
                           (p[2] - q2) * (p[2] - q2);
                best.push(d, index[t]);
            }
        };
        for (ptrdiff_t ring = 0; ring <= kViewMaxRing; ++ring) {
            if (ring == 0) {
                visit_run(c, c);
            } else {
                visit_run(c - ring * st - ring, c - ring * st + ring);
                for (ptrdiff_t dr = -ring + 1; dr < ring; ++dr) {
                    visit_run(c + dr * st - ring, c + dr * st - ring);
                    visit_run(c + dr * st + ring, c + dr * st + ring);
                }
                visit_run(c + ring * st - ring, c + ring * st + ring);
            }
            if (best.size < best.k) continue;
            // every point outside these rings is at least this far (its image at least
            // ring x h + margin from the point's)
            const double gap = double(ring) * h + margin;
            if (best.d2[best.k - 1] < reach2(gap * gap, rq)) return int(ring);
        }
        return -1;
    }

    /// A lower bound on the squared distance from a point at range `rq` to any point whose
    /// image lies at least sqrt(`gap2`) from its image. Their angle a at the viewpoint is at
    /// least gap x stretch (the plane stretches angles by at most 1 / stretch), and the point
    /// seen at angle a lies rq sin a across from the other's ray. Smaller by 2e-9 than the exact
    /// bound (a strict test under rounding); sin a >= a (1 - a^2 / 6) below 1 radian, and
    /// >= 0.8333 from there to 120 degrees (points lie within 60 degrees of the axis).
    double reach2(double gap2, double rq) const {
        double a2 = gap2 * stretch * stretch;
        double across = a2 < 1.0 ? rq * (1.0 - a2 / 6.0) : rq * 0.8333;
        return (a2 < 1.0 ? across * across * a2 : across * across) * (1.0 - 2e-9);
    }

    /// Whether an even sample of the points settles within few rings on average (counting a
    /// point left open as kViewMaxRing + 1): at most two more than 1.5 x the radius, in cells, of
    /// the disc that holds k samples. Else the scan is searched in its tree (its points seen
    /// mostly edge-on, or sampled far from evenly).
    bool pays(KnnHeap &best) const {
        const double kPayRings = 2.0 + 1.5 * std::sqrt(best.k / (3.14159 * kSamplesPerCell));
        const size_t m = index.size(), step = std::max<size_t>(1, m / 256);
        size_t tried = 0, rings = 0;
        for (size_t s = step / 2; s < m; s += step, ++tried) {
            int r = search(uint32_t(s), best);
            rings += size_t(r < 0 ? kViewMaxRing + 1 : r);
        }
        return double(rings) <= kPayRings * double(tried);
    }
};

}  // namespace

NeighbourTable knn_within_groups(const double *points, size_t n, const int32_t *group,
                                 uint32_t k, const KnnTree &all, int threads,
                                 Progress *progress) {
    NeighbourTable out;
    std::vector<std::vector<uint32_t>> scans =
        large_groups(points, n, group, k, all, out, dense_groups(group, n));
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

namespace {

/// knn_within_grids into `out` (its rows of points with need[i] == 0 left as they are), the
/// scans numbered by `dense`.
void grid_rows(const double *points, size_t n, const int32_t *group, const int32_t *cell,
               const double *viewpoints, size_t n_viewpoints, uint32_t k, const KnnTree &all,
               int threads, Progress *progress, GridNeighbourStats *stats, const uint8_t *need,
               const DenseGroups &dense, NeighbourTable &out) {
    std::vector<std::vector<uint32_t>> scans = large_groups(points, n, group, k, all, out, dense);
    if (need) {
        // the most searches first, by the rows each scan searches (a scan whose rows were
        // mostly taken from elsewhere is quick): a long one taken last would leave the other
        // workers idle
        std::vector<std::pair<size_t, size_t>> order(scans.size());
        for (size_t s = 0; s < scans.size(); ++s) {
            size_t c = 0;
            for (uint32_t i : scans[s]) c += need[i] != 0;
            order[s] = {c, s};
        }
        std::stable_sort(order.begin(), order.end(),
                         [](const auto &a, const auto &b) { return a.first > b.first; });
        std::vector<std::vector<uint32_t>> sorted(scans.size());
        for (size_t s = 0; s < scans.size(); ++s) sorted[s] = std::move(scans[order[s].second]);
        scans.swap(sorted);
    }
    size_t queries = 0;
    for (const std::vector<uint32_t> &ids : scans) queries += ids.size();
    if (progress) progress->total.fetch_add(queries, std::memory_order_relaxed);
    std::atomic<size_t> from_tree{0}, from_grid{0}, from_view{0};
    parallel_for(scans.size(), 1, threads, [&](size_t b, size_t e, int) {
        std::vector<uint32_t> hidx(k), rest;
        std::vector<double> hd2(k);
        KnnHeap heap{k, 0, hd2.data(), hidx.data()};
        for (size_t s = b; s < e; ++s) {
            const std::vector<uint32_t> &ids = scans[s];
            rest.clear();
            CellMap map;
            ViewGrid view;
            const double *eye = scan_viewpoint(viewpoints, n_viewpoints, ids);
            if (cell && map.build(points, cell, ids)) {
                // the points in grid order (each row is independent of the order)
                size_t skipped = 0;
                for (size_t p = 0; p < ids.size(); ++p) {
                    uint32_t i = ids[p];
                    if (need && !need[i]) ++skipped;
                    else if (cell[2 * size_t(i)] < 0 || cell[2 * size_t(i) + 1] < 0)
                        rest.push_back(uint32_t(p));
                }
                for (size_t o = 0; o < map.at.size(); ++o) {
                    uint32_t i = map.at[o];
                    if (i == kNoIndex || (need && !need[i])) continue;
                    if (!grid_search(map, o, heap)) {
                        // ids is in index order
                        rest.push_back(uint32_t(std::lower_bound(ids.begin(), ids.end(), i) -
                                                ids.begin()));
                        continue;
                    }
                    std::copy(hidx.begin(), hidx.end(), out.index.begin() + size_t(i) * k);
                }
                from_grid.fetch_add(ids.size() - skipped - rest.size(), std::memory_order_relaxed);
            } else if (eye && view.build(points, ids, eye) && view.pays(heap)) {
                size_t skipped = 0;
                for (uint32_t t = 0; t < view.index.size(); ++t) {
                    if (need && !need[view.index[t]]) {
                        ++skipped;
                        continue;
                    }
                    if (view.search(t, heap) < 0) {
                        rest.push_back(view.member[t]);
                        continue;
                    }
                    std::copy(hidx.begin(), hidx.end(),
                              out.index.begin() + size_t(view.index[t]) * k);
                }
                from_view.fetch_add(ids.size() - skipped - rest.size(), std::memory_order_relaxed);
            } else if (need) {
                for (size_t p = 0; p < ids.size(); ++p)
                    if (need[ids[p]]) rest.push_back(uint32_t(p));
                if (!rest.empty()) scan_tree_rows(points, ids, &rest, k, out);
                from_tree.fetch_add(rest.size(), std::memory_order_relaxed);
                if (progress) progress->advance(ids.size());
                continue;
            } else {
                scan_tree_rows(points, ids, nullptr, k, out);
                from_tree.fetch_add(ids.size(), std::memory_order_relaxed);
                if (progress) progress->advance(ids.size());
                continue;
            }
            if (!rest.empty()) scan_tree_rows(points, ids, &rest, k, out);
            from_tree.fetch_add(rest.size(), std::memory_order_relaxed);
            if (progress) progress->advance(ids.size());
        }
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    if (stats) {
        stats->from_tree = from_tree.load();
        stats->from_grid = from_grid.load();
        stats->from_view = from_view.load();
    }
}

}  // namespace

NeighbourTable knn_within_grids(const double *points, size_t n, const int32_t *group,
                                const int32_t *cell, const double *viewpoints,
                                size_t n_viewpoints, uint32_t k, const KnnTree &all, int threads,
                                Progress *progress, GridNeighbourStats *stats,
                                const uint8_t *need) {
    NeighbourTable out;
    grid_rows(points, n, group, cell, viewpoints, n_viewpoints, k, all, threads, progress, stats,
              need, dense_groups(group, n), out);
    return out;
}

ScanRows knn_within_grids_reusing(const double *points, size_t n, const int32_t *group,
                                  const int32_t *cell, const double *viewpoints,
                                  size_t n_viewpoints, uint32_t k, uint32_t k_least,
                                  const NeighbourTable &across, const KnnTree &all, int threads,
                                  Progress *progress, GridNeighbourStats *stats) {
    if (across.n != n || k_least == 0 || k_least > k)
        throw std::invalid_argument("neighbours within scans: bad table to reuse");
    if (all.size() != n || n <= k)
        throw std::invalid_argument("neighbours within scans: need a tree over more than k points");
    ScanRows out;
    out.count.resize(n);
    out.table.n = n;
    out.table.k = k;
    out.table.index.resize(n * size_t(k));  // unfilled: every row is written below or searched
    const DenseGroups dense = dense_groups(group, n);
    std::vector<size_t> sizes(dense.value.size(), 0);
    for (size_t i = 0; i < n; ++i) ++sizes[dense.of[i]];
    // the same-scan entries of each row of `across`, in its order: the nearest of the point's
    // own scan, as the search within the scan ranks them (by distance, then index); a row with
    // fewer than k_least of them (or of a scan of at most k points) is searched instead
    std::vector<uint8_t> need(n);
    std::atomic<size_t> reused{0};
    parallel_for(n, 4096, threads, [&](size_t b, size_t e, int) {
        std::vector<uint32_t> same(across.k + 1);
        size_t taken = 0;
        for (size_t i = b; i < e; ++i) {
            // without a branch on each entry (a row's scans are mixed): every entry written,
            // the count advanced over those of the point's scan; the first k of them kept
            const uint32_t *row = across.row(i);
            const int32_t own = group[i];
            uint32_t c = 0;
            for (uint32_t m = 0; m < across.k; ++m) {
                same[c] = row[m];
                c += group[row[m]] == own;
            }
            c = std::min(c, k);
            need[i] = c < k_least || sizes[dense.of[i]] <= k;
            out.count[i] = need[i] ? k : c;
            if (need[i]) continue;
            uint32_t *dst = out.table.index.data() + i * k;
            std::copy(same.begin(), same.begin() + c, dst);
            std::fill(dst + c, dst + k, kNoIndex);  // past the row's count
            ++taken;
        }
        reused.fetch_add(taken, std::memory_order_relaxed);
    }, progress ? &progress->cancel : nullptr);
    check_cancel(progress);
    out.reused = reused.load();
    grid_rows(points, n, group, cell, viewpoints, n_viewpoints, k, all, threads, progress, stats,
              need.data(), dense, out.table);
    if (stats) stats->from_across = out.reused;
    return out;
}

}  // namespace pointviz
