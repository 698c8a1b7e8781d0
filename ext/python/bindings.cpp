// pointviz._core — type conversion only: numpy arrays in, numpy arrays out. Every long call
// releases the GIL. The public API is the Python package that wraps this module.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/stl/optional.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/unique_ptr.h>

#include <array>
#include <optional>

#include <memory>

#include "pointviz/cast.h"
#include "pointviz/tree.h"

namespace nb = nanobind;
using namespace nb::literals;
using namespace pointviz;

namespace {

template <class T>
using CArray = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;

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

void check_rows(const char *name, size_t ndim, size_t rows, size_t cols, size_t want_rows,
                size_t want_cols) {
    if (ndim != (want_cols == 0 ? 1u : 2u) || (want_cols && cols != want_cols) ||
        (want_rows != size_t(-1) && rows != want_rows))
        throw nb::value_error((std::string(name) + ": wrong shape").c_str());
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

std::unique_ptr<SurfelTree> make_tree(CArray<double> points, CArray<float> normals,
                                      CArray<float> radii, std::optional<CArray<float>> colors,
                                      std::array<double, 3> origin, uint32_t leaf_size,
                                      uint32_t box_depth, int threads) {
    size_t n = points.shape(0);
    check_rows("points", points.ndim(), n, points.ndim() > 1 ? points.shape(1) : 0, n, 3);
    check_rows("normals", normals.ndim(), normals.shape(0), normals.ndim() > 1 ? normals.shape(1) : 0, n, 3);
    check_rows("radii", radii.ndim(), radii.shape(0), 0, n, 0);
    SurfelArrays in{points.data(), normals.data(), radii.data(), nullptr, n};
    if (colors) {
        check_rows("colors", colors->ndim(), colors->shape(0), colors->ndim() > 1 ? colors->shape(1) : 0, n, 3);
        in.colors = colors->data();
    }
    BuildOptions opt{leaf_size, box_depth, threads};
    nb::gil_scoped_release release;
    return std::make_unique<SurfelTree>(in, origin.data(), opt);
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "pointviz C++ core: surfel hierarchy, traversal and rendering";

    nb::enum_<Interpolation>(m, "Interpolation")
        .value("none", Interpolation::None)
        .value("paper", Interpolation::Paper)
        .value("smooth", Interpolation::Smooth);

    nb::class_<TraceOptions>(m, "TraceOptions")
        .def(nb::init<>())
        .def_rw("lod", &TraceOptions::lod)
        .def_rw("lod_pixels", &TraceOptions::lod_pixels)
        .def_rw("cull", &TraceOptions::cull)
        .def_rw("box_depth", &TraceOptions::box_depth)
        .def_rw("interpolation", &TraceOptions::interp)
        .def_rw("window", &TraceOptions::window);

    nb::class_<SurfelTree>(m, "SurfelTree")
        .def(nb::new_(&make_tree), "points"_a, "normals"_a, "radii"_a, "colors"_a.none(),
             "origin"_a, "leaf_size"_a = 8, "box_depth"_a = 0, "threads"_a = 0)
        .def_prop_ro("memory_bytes", &SurfelTree::memory_bytes)
        .def_prop_ro("build_seconds", &SurfelTree::build_seconds)
        .def_prop_ro("depth", &SurfelTree::depth)
        .def_prop_ro("box_depth", &SurfelTree::box_depth)
        .def_prop_ro("n_nodes", [](const SurfelTree &t) { return t.nodes().size(); })
        .def_prop_ro("n_surfels", [](const SurfelTree &t) { return t.surfels().size(); })
        .def_prop_ro("level_start", &SurfelTree::level_start)
        .def_prop_ro("origin", [](const SurfelTree &t) -> std::array<double, 3> {
            return {t.origin()[0], t.origin()[1], t.origin()[2]};
        })
        .def("node_arrays", [](const SurfelTree &t) {
            // Decoded copies of the node fields, for tests and diagnostics.
            size_t n = t.nodes().size();
            float *c, *r, *nn, *cone;
            uint32_t *cnt, *idx;
            auto ac = new_array<float>({n, 3}, &c);
            auto ar = new_array<float>({n}, &r);
            auto an = new_array<float>({n, 3}, &nn);
            auto acone = new_array<float>({n}, &cone);
            auto acnt = new_array<uint32_t>({n}, &cnt);
            auto aidx = new_array<uint32_t>({n}, &idx);
            for (size_t i = 0; i < n; ++i) {
                const Node &nd = t.nodes()[i];
                Vec3 a = oct_decode(nd.normal);
                for (int k = 0; k < 3; ++k) c[3 * i + k] = nd.c[k], nn[3 * i + k] = a[k];
                r[i] = nd.radius;
                cone[i] = nd.cone;
                cnt[i] = nd.count();
                idx[i] = nd.index;
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
            d["count"] = acnt; d["index"] = aidx; d["boxes"] = abx; d["order"] = aord;
            return d;
        })
        .def("cast", [](const SurfelTree &t, CArray<double> rays, const TraceOptions &opt,
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
            BatchStats st;
            {
                nb::gil_scoped_release release;
                cast_rays(t, rays.data(), n, opt, pixel_angle, threads, out, want_stats ? &st : nullptr);
            }
            nb::dict d;
            d["t_hit"] = at; d["normals"] = an; d["colors"] = ac; d["radii"] = ar;
            d["index"] = ai; d["count"] = acnt;
            return nb::make_tuple(d, stats_dict(st));
        }, "rays"_a, "options"_a, "pixel_angle"_a = 0.f, "threads"_a = 0, "stats"_a = true)
        .def("occluded", [](const SurfelTree &t, CArray<double> rays, CArray<float> t_max,
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
                occluded(t, rays.data(), t_max.data(), n, opt, t_min, pixel_angle, threads, hit,
                         want_stats ? &st : nullptr);
            }
            return nb::make_tuple(ah, stats_dict(st));
        }, "rays"_a, "t_max"_a, "options"_a, "t_min"_a = 0.f, "pixel_angle"_a = 0.f,
           "threads"_a = 0, "stats"_a = true);
}
