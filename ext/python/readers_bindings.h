// pointviz._core — the table reader (ext/include/pointviz/readers/table.h): type conversion only.
// Included once by bindings.cpp; `bind_readers(m)` adds the block to the module.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>
#include <nanobind/stl/array.h>

#include <cstdint>

#include <memory>
#include <utility>
#include <vector>

#include "pointviz/progress.h"
#include "pointviz/readers/faces.h"
#include "pointviz/readers/lzf.h"
#include "pointviz/readers/obj.h"
#include "pointviz/readers/table.h"

namespace pointviz_bindings {

namespace nb = nanobind;

/// The long call, with the GIL released: one call taking a Progress, so that a runner on a
/// worker thread (progress reports, Ctrl-C) can drive it as is.
inline std::vector<pointviz::Table> read_tables_released(
        const std::vector<pointviz::TableSpec> &specs, int threads, pointviz::Progress &progress) {
    std::vector<pointviz::Table> out;
    nb::gil_scoped_release release;
    pointviz::read_tables(specs, out, threads, progress);
    return out;
}

/// As read_tables_released, every table's rows in `joined`.
inline std::vector<pointviz::Table> read_tables_joined_released(
        const std::vector<pointviz::TableSpec> &specs, pointviz::TableValues &joined, int threads,
        pointviz::Progress &progress) {
    std::vector<pointviz::Table> out;
    nb::gil_scoped_release release;
    pointviz::read_tables_joined(specs, joined, out, threads, progress);
    return out;
}

/// read_faces with the GIL released.
inline pointviz::Faces read_faces_released(const pointviz::FaceSpec &spec,
                                           pointviz::Progress &progress) {
    pointviz::Faces out;
    nb::gil_scoped_release release;
    pointviz::read_faces(spec, out, progress);
    return out;
}

/// (rows, columns) float64 numpy array that takes over a buffer of values (no copy).
inline nb::object values_array(pointviz::TableValues &values, size_t rows, size_t ncols) {
    auto *buf = new pointviz::TableValues(std::move(values));
    nb::capsule owner(buf, [](void *p) noexcept { delete static_cast<pointviz::TableValues *>(p); });
    size_t shape[2] = {rows, ncols};
    return nb::cast(nb::ndarray<nb::numpy, double>(buf->empty() ? nullptr : buf->data(), 2, shape,
                                                   owner));
}

/// One table's results but its values: lines_after, the positions' lo, hi, sum and finite, and
/// grid ((rows, 2) int32) when it has one.
inline nb::dict table_dict(const pointviz::Table &t) {
    const pointviz::PositionStats &ps = t.positions;
    nb::dict d;
    d["lines_after"] = t.lines_after;
    if (!t.grid.empty()) {
        size_t shape[2] = {size_t(t.rows), 2};
        d["grid"] = nb::cast(nb::ndarray<nb::numpy, int32_t>(const_cast<int32_t *>(t.grid.data()),
                                                              2, shape, nb::handle()),
                             nb::rv_policy::copy);
    }
    d["lo"] = ps.lo;
    d["hi"] = ps.hi;
    d["sum"] = ps.sum;
    d["finite"] = ps.finite;
    return d;
}

inline void bind_readers(nb::module_ &m) {
    using namespace nb::literals;
    using pointviz::Encoding;
    using pointviz::Scalar;
    using pointviz::TableSpec;

    nb::enum_<Scalar>(m, "Scalar")
        .value("i8", Scalar::I8).value("u8", Scalar::U8)
        .value("i16", Scalar::I16).value("u16", Scalar::U16)
        .value("i32", Scalar::I32).value("u32", Scalar::U32)
        .value("f32", Scalar::F32).value("f64", Scalar::F64);
    nb::enum_<Encoding>(m, "Encoding")
        .value("ascii", Encoding::Ascii)
        .value("binary_little_endian", Encoding::BinaryLittle)
        .value("binary_big_endian", Encoding::BinaryBig);
    nb::class_<TableSpec>(m, "TableSpec")
        .def(nb::init<>())
        .def_rw("path", &TableSpec::path)
        .def_rw("offset", &TableSpec::offset)
        .def_rw("encoding", &TableSpec::encoding)
        .def_rw("columns", &TableSpec::columns)
        .def_rw("rows", &TableSpec::rows)
        .def_rw("wanted", &TableSpec::wanted)
        .def_rw("exact_columns", &TableSpec::exact_columns)
        .def_rw("commas", &TableSpec::commas)
        .def_rw("transform", &TableSpec::transform)
        .def_rw("affine", &TableSpec::affine)
        .def_rw("grid_cells", &TableSpec::grid_cells)
        .def_rw("grid_cols", &TableSpec::grid_cols)
        .def_rw("grid_count", &TableSpec::grid_count)
        .def_rw("grid_index", &TableSpec::grid_index);
    nb::class_<pointviz::FaceProperty>(m, "FaceProperty")
        .def(nb::init<>())
        .def_rw("list", &pointviz::FaceProperty::list)
        .def_rw("count", &pointviz::FaceProperty::count)
        .def_rw("item", &pointviz::FaceProperty::item);
    nb::class_<pointviz::FaceSpec>(m, "FaceSpec")
        .def(nb::init<>())
        .def_rw("path", &pointviz::FaceSpec::path)
        .def_rw("offset", &pointviz::FaceSpec::offset)
        .def_rw("skip_lines", &pointviz::FaceSpec::skip_lines)
        .def_rw("encoding", &pointviz::FaceSpec::encoding)
        .def_rw("properties", &pointviz::FaceSpec::properties)
        .def_rw("indices", &pointviz::FaceSpec::indices)
        .def_rw("faces", &pointviz::FaceSpec::faces)
        .def_rw("vertices", &pointviz::FaceSpec::vertices);
    nb::exception<pointviz::TruncatedData>(m, "TruncatedData", PyExc_ValueError);
    nb::exception<pointviz::MalformedData>(m, "MalformedData", PyExc_ValueError);

    m.def("read_tables", [](const std::vector<TableSpec> &specs, int threads) {
        pointviz::Progress progress;
        std::vector<pointviz::Table> tables = read_tables_released(specs, threads, progress);
        nb::list out;
        for (size_t i = 0; i < tables.size(); ++i) {
            nb::dict d = table_dict(tables[i]);
            d["values"] = values_array(tables[i].values, size_t(tables[i].rows),
                                       specs[i].wanted.size());
            out.append(d);
        }
        return out;
    }, "specs"_a, "threads"_a = 0,
    "Read the numeric rows each TableSpec describes (several files in parallel). Returns one dict "
    "per spec: values ((rows, len(wanted)) float64), lines_after, and lo, hi, sum, finite of the "
    "positions as read (before the affine map), and grid ((rows, 2) int32) with grid_cells.");
    m.def("read_tables_joined", [](const std::vector<TableSpec> &specs, int threads) {
        pointviz::Progress progress;
        pointviz::TableValues joined;
        std::vector<pointviz::Table> tables =
            read_tables_joined_released(specs, joined, threads, progress);
        const size_t ncols = specs.empty() ? 0 : specs[0].wanted.size();
        const size_t rows = ncols == 0 ? 0 : joined.size() / ncols;
        nb::list out;
        for (const pointviz::Table &t : tables) out.append(table_dict(t));
        return nb::make_tuple(values_array(joined, rows, ncols), out);
    }, "specs"_a, "threads"_a = 0,
    "As read_tables, every spec's rows in one array, one spec's after the other's (each spec "
    "needs a row count, all the same wanted columns). Returns (values, dicts): values "
    "((total rows, len(wanted)) float64) and per spec the dict of read_tables without values.");
    m.def("read_faces", [](const pointviz::FaceSpec &spec) {
        pointviz::Progress progress;
        pointviz::Faces faces = read_faces_released(spec, progress);
        auto *buf = new std::vector<int32_t>(std::move(faces.triangles));
        nb::capsule owner(buf, [](void *p) noexcept {
            delete static_cast<std::vector<int32_t> *>(p);
        });
        size_t shape[2] = {buf->size() / 3, 3};
        nb::dict d;
        d["triangles"] = nb::cast(nb::ndarray<nb::numpy, int32_t>(
            buf->empty() ? nullptr : buf->data(), 2, shape, owner));
        d["polygons"] = faces.polygons;
        return d;
    }, "spec"_a,
    "Read the PLY face records a FaceSpec describes. Returns a dict: triangles ((m, 3) int32, "
    "polygons of n > 3 corners as fans of n - 2) and polygons (how many records had more than "
    "three corners). TruncatedData / MalformedData (naming the face) when the data is not what "
    "the spec says.");
    m.def("read_obj", [](const std::string &path) {
        pointviz::Progress progress;
        pointviz::ObjMesh mesh;
        {
            nb::gil_scoped_release release;
            mesh = pointviz::read_obj(path, progress);
        }
        const size_t n = mesh.vertices.size() / 3, m = mesh.triangles.size() / 3;
        nb::dict d;
        d["vertices"] = nb::cast(nb::ndarray<nb::numpy, double>(
            mesh.vertices.data(), 2, std::array<size_t, 2>{n, 3}.data(), nb::handle()),
            nb::rv_policy::copy);
        d["triangles"] = nb::cast(nb::ndarray<nb::numpy, int32_t>(
            mesh.triangles.data(), 2, std::array<size_t, 2>{m, 3}.data(), nb::handle()),
            nb::rv_policy::copy);
        if (mesh.colors.empty())
            d["colors"] = nb::none();
        else
            d["colors"] = nb::cast(nb::ndarray<nb::numpy, double>(
                mesh.colors.data(), 2, std::array<size_t, 2>{n, 3}.data(), nb::handle()),
                nb::rv_policy::copy);
        d["polygons"] = mesh.polygons;
        return d;
    }, "path"_a,
    "Read an OBJ file's geometry: a dict of vertices ((n, 3) float64), colors ((n, 3) float64 "
    "when every vertex line has r g b, else None), triangles ((m, 3) int32, polygons as fans) "
    "and polygons (faces with more than three corners). MalformedData names the line.");
    m.def("lzf_decompress", [](nb::bytes data, size_t size) {
        std::unique_ptr<uint8_t[]> buf(new uint8_t[size > 0 ? size : 1]);
        {
            nb::gil_scoped_release release;
            pointviz::lzf_decompress(reinterpret_cast<const uint8_t *>(data.c_str()), data.size(),
                                     buf.get(), size);
        }
        uint8_t *raw = buf.release();
        nb::capsule owner(raw, [](void *p) noexcept { delete[] static_cast<uint8_t *>(p); });
        size_t shape[1] = {size};
        return nb::ndarray<nb::numpy, uint8_t>(raw, 1, shape, owner);
    }, "data"_a, "size"_a,
    "Decompress an LZF block (PCD binary_compressed data) of exactly `size` bytes into a uint8 "
    "array; MalformedData if the stream is damaged or expands to another size.");
}

}  // namespace pointviz_bindings
