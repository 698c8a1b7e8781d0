// pointviz._core — a Geometry whose queries call a Python object (e.g. an embreex mesh), so
// that mesh renders share the C++ shading code. Not thread-safe: the renderer calls it from one
// thread, and each call takes the GIL.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <atomic>
#include <mutex>
#include <string>

#include "pointviz/geometry.h"

namespace pointviz {

class PyGeometry final : public Geometry {
public:
    /// `obj` has intersect(rays) -> (t, normals, colors, radii) and occluded(rays) -> bool
    /// array; `rays` is (n, 8) float32: origin, direction (unit), tmin, tmax.
    explicit PyGeometry(nanobind::object obj) : obj_(std::move(obj)) {}

    void set_cancel(std::atomic<bool> *cancel) { cancel_ = cancel; }
    /// The first Python error raised by a callback, or empty.
    std::string error() const {
        std::lock_guard<std::mutex> l(m_);
        return error_;
    }
    bool thread_safe() const override { return false; }

    void intersect(const Ray *rays, size_t n, SurfaceHit *hits) const override {
        for (size_t i = 0; i < n; ++i) hits[i] = SurfaceHit{};
        if (n == 0 || failed()) return;
        namespace nb = nanobind;
        nb::gil_scoped_acquire gil;
        try {
            nb::object res = obj_.attr("intersect")(pack(rays, n));
            auto t = nb::cast<nb::ndarray<const float, nb::c_contig>>(res[0]);
            auto nn = nb::cast<nb::ndarray<const float, nb::c_contig>>(res[1]);
            auto cc = nb::cast<nb::ndarray<const float, nb::c_contig>>(res[2]);
            auto rr = nb::cast<nb::ndarray<const float, nb::c_contig>>(res[3]);
            if (t.size() != n || nn.size() != 3 * n || cc.size() != 3 * n || rr.size() != n)
                throw std::runtime_error("intersect() returned arrays of the wrong size");
            for (size_t i = 0; i < n; ++i) {
                float ti = t.data()[i];
                if (!(ti < kInf)) continue;
                SurfaceHit &h = hits[i];
                h.t = ti;
                h.n = normalize(Vec3{nn.data()[3 * i], nn.data()[3 * i + 1], nn.data()[3 * i + 2]});
                h.color = {cc.data()[3 * i], cc.data()[3 * i + 1], cc.data()[3 * i + 2]};
                h.radius = rr.data()[i];
                h.index = 0;
                h.count = 1;
            }
        } catch (const std::exception &e) {
            fail(e.what());
            for (size_t i = 0; i < n; ++i) hits[i] = SurfaceHit{};
        }
    }

    void occluded(const Ray *rays, size_t n, uint8_t *hit) const override {
        for (size_t i = 0; i < n; ++i) hit[i] = 0;
        if (n == 0 || failed()) return;
        namespace nb = nanobind;
        nb::gil_scoped_acquire gil;
        try {
            nb::object res = obj_.attr("occluded")(pack(rays, n));
            auto h = nb::cast<nb::ndarray<const bool, nb::c_contig>>(res);
            if (h.size() != n) throw std::runtime_error("occluded() returned an array of the wrong size");
            for (size_t i = 0; i < n; ++i) hit[i] = h.data()[i] ? 1 : 0;
        } catch (const std::exception &e) {
            fail(e.what());
        }
    }

private:
    static nanobind::object pack(const Ray *rays, size_t n) {
        namespace nb = nanobind;
        float *buf = new float[8 * n];
        for (size_t i = 0; i < n; ++i) {
            const Ray &r = rays[i];
            float *q = buf + 8 * i;
            q[0] = r.o.x; q[1] = r.o.y; q[2] = r.o.z;
            q[3] = r.d.x; q[4] = r.d.y; q[5] = r.d.z;
            q[6] = r.tmin; q[7] = r.tmax;
        }
        nb::capsule owner(buf, [](void *p) noexcept { delete[] static_cast<float *>(p); });
        size_t shape[2] = {n, 8};
        return nb::cast(nb::ndarray<nb::numpy, float>(buf, 2, shape, owner));
    }
    bool failed() const {
        std::lock_guard<std::mutex> l(m_);
        return !error_.empty();
    }
    void fail(const char *what) const {
        {
            std::lock_guard<std::mutex> l(m_);
            if (error_.empty()) error_ = what && *what ? what : "geometry callback failed";
        }
        if (cancel_) cancel_->store(true);
    }

    nanobind::object obj_;
    std::atomic<bool> *cancel_ = nullptr;
    mutable std::mutex m_;
    mutable std::string error_;
};

}  // namespace pointviz
