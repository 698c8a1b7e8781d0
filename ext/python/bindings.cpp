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

#include <chrono>
#include <thread>

#include "pointviz/cast.h"
#include "pointviz/dispatch.h"
#include "pointviz/render.h"
#include "pointviz/tree.h"
#include "pygeometry.h"

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

template <class T>
nb::tuple cast_binding(const SurfelTree &t, CArray<T> rays, const TraceOptions &opt,
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
        cast_rays(t, rays.data(), n, opt, pixel_angle, threads, out, want_stats, st);
    }
    check_invalid(st, "rays have NaN/inf values or a zero direction (length outside [1e-30, 1e30])");
    nb::dict d;
    d["t_hit"] = at; d["normals"] = an; d["colors"] = ac; d["radii"] = ar;
    d["index"] = ai; d["count"] = acnt; d["positions"] = ap;
    return nb::make_tuple(d, stats_dict(st));
}

template <class T>
nb::tuple occluded_binding(const SurfelTree &t, CArray<T> rays, CArray<float> t_max,
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
                 want_stats, st);
    }
    check_invalid(st, "rays have NaN/inf values, a zero direction or a NaN t_max");
    return nb::make_tuple(ah, stats_dict(st));
}

/// A render scene plus the Python objects its geometries depend on.
struct PyRenderScene {
    RenderScene scene;
    std::vector<nb::object> keep_alive;
    std::vector<PyGeometry *> callbacks;
};

