// pointviz._core — type conversion only: numpy arrays in, numpy arrays out. Every long call
// releases the GIL. The public API is the Python package that wraps this module.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/unique_ptr.h>
#include <nanobind/stl/tuple.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <optional>
#include <limits>
#include <tuple>

#include <memory>

#include <chrono>
#include <thread>

#include "pointviz/cast.h"
#include "pointviz/depth_planes.h"
#include "pointviz/dispatch.h"
#include "pointviz/kdtree.h"
#include "pointviz/preprocess.h"
#include "pointviz/lod.h"
#include "pointviz/render.h"
#include "pointviz/tree.h"
#include "pygeometry.h"
#include "readers_bindings.h"
#include "run_progress.h"

namespace nanobind::detail {
/// Vec3 <-> any sequence of three numbers (tuple on the way out).
template <>
struct type_caster<pointviz::Vec3> {
    NB_TYPE_CASTER(pointviz::Vec3, const_name("tuple[float, float, float]"))
    bool from_python(handle src, uint8_t, cleanup_list *) noexcept {
        PyObject *seq = PySequence_Fast(src.ptr(), "");
        if (!seq) {
            PyErr_Clear();
            return false;
        }
        bool ok = PySequence_Fast_GET_SIZE(seq) == 3;
        for (Py_ssize_t k = 0; ok && k < 3; ++k) {
            double v = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(seq, k));
            if (v == -1.0 && PyErr_Occurred()) {
                PyErr_Clear();
                ok = false;
            }
            value[int(k)] = float(v);
        }
        Py_DECREF(seq);
        return ok;
    }
    static handle from_cpp(const pointviz::Vec3 &v, rv_policy, cleanup_list *) noexcept {
        return PyTuple_Pack(3, PyFloat_FromDouble(v.x), PyFloat_FromDouble(v.y), PyFloat_FromDouble(v.z));
    }
};
}  // namespace nanobind::detail

namespace nb = nanobind;
using namespace nb::literals;
using namespace pointviz;