/// Runs the renderer on a worker thread while this thread, holding the GIL only briefly,
/// reports progress and watches for cancellation (the poll callback returning False, an
/// exception in it, or Ctrl-C).
nb::object run_render(PyRenderScene &ps, const CameraModel &cam, const RenderSettings &set,
                      nb::object poll) {
    auto fb = std::make_unique<FrameBuffers>();
    RenderStats st;
    std::atomic<bool> cancel{false}, done{false};
    for (PyGeometry *g : ps.callbacks) g->set_cancel(&cancel);
    std::exception_ptr err;
    bool completed = false, interrupted = false;
    std::string poll_error;
    auto t0 = std::chrono::steady_clock::now();
    {
        nb::gil_scoped_release release;
        std::thread worker([&] {
            try {
                completed = render(ps.scene, cam, set, *fb, st, cancel);
            } catch (...) {
                err = std::current_exception();
                cancel = true;
            }
            done = true;
        });
        uint64_t reported = ~0ull;
        while (!done.load()) {
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
            uint64_t now = st.tiles_done.load();
            nb::gil_scoped_acquire gil;
            if (PyErr_CheckSignals() != 0) {
                PyErr_Clear();
                interrupted = true;
                cancel = true;
            }
            if (!poll.is_none() && now != reported && !cancel.load()) {
                reported = now;
                try {
                    nb::object r = poll(now, st.tiles_total);
                    if (!r.is_none() && !nb::cast<bool>(r)) cancel = true;
                } catch (const std::exception &e) {
                    poll_error = e.what();
                    cancel = true;
                }
            }
        }
        worker.join();
    }
    for (PyGeometry *g : ps.callbacks) g->set_cancel(nullptr);
    if (err) std::rethrow_exception(err);
    for (PyGeometry *g : ps.callbacks)
        if (!g->error().empty()) throw std::runtime_error("geometry callback failed: " + g->error());
    if (!poll_error.empty()) throw std::runtime_error("progress callback failed: " + poll_error);
    if (interrupted) {
        PyErr_SetNone(PyExc_KeyboardInterrupt);
        throw nb::python_error();
    }
    double secs = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    nb::dict d;
    d["completed"] = completed && !cancel.load();
    d["seconds"] = secs;
    d["primary_rays"] = st.primary.load();
    d["shadow_rays"] = st.shadow.load();
    d["reflection_rays"] = st.reflection.load();
    d["tiles_done"] = st.tiles_done.load();
    d["tiles_total"] = st.tiles_total;
    if (!d["completed"].equal(nb::bool_(true))) return nb::make_tuple(nb::none(), d);
    size_t h = size_t(cam.height), w = size_t(cam.width);
    float *c, *dep, *nn, *al;
    auto ac = new_array<float>({h, w, 3}, &c);
    auto ad = new_array<float>({h, w}, &dep);
    auto an = new_array<float>({h, w, 3}, &nn);
    auto aa = new_array<float>({h, w}, &al);
    std::copy(fb->color.begin(), fb->color.end(), c);
    std::copy(fb->depth.begin(), fb->depth.end(), dep);
    std::copy(fb->normal.begin(), fb->normal.end(), nn);
    std::copy(fb->alpha.begin(), fb->alpha.end(), al);
    nb::dict bufs;
    bufs["color"] = ac; bufs["depth"] = ad; bufs["normal"] = an; bufs["alpha"] = aa;
    return nb::make_tuple(bufs, d);
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "pointviz C++ core: surfel hierarchy, traversal and rendering";

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
        .value("deviation", LodCriterion::Deviation);

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
        .def_rw("wide", &TraceOptions::wide)
        .def_rw("isa", &TraceOptions::isa);

    nb::class_<CameraModel>(m, "CameraModel")
        .def(nb::init<>())
        .def_rw("eye", &CameraModel::eye)
        .def_rw("forward", &CameraModel::forward)
        .def_rw("right", &CameraModel::right)
        .def_rw("up", &CameraModel::up)
        .def_rw("tan_half", &CameraModel::tan_half)
        .def_rw("width", &CameraModel::width)
        .def_rw("height", &CameraModel::height)
        .def_prop_ro("pixel_angle", &CameraModel::pixel_angle);

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
        .def_rw("edge_v", &Light::edge_v);

    nb::class_<Sky>(m, "Sky")
        .def(nb::init<>())
        .def_rw("zenith", &Sky::zenith)
        .def_rw("horizon", &Sky::horizon)
        .def_rw("below", &Sky::below)
        .def_rw("up", &Sky::up)
        .def_rw("ambient", &Sky::ambient)
        .def_rw("background_is_sky", &Sky::background_is_sky)
        .def_rw("background", &Sky::background);

    nb::class_<RenderSettings>(m, "RenderSettings")
        .def(nb::init<>())
        .def_rw("spp", &RenderSettings::spp)
        .def_rw("reflections", &RenderSettings::reflections)
        .def_rw("shadows", &RenderSettings::shadows)
        .def_rw("lod_pixels", &RenderSettings::lod_pixels)
        .def_rw("seed", &RenderSettings::seed)
        .def_rw("threads", &RenderSettings::threads)
        .def_rw("tile", &RenderSettings::tile)
        .def_prop_rw("normal_offset", [](const RenderSettings &s) { return s.offsets.normal_offset; },
                     [](RenderSettings &s, float v) { s.offsets.normal_offset = v; })
        .def_prop_rw("offset_tmin", [](const RenderSettings &s) { return s.offsets.tmin; },
                     [](RenderSettings &s, float v) { s.offsets.tmin = v; });

    nb::class_<PyRenderScene>(m, "RenderScene")
        .def(nb::init<>())
        .def("add_surfels", [](PyRenderScene &s, nb::object tree_obj, const TraceOptions &opt,
                               Vec3 offset, const Material &mat) {
            const SurfelTree *tree = nb::cast<const SurfelTree *>(tree_obj);
            s.keep_alive.push_back(tree_obj);
            s.scene.objects.push_back({std::make_shared<SurfelGeometry>(tree, opt, offset), mat});
        }, "tree"_a, "options"_a, "offset"_a, "material"_a)
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

    m.def("render", &run_render, "scene"_a, "camera"_a, "settings"_a, "poll"_a.none());

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
                Vec3 a = normalize(nd.axis());
                for (int k = 0; k < 3; ++k) c[3 * i + k] = nd.c[k], nn[3 * i + k] = a[k];
                r[i] = nd.radius;
                cone[i] = nd.cone();
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
            d["count"] = acnt; d["index"] = aidx; d["boxes"] = abx; d["order"] = aord;
            return d;
        })
        // One entry point per query, dispatching on the rays' dtype here: nanobind overloads
        // would let a float64 array be converted to float32 when another argument needs a
        // conversion pass, silently losing the precision that georeferenced rays need.
        .def("cast", [](const SurfelTree &t, AnyArray rays, const TraceOptions &opt,
                        double pixel_angle, int threads, bool want_stats) {
            if (rays.dtype() == nb::dtype<float>())
                return cast_binding<float>(t, nb::cast<CArray<float>>(nb::cast(rays)), opt,
                                           float(pixel_angle), threads, want_stats);
            if (rays.dtype() == nb::dtype<double>())
                return cast_binding<double>(t, nb::cast<CArray<double>>(nb::cast(rays)), opt,
                                            float(pixel_angle), threads, want_stats);
            throw nb::type_error("rays: expected a float32 or float64 array");
        }, "rays"_a, "options"_a, "pixel_angle"_a = 0.0, "threads"_a = 0, "stats"_a = true)
        .def("occluded", [](const SurfelTree &t, AnyArray rays, CArray<float> t_max,
                            const TraceOptions &opt, double t_min, double pixel_angle, int threads,
                            bool want_stats) {
            if (rays.dtype() == nb::dtype<float>())
                return occluded_binding<float>(t, nb::cast<CArray<float>>(nb::cast(rays)), t_max, opt,
                                               float(t_min), float(pixel_angle), threads, want_stats);
            if (rays.dtype() == nb::dtype<double>())
                return occluded_binding<double>(t, nb::cast<CArray<double>>(nb::cast(rays)), t_max, opt,
                                                float(t_min), float(pixel_angle), threads, want_stats);
            throw nb::type_error("rays: expected a float32 or float64 array");
        }, "rays"_a, "t_max"_a, "options"_a, "t_min"_a = 0.0, "pixel_angle"_a = 0.0,
           "threads"_a = 0, "stats"_a = true);
}