namespace {

template <class T>
using CArray = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;
/// Any C-contiguous CPU array; the binding checks its dtype itself.
using AnyArray = nb::ndarray<nb::c_contig, nb::device::cpu>;

/// A fresh numpy array that owns its buffer.
template <class T>
nb::ndarray<nb::numpy, T> new_array(std::initializer_list<size_t> shape, T **data) {
    size_t total = 1;
    for (size_t s : shape) total *= s;
    T *buf = new T[total == 0 ? 1 : total];
    nb::capsule owner(buf, [](void *p) noexcept { delete[] static_cast<T *>(p); });
    *data = buf;
    return nb::ndarray<nb::numpy, T>(buf, shape.size(), shape.begin(), owner);
}

/// The array's data, or (when it is misaligned for T) an aligned copy of it in `copy`. Arrays
/// unpickled from out-of-band buffers (a Dask worker's scene) can sit at any byte offset, and
/// reading a misaligned double is undefined behaviour (UBSan flags it).
template <class T>
const T *aligned_data(const T *data, size_t count, std::vector<T> &copy) {
    if (reinterpret_cast<std::uintptr_t>(data) % alignof(T) == 0) return data;
    copy.resize(count);
    std::memcpy(copy.data(), data, count * sizeof(T));
    return copy.data();
}

void check_rows(const char *name, size_t ndim, size_t rows, size_t cols, size_t want_rows,
                size_t want_cols) {
    if (ndim != (want_cols == 0 ? 1u : 2u) || (want_cols && cols != want_cols) ||
        (want_rows != size_t(-1) && rows != want_rows))
        throw nb::value_error((std::string(name) + ": wrong shape").c_str());
}

/// Raised as pointviz.InputError by the Python layer: names the first bad row.
void check_invalid(const BatchStats &s, const char *what) {
    if (s.invalid == 0) return;
    throw nb::value_error((std::string("rays: ") + std::to_string(s.invalid) + " " + what +
                           " (first at row " + std::to_string(s.first_invalid) + ")").c_str());
}

nb::dict stats_dict(const BatchStats &s) {
    nb::dict d;
    double n = s.rays ? double(s.rays) : 1.0;
    d["rays"] = s.rays;
    d["hits"] = s.hits;
    d["nodes_visited"] = double(s.nodes) / n;
    d["disk_tests"] = double(s.disks) / n;
    d["max_depth"] = double(s.depth_sum) / n;
    d["deepest"] = s.max_depth;
    d["nodes_total"] = s.nodes;
    d["disk_tests_total"] = s.disks;
    return d;
}

/// `poll` as given or, for None, pointviz.interrupt.poll (the ambient cancel token): every long
/// call honours the CLI's Ctrl-C without each caller passing a token down.
nb::object poll_or_ambient(nb::object poll) {
    if (!poll.is_none()) return poll;
    return nb::module_::import_("pointviz.interrupt").attr("poll");
}

/// Aligned copies of a build's input arrays, made only where the caller's were misaligned.
struct SurfelCopies {
    std::vector<double> points;
    std::vector<float> normals, radii, colors;
};

/// The input arrays of a build, shapes checked; `keep` holds any aligned copies.
SurfelArrays surfel_arrays(const CArray<double> &points, const CArray<float> &normals,
                           const CArray<float> &radii, const std::optional<CArray<float>> &colors,
                           SurfelCopies &keep) {
    size_t n = points.shape(0);
    check_rows("points", points.ndim(), n, points.ndim() > 1 ? points.shape(1) : 0, n, 3);
    check_rows("normals", normals.ndim(), normals.shape(0), normals.ndim() > 1 ? normals.shape(1) : 0, n, 3);
    check_rows("radii", radii.ndim(), radii.shape(0), 0, n, 0);
    SurfelArrays in{aligned_data(points.data(), 3 * n, keep.points),
                    aligned_data(normals.data(), 3 * n, keep.normals),
                    aligned_data(radii.data(), n, keep.radii), nullptr, n};
    if (colors) {
        check_rows("colors", colors->ndim(), colors->shape(0), colors->ndim() > 1 ? colors->shape(1) : 0, n, 3);
        in.colors = aligned_data(colors->data(), 3 * n, keep.colors);
    }
    return in;
}

std::unique_ptr<SurfelTree> make_tree(CArray<double> points, CArray<float> normals,
                                      CArray<float> radii, std::optional<CArray<float>> colors,
                                      std::array<double, 3> origin, uint32_t leaf_size,
                                      uint32_t box_depth, int threads, bool wide, nb::object poll) {
    SurfelCopies keep;
    SurfelArrays in = surfel_arrays(points, normals, radii, colors, keep);
    BuildOptions opt{leaf_size, box_depth, threads, wide};
    Progress progress;
    return run_with_progress(progress, poll_or_ambient(poll), [&](Progress &p) {
        auto tree = std::make_unique<SurfelTree>(in, origin.data(), opt);
        p.check();  // the build does not poll yet: a cancel during it is honoured at its end
        return tree;
    });
}

/// Stage 1 of a staged build (see SurfelTreeBuild): positions and topology.
std::unique_ptr<SurfelTreeBuild> make_tree_build(CArray<double> points, std::array<double, 3> origin,
                                 uint32_t leaf_size, uint32_t box_depth, int threads,
                                 bool wide, nb::object poll) {
    size_t n = points.shape(0);
    check_rows("points", points.ndim(), n, points.ndim() > 1 ? points.shape(1) : 0, n, 3);
    std::vector<double> copy;
    const double *p = aligned_data(points.data(), 3 * n, copy);
    BuildOptions opt{leaf_size, box_depth, threads, wide};
    Progress progress;
    return run_with_progress(progress, poll_or_ambient(poll), [&](Progress &pr) {
        auto build = std::make_unique<SurfelTreeBuild>(p, n, origin.data(), opt);
        pr.check();
        return build;
    });
}

/// Stage 2: the surfels from normals, radii and colours.
void tree_build_add_surfels(SurfelTreeBuild &b, CArray<float> normals, CArray<float> radii,
                            std::optional<CArray<float>> colors, nb::object poll) {
    size_t n = b.size();
    check_rows("normals", normals.ndim(), normals.shape(0), normals.ndim() > 1 ? normals.shape(1) : 0, n, 3);
    check_rows("radii", radii.ndim(), radii.shape(0), 0, n, 0);
    SurfelCopies keep;
    const float *nn = aligned_data(normals.data(), 3 * n, keep.normals);
    const float *rr = aligned_data(radii.data(), n, keep.radii);
    const float *cc = nullptr;
    if (colors) {
        check_rows("colors", colors->ndim(), colors->shape(0), colors->ndim() > 1 ? colors->shape(1) : 0, n, 3);
        cc = aligned_data(colors->data(), 3 * n, keep.colors);
    }
    Progress progress;
    run_with_progress(progress, poll_or_ambient(poll), [&](Progress &pr) {
        b.add_surfels(nn, rr, cc);
        pr.check();
    });
}

/// Stage 3: the nodes; the finished tree.
std::unique_ptr<SurfelTree> tree_build_finish(SurfelTreeBuild &b, nb::object poll) {
    Progress progress;
    return run_with_progress(progress, poll_or_ambient(poll), [&](Progress &pr) {
        auto tree = std::make_unique<SurfelTree>(b.finish());
        pr.check();
        return tree;
    });
}

template <class T, class Tree>
nb::tuple cast_binding(const Tree &t, CArray<T> rays, const TraceOptions &opt,
                       float pixel_angle, int threads, bool want_stats) {
    size_t n = rays.shape(0);
    check_rows("rays", rays.ndim(), n, rays.ndim() > 1 ? rays.shape(1) : 0, n, 6);
    CastOutput out;
    auto at = new_array<float>({n}, &out.t);
    auto an = new_array<float>({n, 3}, &out.normal);
    auto ac = new_array<float>({n, 3}, &out.color);
    auto ar = new_array<float>({n}, &out.radius);
    auto ai = new_array<int32_t>({n}, &out.index);
    auto acnt = new_array<uint8_t>({n}, &out.count);
    auto ap = new_array<double>({n, 3}, &out.position);
    BatchStats st;
    {
        nb::gil_scoped_release release;
        std::vector<T> rays_copy;
        cast_rays(t, aligned_data(rays.data(), 6 * n, rays_copy), n, opt, pixel_angle, threads, out,
                  want_stats, st);
    }
    check_invalid(st, "rays have NaN/inf values or a zero direction (length outside [1e-30, 1e30])");
    nb::dict d;
    d["t_hit"] = at; d["normals"] = an; d["colors"] = ac; d["radii"] = ar;
    d["index"] = ai; d["count"] = acnt; d["positions"] = ap;
    return nb::make_tuple(d, stats_dict(st));
}

template <class T, class Tree>
nb::tuple occluded_binding(const Tree &t, CArray<T> rays, CArray<float> t_max,
                           const TraceOptions &opt, float t_min, float pixel_angle, int threads,
                           bool want_stats) {
    size_t n = rays.shape(0);
    check_rows("rays", rays.ndim(), n, rays.ndim() > 1 ? rays.shape(1) : 0, n, 6);
    check_rows("t_max", t_max.ndim(), t_max.shape(0), 0, n, 0);
    uint8_t *hit;
    auto ah = new_array<uint8_t>({n}, &hit);
    BatchStats st;
    {
        nb::gil_scoped_release release;
        std::vector<T> rays_copy;
        std::vector<float> t_max_copy;
        occluded(t, aligned_data(rays.data(), 6 * n, rays_copy), aligned_data(t_max.data(), n, t_max_copy),
                 n, opt, t_min, pixel_angle, threads, hit,
                 want_stats, st);
    }
    check_invalid(st, "rays have NaN/inf values, a zero direction or a NaN t_max");
    return nb::make_tuple(ah, stats_dict(st));
}

// Dispatch on the rays' dtype here: nanobind overloads would let a float64 array be converted to
// float32 when another argument needs a conversion pass, silently losing the precision that
// georeferenced rays need.
template <class Tree>
nb::tuple cast_any(const Tree &t, AnyArray rays, const TraceOptions &opt, double pixel_angle,
                   int threads, bool want_stats) {
    if (rays.dtype() == nb::dtype<float>())
        return cast_binding<float>(t, nb::cast<CArray<float>>(nb::cast(rays)), opt,
                                   float(pixel_angle), threads, want_stats);
    if (rays.dtype() == nb::dtype<double>())
        return cast_binding<double>(t, nb::cast<CArray<double>>(nb::cast(rays)), opt,
                                    float(pixel_angle), threads, want_stats);
    throw nb::type_error("rays: expected a float32 or float64 array");
}

template <class Tree>
nb::tuple occluded_any(const Tree &t, AnyArray rays, CArray<float> t_max, const TraceOptions &opt,
                       double t_min, double pixel_angle, int threads, bool want_stats) {
    if (rays.dtype() == nb::dtype<float>())
        return occluded_binding<float>(t, nb::cast<CArray<float>>(nb::cast(rays)), t_max, opt,
                                       float(t_min), float(pixel_angle), threads, want_stats);
    if (rays.dtype() == nb::dtype<double>())
        return occluded_binding<double>(t, nb::cast<CArray<double>>(nb::cast(rays)), t_max, opt,
                                        float(t_min), float(pixel_angle), threads, want_stats);
    throw nb::type_error("rays: expected a float32 or float64 array");
}

/// The conventional KD-tree. The build runs with the GIL released and polls `progress`
/// (see kdtree.h), so the cancellation helper can run it as one call taking a Progress&.
std::unique_ptr<KdTree> build_kdtree(const SurfelArrays &in, std::array<double, 3> origin,
                                     const KdBuildOptions &opt, Progress &progress) {
    nb::gil_scoped_release release;
    return std::make_unique<KdTree>(in, origin.data(), opt, &progress);
}

std::unique_ptr<KdTree> make_kdtree(CArray<double> points, CArray<float> normals,
                                    CArray<float> radii, std::optional<CArray<float>> colors,
                                    std::array<double, 3> origin, float intersect_cost,
                                    float empty_bonus, uint32_t max_leaf, uint32_t max_depth) {
    SurfelCopies keep;
    SurfelArrays in = surfel_arrays(points, normals, radii, colors, keep);
    if (!(intersect_cost > 0.f) || !(empty_bonus >= 0.f && empty_bonus < 1.f) || max_leaf < 1)
        throw nb::value_error("KdTree: intersect_cost must be > 0, empty_bonus in [0, 1), max_leaf >= 1");
    Progress progress;
    return build_kdtree(in, origin, KdBuildOptions{intersect_cost, empty_bonus, max_leaf, max_depth},
                        progress);
}

/// A render scene plus the Python objects its geometries depend on.
struct PyRenderScene {
    RenderScene scene;
    std::vector<nb::object> keep_alive;
    std::vector<PyGeometry *> callbacks;
    std::vector<std::shared_ptr<SurfelGeometry>> surfel_trees;   ///< for set_budget_scale
};

/// Renders on a worker thread (run_with_progress): `poll(tiles_done, tiles_total)` reports
/// progress and returns False to cancel. A cancelled render raises pointviz.CancelledError.
nb::object run_render(PyRenderScene &ps, const CameraModel &cam, const RenderSettings &set,
                      nb::object poll, int nice) {
    auto fb = std::make_unique<FrameBuffers>();
    RenderStats st;
    Progress progress;
    auto t0 = std::chrono::steady_clock::now();
    for (PyGeometry *g : ps.callbacks) g->set_cancel(&progress.cancel);
    struct Detach {  // the geometries outlive this call: drop the pointer to `progress`
        PyRenderScene &ps;
        ~Detach() { for (PyGeometry *g : ps.callbacks) g->set_cancel(nullptr); }
    } detach{ps};
    run_with_progress(progress, poll, [&](Progress &p) {
        if (render(ps.scene, cam, set, *fb, st, p)) return;
        for (PyGeometry *g : ps.callbacks)  // a failed callback cancels the render: say why
            if (!g->error().empty()) throw std::runtime_error("geometry callback failed: " + g->error());
        throw Cancelled();
    }, RunOptions{nice});
    double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    nb::dict d;
    d["seconds"] = secs;
    d["primary_rays"] = st.primary.load();
    d["shadow_rays"] = st.shadow.load();
    d["reflection_rays"] = st.reflection.load();
    d["primary_traced"] = st.primary_traced.load();
    d["shadow_traced"] = st.shadow_traced.load();
    d["reflection_traced"] = st.reflection_traced.load();
    d["primary_background"] = st.background.load();
    nb::dict phases;   // CPU time summed over the workers (zeros unless phase_times)
    phases["primary"] = 1e-9 * double(st.ns.primary.load());
    phases["reflection"] = 1e-9 * double(st.ns.reflection.load());
    phases["shadow"] = 1e-9 * double(st.ns.shadow.load());
    phases["shading"] = 1e-9 * double(st.ns.shading.load());
    phases["tile"] = 1e-9 * double(st.ns.tile.load());
    d["phase_seconds"] = phases;
    d["tiles_done"] = st.tiles_done.load();
    d["tiles_total"] = st.tiles_total;
    size_t h = size_t(cam.height), w = size_t(cam.width);
    nb::dict bufs;
    // the arrays take the buffers over (no copy: a frame's buffers are 48 bytes a pixel)
    auto put = [&](const char *name, std::vector<float> &src, size_t channels) {
        auto *owned = new std::vector<float>(std::move(src));
        nb::capsule owner(owned, [](void *p) noexcept { delete static_cast<std::vector<float> *>(p); });
        const size_t shape[3] = {h, w, channels};
        bufs[name] = nb::ndarray<nb::numpy, float>(owned->data(), channels > 1 ? 3 : 2, shape, owner);
    };
    put("color", fb->color, 3);
    put("depth", fb->depth, 1);
    put("normal", fb->normal, 3);
    put("alpha", fb->alpha, 1);
    put("albedo", fb->albedo, 3);
    put("object_alpha", fb->object_alpha, 1);
    return nb::make_tuple(bufs, d);
}


// ---- preprocessing (raw points to surfels) -------------------------------------------------

/// Borrowed views of a cloud's arrays; viewpoints (1 or n rows) and scan groups optional.
PointsView points_view(const CArray<double> &points, const std::optional<CArray<double>> &viewpoints,
                       const std::optional<CArray<int32_t>> &group) {
    PointsView v;
    v.n = points.shape(0);
    check_rows("points", points.ndim(), v.n, points.ndim() > 1 ? points.shape(1) : 0, v.n, 3);
    v.points = points.data();
    if (viewpoints) {
        size_t m = viewpoints->ndim() == 1 ? 1 : viewpoints->shape(0);
        if (viewpoints->ndim() == 1)
            check_rows("viewpoints", 1, viewpoints->shape(0), 0, 3, 0);
        else
            check_rows("viewpoints", viewpoints->ndim(), m, viewpoints->shape(1), v.n == 1 ? 1 : m, 3);
        if (m != 1 && m != v.n) throw nb::value_error("viewpoints: wrong shape");
        v.viewpoints = viewpoints->data();
        v.n_viewpoints = m;
    }
    if (group) {
        check_rows("scan_index", group->ndim(), group->shape(0), 0, v.n, 0);
        v.group = group->data();
    }
    return v;
}

/// Adds the (n, 2) grid cells of the points (scan_neighbours.h) to a view that has scans.
void add_scan_grid(PointsView &v, const std::optional<CArray<int32_t>> &grid) {
    if (!grid) return;
    check_rows("scan_grid", grid->ndim(), grid->shape(0), grid->ndim() > 1 ? grid->shape(1) : 0,
               v.n, 2);
    if (!v.group) throw nb::value_error("scan_grid: needs scan_index");
    v.cell = grid->data();
}

void check_normals(const CArray<float> &normals, size_t n) {
    check_rows("normals", normals.ndim(), normals.shape(0),
               normals.ndim() > 1 ? normals.shape(1) : 0, n, 3);
}

/// Runs one preprocessing step on a worker thread with the GIL released, polling the ambient
/// cancel token (pointviz.interrupt.poll) every few ms: Ctrl-C in the CLI, or a token set in
/// `cancel_scope`, stops the step at its next check with CancelledError.
template <class Fn>
auto run_step(Fn &&fn) {
    Progress progress;
    return run_with_progress(progress, poll_or_ambient(nb::none()), fn);
}

template <class T, class A>
nb::ndarray<nb::numpy, T> to_array(const std::vector<T, A> &v, std::initializer_list<size_t> shape) {
    T *d;
    auto a = new_array<T>(shape, &d);
    std::copy(v.begin(), v.end(), d);
    return a;
}

nb::dict normals_dict(const NormalsOutput &o, size_t n) {
    nb::dict d;
    d["normals"] = to_array(o.est.normals, {n, 3});
    d["support"] = to_array(o.est.support, {n});
    d["spread"] = to_array(o.est.spread, {n});
    d["borrowed"] = o.est.borrowed;
    d["arbitrary"] = o.est.arbitrary;
    d["components"] = o.orient.components;
    d["steep"] = o.orient.steep;
    d["unreached"] = o.orient.unreached;
    d["grid_neighbours"] = o.grid.from_grid;
    d["view_grid_neighbours"] = o.grid.from_view;
    d["tree_neighbours"] = o.grid.from_tree;
    return d;
}

NormalOptions normal_options(uint32_t k_min, uint32_t k_max, double confidence, int threads) {
    NormalOptions o;
    o.k_min = k_min;
    o.k_max = k_max;
    o.confidence = confidence;
    o.threads = threads;
    return o;
}

/// The non-surface and sparse bounds of the radii (CoverOptions): (band, surface fraction,
/// volume fraction, factor, typical cap); a factor and cap of 0 turn them off.
using VolumeArgs = std::array<double, 5>;

CoverOptions cover_options(uint32_t directions, double margin, double cap, double global_cap,
                           int threads, const VolumeArgs &volume = {0, 0, 0, 0, 0}) {
    CoverOptions o{directions, margin, cap, global_cap, threads};  // (in field order)
    o.volume_band = volume[0];
    o.volume_surface = volume[1];
    o.volume_volume = volume[2];
    o.volume_factor = volume[3];
    o.typical_cap = volume[4];
    return o;
}

/// Orientation settings: neighbours linked, the edge-length weight, the undecided margin.
using OrientArgs = std::tuple<uint32_t, double, double>;

OrientOptions orient_options(const OrientArgs &args, std::optional<std::array<double, 3>> up,
                             double above_steep = 0) {
    OrientOptions o;
    if (above_steep > 0) o.from_above = true, o.steep = above_steep;
    o.k = std::get<0>(args);
    o.distance_weight = std::get<1>(args);
    o.undecided_margin = std::get<2>(args);
    if (up) {
        o.has_up = true;
        for (int a = 0; a < 3; ++a) o.up[a] = (*up)[a];
    }
    return o;
}
}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "pointviz C++ core: surfel hierarchy, traversal and rendering";
    // the error of a frame in which nothing stops (lod.h), for the budget's share in Python
    m.attr("BUDGET_FLOOR") = double(kBudgetFloor);
    // the predictor's terms per unit feature and its size cap (lod.h), for the benchmarks' copies
    m.attr("SPREAD_TERM") = double(kBudgetScale * kSpreadWeight);
    m.attr("COLOUR_TERM") = double(kBudgetScale * kColourWeight);
    m.attr("BUDGET_MAX_EXTENT") = double(kBudgetMaxExtent);

    // pointviz::Cancelled (a core call stopped by its Progress) -> pointviz.CancelledError.
    nb::register_exception_translator([](const std::exception_ptr &p, void *) {
        try {
            std::rethrow_exception(p);
        } catch (const Cancelled &e) {
            nb::object cls = nb::module_::import_("pointviz.errors").attr("CancelledError");
            PyErr_SetString(cls.ptr(), e.what());
        }
    });

    nb::enum_<Interpolation>(m, "Interpolation")
        .value("none", Interpolation::None)
        .value("paper", Interpolation::Paper)
        .value("smooth", Interpolation::Smooth);

    nb::enum_<Isa>(m, "Isa")
        .value("auto", Isa::Auto)
        .value("base", Isa::Base)
        .value("sse42", Isa::Sse42)
        .value("avx2", Isa::Avx2)
        .value("avx512", Isa::Avx512);
    m.def("isa_available", &isa_available, "isa"_a);
    m.def("best_isa", &best_isa);

    nb::enum_<LodCriterion>(m, "LodCriterion")
        .value("size", LodCriterion::Size)
        .value("deviation", LodCriterion::Deviation)
        .value("budget", LodCriterion::Budget);

    nb::class_<TraceOptions>(m, "TraceOptions")
        .def(nb::init<>())
        .def_rw("lod", &TraceOptions::lod)
        .def_rw("lod_pixels", &TraceOptions::lod_pixels)
        .def_rw("cull", &TraceOptions::cull)
        .def_rw("box_depth", &TraceOptions::box_depth)
        .def_rw("interpolation", &TraceOptions::interp)
        .def_rw("window", &TraceOptions::window)
        .def_rw("slabs", &TraceOptions::slabs)
        .def_rw("lod_criterion", &TraceOptions::lod_criterion)
        .def_rw("lod_max_extent", &TraceOptions::lod_max_extent)
        .def_rw("max_error", &TraceOptions::max_error)
        .def_rw("shadow_flip_weight", &TraceOptions::shadow_flip_weight)
        .def_rw("sky_flip_weight", &TraceOptions::sky_flip_weight)
        .def_rw("colour_pixel_response", &TraceOptions::colour_pixel_response)
        .def_rw("budget_scale", &TraceOptions::budget_scale)
        .def_rw("isa", &TraceOptions::isa)
        .def_rw("wide", &TraceOptions::wide)
        .def_rw("packets", &TraceOptions::packets);

    nb::class_<CameraModel>(m, "CameraModel")
        .def(nb::init<>())
        .def_rw("eye", &CameraModel::eye)
        .def_rw("forward", &CameraModel::forward)
        .def_rw("right", &CameraModel::right)
        .def_rw("up", &CameraModel::up)
        .def_rw("tan_half", &CameraModel::tan_half)
        .def_rw("width", &CameraModel::width)
        .def_rw("height", &CameraModel::height)
        .def_prop_ro("pixel_angle", &CameraModel::pixel_angle)
        .def("direction", &CameraModel::direction, "col"_a, "row"_a,
             "Unit direction of the primary ray through continuous pixel (col, row) (the "
             "renderer's ray model; pointviz.Camera.rays is tested against it).");

    nb::class_<Material>(m, "Material")
        .def(nb::init<>())
        .def_rw("base_color", &Material::base_color)
        .def_rw("use_point_colors", &Material::use_point_colors)
        .def_rw("diffuse", &Material::diffuse)
        .def_rw("specular", &Material::specular)
        .def_rw("shininess", &Material::shininess)
        .def_rw("mirror", &Material::mirror)
        .def_rw("roughness", &Material::roughness)
        .def_rw("checker", &Material::checker)
        .def_rw("checker_size", &Material::checker_size);

    nb::enum_<LightType>(m, "LightType")
        .value("directional", LightType::Directional)
        .value("point", LightType::Point)
        .value("area", LightType::Area);

    nb::class_<Light>(m, "Light")
        .def(nb::init<>())
        .def_rw("type", &Light::type)
        .def_rw("color", &Light::color)
        .def_rw("direction", &Light::direction)
        .def_rw("angle", &Light::angle)
        .def_rw("position", &Light::position)
        .def_rw("radius", &Light::radius)
        .def_rw("edge_u", &Light::edge_u)
        .def_rw("edge_v", &Light::edge_v)
        .def_rw("cast_shadows", &Light::cast_shadows);

    nb::class_<Sky>(m, "Sky")
        .def(nb::init<>())
        .def_rw("zenith", &Sky::zenith)
        .def_rw("horizon", &Sky::horizon)
        .def_rw("below", &Sky::below)
        .def_rw("up", &Sky::up)
        .def_rw("ambient", &Sky::ambient)
        .def_rw("background_is_sky", &Sky::background_is_sky)
        .def_rw("background", &Sky::background)
        .def_rw("occlusion_distance", &Sky::occlusion_distance)
        .def_rw("ground_fade", &Sky::ground_fade);

    nb::class_<RenderSettings>(m, "RenderSettings")
        .def(nb::init<>())
        .def_rw("spp", &RenderSettings::spp)
        .def_rw("reflections", &RenderSettings::reflections)
        .def_rw("shadows", &RenderSettings::shadows)
        .def_rw("lod_pixels", &RenderSettings::lod_pixels)
        .def_rw("footprint_offsets", &RenderSettings::footprint_offsets)
        .def_rw("seed", &RenderSettings::seed)
        .def_rw("sample_offset", &RenderSettings::sample_offset)
        .def_rw("sequence_spp", &RenderSettings::sequence_spp)
        .def_rw("threads", &RenderSettings::threads)
        .def_rw("tile", &RenderSettings::tile)
        .def_rw("occlusion_rays", &RenderSettings::occlusion_rays)
        .def_rw("phase_times", &RenderSettings::phase_times)
        .def_rw("background_shortcut", &RenderSettings::background_shortcut)
        .def_prop_rw("normal_offset", [](const RenderSettings &s) { return s.offsets.normal_offset; },
                     [](RenderSettings &s, float v) { s.offsets.normal_offset = v; })
        .def_prop_rw("offset_tmin", [](const RenderSettings &s) { return s.offsets.tmin; },
                     [](RenderSettings &s, float v) { s.offsets.tmin = v; });

    nb::class_<PyRenderScene>(m, "RenderScene")
        .def(nb::init<>())
        .def("add_surfels", [](PyRenderScene &s, nb::object tree_obj, const TraceOptions &opt,
                               Vec3 offset, const Material &mat) {
            s.keep_alive.push_back(tree_obj);
            std::shared_ptr<Geometry> g;
            if (nb::isinstance<KdTree>(tree_obj))
                g = std::make_shared<KdGeometry>(nb::cast<const KdTree *>(tree_obj), opt, offset);
            else {
                auto sg = std::make_shared<SurfelGeometry>(nb::cast<const SurfelTree *>(tree_obj), opt, offset);
                s.surfel_trees.push_back(sg);
                g = sg;
            }
            s.scene.objects.push_back({g, mat});
        }, "tree"_a, "options"_a, "offset"_a, "material"_a)
        .def("set_budget_scale", [](PyRenderScene &s, float scale) {
            for (auto &g : s.surfel_trees) g->set_budget_scale(scale);
        }, "scale"_a)
        .def("add_callback", [](PyRenderScene &s, nb::object obj, const Material &mat) {
            auto g = std::make_shared<PyGeometry>(obj);
            s.callbacks.push_back(g.get());
            s.scene.objects.push_back({g, mat});
        }, "geometry"_a, "material"_a)
        .def("set_ground", [](PyRenderScene &s, Vec3 point, Vec3 normal, const Material &mat) {
            s.scene.ground = true;
            s.scene.ground_point = point;
            s.scene.ground_normal = normalize(normal);
            s.scene.ground_material = mat;
        }, "point"_a, "normal"_a, "material"_a)
        .def("add_light", [](PyRenderScene &s, const Light &l) {
            Light c = l;
            c.direction = normalize(c.direction);
            s.scene.lights.push_back(c);
        }, "light"_a)
        .def_prop_rw("sky", [](const PyRenderScene &s) { return s.scene.sky; },
                     [](PyRenderScene &s, const Sky &k) { s.scene.sky = k; s.scene.sky.up = normalize(k.up); })
        .def_prop_rw("scale", [](const PyRenderScene &s) { return s.scene.scale; },
                     [](PyRenderScene &s, float v) { s.scene.scale = v; })
        .def_prop_ro("n_objects", [](const PyRenderScene &s) { return s.scene.objects.size(); });

    m.def("render", &run_render, "scene"_a, "camera"_a, "settings"_a, "poll"_a.none(),
          "nice"_a = 0);

    nb::class_<SurfelTreeBuild>(m, "SurfelTreeBuild")
        .def(nb::new_(&make_tree_build), "points"_a, "origin"_a, "leaf_size"_a = 8,
             "box_depth"_a = 0, "threads"_a = 0, "wide"_a = true, "poll"_a.none() = nb::none())
        .def("add_surfels", &tree_build_add_surfels, "normals"_a, "radii"_a, "colors"_a.none(),
             "poll"_a.none() = nb::none())
        .def("finish", &tree_build_finish, "poll"_a.none() = nb::none())
        .def_prop_ro("next_stage", &SurfelTreeBuild::next_stage)
        .def_prop_ro("n_surfels", &SurfelTreeBuild::size);

    nb::class_<SurfelTree>(m, "SurfelTree")
        .def(nb::new_(&make_tree), "points"_a, "normals"_a, "radii"_a, "colors"_a.none(),
             "origin"_a, "leaf_size"_a = 8, "box_depth"_a = 0, "threads"_a = 0, "wide"_a = true,
             "poll"_a.none() = nb::none())
        .def_prop_ro("memory_bytes", &SurfelTree::memory_bytes)
        .def_prop_ro("wide_memory_bytes", [](const SurfelTree &t) { return t.wide().memory_bytes(); })
        .def_prop_ro("build_seconds", &SurfelTree::build_seconds)
        .def_prop_ro("depth", &SurfelTree::depth)
        .def_prop_ro("box_depth", &SurfelTree::box_depth)
        .def_prop_ro("n_nodes", [](const SurfelTree &t) { return t.nodes().size(); })
        .def_prop_ro("n_surfels", [](const SurfelTree &t) { return t.surfels().size(); })
        .def_prop_ro("level_start", &SurfelTree::level_start)
        .def_prop_ro("origin", [](const SurfelTree &t) -> std::array<double, 3> {
            return {t.origin()[0], t.origin()[1], t.origin()[2]};
        })
        .def("surfel_view", [](nb::handle self) {
            // The stored surfels without a copy, (n, 8) float32 rows: centre (local frame),
            // radius, normal, and the packed colour's bits; read-only, alive with the tree.
            const SurfelTree &t = nb::cast<const SurfelTree &>(self);
            size_t shape[2] = {t.surfels().size(), 8};
            return nb::ndarray<nb::numpy, const float, nb::ndim<2>>(
                reinterpret_cast<const float *>(t.surfels().data()), 2, shape, self);
        })
        .def("root_sphere", [](const SurfelTree &t) {
            // The root node's bounding sphere: centre (the tree's local frame) and radius.
            const Node &r = t.nodes().at(0);
            return std::make_tuple(r.c.x, r.c.y, r.c.z, r.radius);
        })
        .def("node_arrays", [](const SurfelTree &t) {
            // Decoded copies of the node fields, for tests and diagnostics.
            size_t n = t.nodes().size();
            float *c, *r, *nn, *cone, *cspread, *pred;
            uint32_t *cnt, *idx;
            auto ac = new_array<float>({n, 3}, &c);
            auto ar = new_array<float>({n}, &r);
            auto an = new_array<float>({n, 3}, &nn);
            auto acone = new_array<float>({n}, &cone);
            auto acs = new_array<float>({n}, &cspread);
            auto apred = new_array<float>({n}, &pred);
            auto acnt = new_array<uint32_t>({n}, &cnt);
            auto aidx = new_array<uint32_t>({n}, &idx);
            for (size_t i = 0; i < n; ++i) {
                const Node &nd = t.nodes()[i];
                Vec3 a = normalize(nd.axis());
                for (int k = 0; k < 3; ++k) c[3 * i + k] = nd.c[k], nn[3 * i + k] = a[k];
                r[i] = nd.radius;
                cone[i] = nd.cone();
                cspread[i] = nd.colour_spread();
                pred[i] = nd.has_cone() ? predicted_error(nd) : std::numeric_limits<float>::infinity();
                cnt[i] = nd.count();
                idx[i] = nd.index();
            }
            size_t nb_ = t.boxes().size();
            float *bx;
            auto abx = new_array<float>({nb_, 6}, &bx);
            for (size_t i = 0; i < nb_; ++i)
                for (int k = 0; k < 3; ++k)
                    bx[6 * i + k] = t.boxes()[i].lo[k], bx[6 * i + 3 + k] = t.boxes()[i].hi[k];
            uint32_t *ord;
            auto aord = new_array<uint32_t>({t.order().size()}, &ord);
            std::copy(t.order().begin(), t.order().end(), ord);
            nb::dict d;
            d["center"] = ac; d["radius"] = ar; d["normal"] = an; d["cone"] = acone;
            d["colour_spread"] = acs; d["predicted_error"] = apred;
            d["count"] = acnt; d["index"] = aidx; d["boxes"] = abx; d["order"] = aord;
            return d;
        })
        // One entry point per query, dispatching on the rays' dtype (see cast_any).
        .def("cast", &cast_any<SurfelTree>, "rays"_a, "options"_a, "pixel_angle"_a = 0.0,
             "threads"_a = 0, "stats"_a = true)
        .def("occluded", &occluded_any<SurfelTree>, "rays"_a, "t_max"_a, "options"_a,
             "t_min"_a = 0.0, "pixel_angle"_a = 0.0, "threads"_a = 0, "stats"_a = true);

    // ---- the conventional KD-tree (kdtree.h): the paper's baseline ----------------------------
    nb::class_<KdTree>(m, "KdTree")
        .def(nb::new_(&make_kdtree), "points"_a, "normals"_a, "radii"_a, "colors"_a.none(),
             "origin"_a, "intersect_cost"_a = KdBuildOptions{}.intersect_cost,
             "empty_bonus"_a = KdBuildOptions{}.empty_bonus, "max_leaf"_a = KdBuildOptions{}.max_leaf,
             "max_depth"_a = 0)
        .def_prop_ro("memory_bytes", &KdTree::memory_bytes)
        .def_prop_ro("build_seconds", &KdTree::build_seconds)
        .def_prop_ro("depth", &KdTree::depth)
        .def_prop_ro("box_depth", [](const KdTree &) { return 0u; })
        .def_prop_ro("n_nodes", [](const KdTree &t) { return t.nodes().size(); })
        .def_prop_ro("n_surfels", &KdTree::n_surfels)
        .def_prop_ro("n_references", [](const KdTree &t) { return t.slots().size(); })
        .def_prop_ro("n_leaves", [](const KdTree &t) {
            return size_t(std::count_if(t.nodes().begin(), t.nodes().end(),
                                        [](const KdNode &nd) { return nd.is_leaf(); }));
        })
        .def_prop_ro("origin", [](const KdTree &t) -> std::array<double, 3> {
            return {t.origin()[0], t.origin()[1], t.origin()[2]};
        })
        .def("cast", &cast_any<KdTree>, "rays"_a, "options"_a, "pixel_angle"_a = 0.0,
             "threads"_a = 0, "stats"_a = true)
        .def("occluded", &occluded_any<KdTree>, "rays"_a, "t_max"_a, "options"_a,
             "t_min"_a = 0.0, "pixel_angle"_a = 0.0, "threads"_a = 0, "stats"_a = true);

    pointviz_bindings::bind_readers(m);

    // ---- preprocessing: one function per step, each run with the GIL released ----------------
    nb::register_exception_translator([](const std::exception_ptr &p, void *) {
        try {
            std::rethrow_exception(p);
        } catch (const Cancelled &e) {
            nb::object cls = nb::module_::import_("pointviz.errors").attr("CancelledError");
            PyErr_SetString(cls.ptr(), e.what());
        }
    });

    m.def("knn", [](CArray<double> points, uint32_t k, int threads) {
        PointsView v = points_view(points, std::nullopt, std::nullopt);
        KnnOutput o = run_step([&](Progress &pr) { return knn_points(v, k, threads, pr); });
        size_t n = o.table.n, kk = o.table.k;
        return nb::make_tuple(to_array(o.dist, {n, kk}), to_array(o.table.index, {n, kk}));
    }, "points"_a, "k"_a, "threads"_a = 0,
       "(dist (n, k) float64, index (n, k) uint32): k nearest neighbours, the point excluded");

    m.def("nearest", [](CArray<double> points, CArray<double> queries, int threads) {
        PointsView v = points_view(points, std::nullopt, std::nullopt);
        if (queries.ndim() != 2 || queries.shape(1) != 3)
            throw std::invalid_argument("queries: expected shape (m, 3)");
        if (v.n == 0) throw std::invalid_argument("points: no point to be nearest to");
        const size_t m = queries.shape(0);
        NearestOutput o = run_step([&](Progress &pr) {
            return nearest_points(v, queries.data(), m, threads, pr);
        });
        return nb::make_tuple(to_array(o.dist, {m}), to_array(o.index, {m}));
    }, "points"_a, "queries"_a, "threads"_a = 0,
       "(dist (m,) float64, index (m,) uint32): the nearest of `points` to each query");

    m.def("estimate_normals", [](CArray<double> points, std::optional<CArray<double>> viewpoints,
                                 std::optional<CArray<int32_t>> scan_index,
                                 std::optional<std::array<double, 3>> up, uint32_t k_min,
                                 uint32_t k_max, double confidence, OrientArgs orient, int threads,
                                 std::optional<CArray<int32_t>> scan_grid, double above,
                                 uint32_t cover_k, uint32_t directions, double margin, double cap,
                                 double global_cap, VolumeArgs volume) {
        PointsView v = points_view(points, viewpoints, scan_index);
        add_scan_grid(v, scan_grid);
        NormalOptions no = normal_options(k_min, k_max, confidence, threads);
        OrientOptions oo = orient_options(orient, up, above);
        CoverOptions co = cover_options(directions, margin, cap, global_cap, threads, volume);
        NormalsOutput o = run_step([&](Progress &pr) {
            return normals_points(v, no, oo, pr, cover_k ? &co : nullptr, cover_k);
        });
        nb::dict d = normals_dict(o, v.n);
        if (!o.radii.empty()) d["radii"] = to_array(o.radii, {v.n});
        return d;
    }, "points"_a, "viewpoints"_a.none(), "scan_index"_a.none(), "up"_a.none(), "k_min"_a,
       "k_max"_a, "confidence"_a, "orient"_a, "threads"_a = 0, "scan_grid"_a.none() = nb::none(),
       "above"_a = 0.0, "cover_k"_a = 0, "directions"_a = CoverOptions{}.directions,
       "margin"_a = CoverOptions{}.margin, "cap"_a = CoverOptions{}.cap,
       "global_cap"_a = CoverOptions{}.global_cap, "volume"_a = VolumeArgs{0, 0, 0, 0, 0});

    m.def("orient_normals", [](CArray<double> points, CArray<float> normals,
                               std::optional<CArray<double>> viewpoints,
                               std::optional<std::array<double, 3>> up, OrientArgs orient,
                               int threads, double above) {
        PointsView v = points_view(points, viewpoints, std::nullopt);
        check_normals(normals, v.n);
        std::vector<float> out(normals.data(), normals.data() + 3 * v.n);
        OrientOptions oo = orient_options(orient, up, above);
        OrientResult r = run_step([&](Progress &pr) {
            return orient_points(v, out.data(), oo, threads, pr);
        });
        return nb::make_tuple(to_array(out, {v.n, 3}), r.components);
    }, "points"_a, "normals"_a, "viewpoints"_a.none(), "up"_a.none(), "orient"_a, "threads"_a = 0,
       "above"_a = 0.0);

    m.def("coverage_radii", [](CArray<double> points, CArray<float> normals, uint32_t k,
                               uint32_t directions, double margin, double cap, double global_cap,
                               int threads, VolumeArgs volume) {
        PointsView v = points_view(points, std::nullopt, std::nullopt);
        check_normals(normals, v.n);
        CoverOptions co = cover_options(directions, margin, cap, global_cap, threads, volume);
        std::vector<float> r = run_step([&](Progress &pr) {
            return radii_points(v, normals.data(), k, co, pr);
        });
        return to_array(r, {v.n});
    }, "points"_a, "normals"_a, "k"_a, "directions"_a, "margin"_a, "cap"_a, "global_cap"_a,
       "threads"_a = 0, "volume"_a = VolumeArgs{0, 0, 0, 0, 0});

    m.def("fit_surface", [](CArray<double> points, std::optional<CArray<float>> normals,
                            std::optional<CArray<double>> viewpoints,
                            std::optional<CArray<int32_t>> scan_index,
                            std::optional<std::array<double, 3>> up, uint32_t k_min, uint32_t k_max,
                            double confidence, OrientArgs orient, uint32_t min_support,
                            bool quadric, int passes, int robust_passes, double robust_width,
                            double thin, bool strays, int threads,
                            std::optional<CArray<int32_t>> scan_grid, uint32_t cover_k,
                            uint32_t directions, double margin, double cap, double global_cap,
                            double normal_growth) {
        PointsView v = points_view(points, viewpoints, scan_index);
        add_scan_grid(v, scan_grid);
        if (normals) check_normals(*normals, v.n);
        NormalOptions no = normal_options(k_min, k_max, confidence, threads);
        no.growth = normal_growth;
        OrientOptions oo = orient_options(orient, up);
        FitOptions fo;
        fo.min_support = min_support;
        fo.quadric = quadric;
        fo.passes = passes;
        fo.robust_passes = robust_passes;
        fo.robust_width = robust_width;
        fo.thin = thin;
        fo.threads = threads;
        const float *nrm = normals ? normals->data() : nullptr;
        StrayOptions so;
        so.threads = threads;
        CoverOptions co = cover_options(directions, margin, cap, global_cap, threads);
        FitOutput o = run_step([&](Progress &pr) {
            return fit_points(v, nrm, no, oo, fo, pr, strays ? &so : nullptr,
                              cover_k ? &co : nullptr, cover_k);
        });
        nb::dict d;
        d["points"] = to_array(o.fit.points, {v.n, 3});
        d["normals"] = to_array(o.fit.normals, {v.n, 3});
        d["keep"] = to_array(o.fit.keep, {v.n});
        d["shift"] = to_array(o.fit.shift, {v.n});
        d["spacing"] = to_array(o.fit.spacing, {v.n});
        d["median_spacing"] = o.median_spacing;
        if (cover_k) d["radii"] = to_array(o.radii, {v.n});
        d["radii_searched"] = o.radii_searched;
        d["kept"] = o.fit.kept;
        d["unmoved"] = o.fit.unmoved;
        d["stray"] = to_array(o.stray.stray, {o.stray.stray.size()});
        d["stray_points"] = o.stray.points;
        d["stray_clusters"] = o.stray.clusters;
        if (!nrm) d["estimate"] = normals_dict(o.normals, v.n);
        d["grid_neighbours"] = o.normals.grid.from_grid;
        d["view_grid_neighbours"] = o.normals.grid.from_view;
        d["tree_neighbours"] = o.normals.grid.from_tree;
        d["across_neighbours"] = o.normals.grid.from_across;
        return d;
    }, "points"_a, "normals"_a.none(), "viewpoints"_a.none(), "scan_index"_a.none(), "up"_a.none(),
       "k_min"_a, "k_max"_a, "confidence"_a, "orient"_a, "min_support"_a, "quadric"_a,
       "passes"_a, "robust_passes"_a, "robust_width"_a, "thin"_a, "strays"_a = true, "threads"_a = 0,
       "scan_grid"_a.none() = nb::none(), "cover_k"_a = 0, "directions"_a = CoverOptions{}.directions,
       "margin"_a = CoverOptions{}.margin, "cap"_a = CoverOptions{}.cap,
       "global_cap"_a = CoverOptions{}.global_cap, "normal_growth"_a = NormalOptions{}.growth);

    m.def("stray_clusters", [](CArray<double> points, std::optional<CArray<int32_t>> scan_index,
                               uint32_t k, double reach, uint32_t min_points, double fraction,
                               int threads) {
        PointsView v = points_view(points, std::nullopt, scan_index);
        StrayOptions so;
        so.reach = reach;
        so.min_points = min_points;
        so.fraction = fraction;
        so.threads = threads;
        StrayResult r = run_step([&](Progress &pr) { return stray_points(v, k, so, pr); });
        nb::dict d;
        d["stray"] = to_array(r.stray, {v.n});
        d["label"] = to_array(r.label, {v.n});
        d["components"] = r.components;
        d["points"] = r.points;
        d["clusters"] = r.clusters;
        return d;
    }, "points"_a, "scan_index"_a.none(), "k"_a, "reach"_a = StrayOptions{}.reach,
       "min_points"_a = StrayOptions{}.min_points, "fraction"_a = StrayOptions{}.fraction,
       "threads"_a = 0);

    m.def("depth_patch_planes", [](CArray<double> points, CArray<int32_t> grid,
                                   std::array<double, 3> viewpoint, CArray<double> step,
                                   bool edges, double slope_error, int noise_radius,
                                   int noise_sample, std::vector<int> radii,
                                   double residual_steps, double residual_sigmas,
                                   double move_steps, double edge_steps, double edge_sigmas,
                                   double edge_footprints, uint32_t small_segment, int threads) {
        size_t n = points.shape(0);
        check_rows("points", points.ndim(), n, points.ndim() > 1 ? points.shape(1) : 0, n, 3);
        check_rows("grid", grid.ndim(), grid.shape(0), grid.ndim() > 1 ? grid.shape(1) : 0, n, 2);
        check_rows("step", step.ndim(), step.shape(0), 0, n, 0);
        if (n == 0) throw nb::value_error("points: none");
        if (radii.empty() || radii.front() < 0 || !std::is_sorted(radii.begin(), radii.end()))
            throw nb::value_error("radii: expected ascending half-widths >= 0");
        const int32_t *g = grid.data();
        for (size_t i = 0; i < 2 * n; ++i)
            if (g[i] < 0) throw nb::value_error("grid: negative row or column");
        DepthPlaneOptions o;
        o.edges = edges;
        o.slope_error = slope_error;
        o.noise_radius = noise_radius;
        o.noise_sample = noise_sample;
        o.radii = radii;
        o.residual_steps = residual_steps;
        o.residual_sigmas = residual_sigmas;
        o.move_steps = move_steps;
        o.edge_steps = edge_steps;
        o.edge_sigmas = edge_sigmas;
        o.edge_footprints = edge_footprints;
        o.small_segment = small_segment;
        o.threads = threads;
        const double vp[3] = {viewpoint[0], viewpoint[1], viewpoint[2]};
        DepthPlaneResult r = run_step([&](Progress &pr) {
            return depth_patch_planes(points.data(), n, g, vp, step.data(), o, &pr);
        });
        nb::dict info;
        info["noise"] = r.noise;
        info["angle"] = r.angle;
        info["segments"] = r.segments;
        return nb::make_tuple(to_array(r.points, {n, 3}), to_array(r.normals, {n, 3}),
                              to_array(r.radius, {n}), to_array(r.flying, {n}), info);
    }, "points"_a, "grid"_a, "viewpoint"_a, "step"_a, "edges"_a, "slope_error"_a,
       "noise_radius"_a, "noise_sample"_a, "radii"_a, "residual_steps"_a, "residual_sigmas"_a,
       "move_steps"_a, "edge_steps"_a, "edge_sigmas"_a, "edge_footprints"_a, "small_segment"_a,
       "threads"_a = 0,
       "(points (n, 3) float64, normals (n, 3) float32, radius (n,) int64, flying (n,) uint8, "
       "info): planes over pixel patches of a depth-camera frame (depth_planes.h)");
}
