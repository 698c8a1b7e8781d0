// pointviz — reading a PLY face element (faces.h).
#include "pointviz/readers/faces.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>

#include "pointviz/readers/mapped_file.h"

namespace pointviz {
namespace {

/// Records read between cancellation checks and progress updates.
constexpr uint64_t kFaceGrain = 1 << 16;

std::string face_name(uint64_t f) { return "face " + std::to_string(f); }

MalformedData too_few_corners(uint64_t f, double n) {
    return MalformedData(face_name(f) + " has " + std::to_string(int64_t(n)) +
                         " corners (a polygon needs at least 3)");
}
MalformedData bad_index(uint64_t f, uint64_t vertices) {
    return MalformedData(face_name(f) + " has vertex indices outside 0.." +
                         std::to_string(int64_t(vertices) - 1));
}
TruncatedData ends_in(uint64_t f, uint64_t faces) {
    return TruncatedData("the data ends in face " + std::to_string(f) + " of " +
                         std::to_string(faces));
}
MalformedData bad_count(uint64_t f) {
    return MalformedData(face_name(f) + " has a list count that is not a whole number");
}

/// A list count: a whole, non-negative number.
bool whole_count(double v) { return v >= 0 && v == std::floor(v) && v < 4294967296.0; }

/// Appends the fan of a polygon's corners `idx[0..n)` to `tri`.
void add_fan(const int32_t *idx, uint64_t n, std::vector<int32_t> &tri) {
    for (uint64_t k = 1; k + 1 < n; ++k) {
        tri.push_back(idx[0]);
        tri.push_back(idx[k]);
        tri.push_back(idx[k + 1]);
    }
}

/// An index as int32 if it is a whole number in [0, vertices), else false.
bool vertex_index(double v, uint64_t vertices, int32_t &out) {
    if (!(v >= 0 && v < double(vertices)) || v != std::floor(v)) return false;
    out = int32_t(v);
    return true;
}

void check_spec(const FaceSpec &spec) {
    if (spec.indices >= spec.properties.size() || !spec.properties[spec.indices].list)
        throw std::runtime_error("the face spec's index property is not one of its lists");
    if (spec.vertices > uint64_t(std::numeric_limits<int32_t>::max()))
        throw std::runtime_error("more vertices than 32-bit face indices can address");
}

void read_binary_faces(const FaceSpec &spec, const MappedBytes &buf, Faces &out,
                       Progress &progress) {
    const bool swap = spec.encoding == Encoding::BinaryBig;
    const char *data = buf.data();
    const uint64_t size = buf.size();
    uint64_t at = 0;
    std::vector<int32_t> corners;
    // Every record takes at least its scalars' and its lists' counts' bytes: a lying count
    // cannot reserve more triangles than the data could describe.
    uint64_t min_record = 0;
    for (const FaceProperty &p : spec.properties)
        min_record += scalar_size(p.list ? p.count : p.item);
    out.triangles.reserve(3 * size_t(std::min<uint64_t>(spec.faces, size / min_record)));
    uint64_t reported = 0;
    for (uint64_t f = 0; f < spec.faces; ++f) {
        if ((f & (kFaceGrain - 1)) == 0) {
            progress.check();
            progress.advance(at - reported);
            reported = at;
        }
        for (uint32_t k = 0; k < spec.properties.size(); ++k) {
            const FaceProperty &p = spec.properties[k];
            if (!p.list) {
                const size_t bytes = scalar_size(p.item);
                if (size - at < bytes) throw ends_in(f, spec.faces);
                at += bytes;
                continue;
            }
            const size_t cbytes = scalar_size(p.count), ibytes = scalar_size(p.item);
            if (size - at < cbytes) throw ends_in(f, spec.faces);
            const double n = decode_scalar(data + at, p.count, swap);
            at += cbytes;
            if (!whole_count(n)) throw bad_count(f);
            if (uint64_t(n) > (size - at) / ibytes) throw ends_in(f, spec.faces);
            if (k != spec.indices) {
                at += uint64_t(n) * ibytes;
                continue;
            }
            if (n < 3) throw too_few_corners(f, n);
            corners.resize(size_t(n));
            for (uint64_t c = 0; c < uint64_t(n); ++c, at += ibytes)
                if (!vertex_index(decode_scalar(data + at, p.item, swap), spec.vertices, corners[c]))
                    throw bad_index(f, spec.vertices);
            if (n > 3) ++out.polygons;
            add_fan(corners.data(), uint64_t(n), out.triangles);
        }
    }
}

/// The next token of [p, e) on one line, as a number; false at the end of the line.
bool next_number(const char *&p, const char *e, double &v, bool &bad) {
    while (p != e && is_separator(*p, false)) ++p;
    if (p == e) return false;
    const char *t = p;
    while (p != e && !is_separator(*p, false)) ++p;
    bad = !parse_number(t, p, v);
    return true;
}

/// A face line that ends before its properties do: what it is missing.
struct LineEnds {
    const char *what;
};

/// Parses face `f`'s line [b, e) into `out`; throws LineEnds when the line is short (the caller
/// knows whether that is the end of the file), MalformedData for anything else.
void parse_face_line(const char *b, const char *e, const FaceSpec &spec, uint64_t f,
                     std::vector<int32_t> &corners, Faces &out) {
    const char *p = b;
    double v = 0;
    bool bad = false;
    auto need = [&](const char *what) {
        if (!next_number(p, e, v, bad)) throw LineEnds{what};
        if (bad) throw MalformedData(face_name(f) + " holds a non-number");
    };
    for (uint32_t k = 0; k < spec.properties.size(); ++k) {
        const FaceProperty &prop = spec.properties[k];
        if (!prop.list) {
            need("properties");
            continue;
        }
        need("list count");
        if (!whole_count(v)) throw bad_count(f);
        const uint64_t n = uint64_t(v);
        if (k == spec.indices && n < 3) throw too_few_corners(f, v);
        if (k == spec.indices) corners.resize(size_t(n));
        for (uint64_t c = 0; c < n; ++c) {
            need("list items");
            if (k == spec.indices && !vertex_index(v, spec.vertices, corners[c]))
                throw bad_index(f, spec.vertices);
        }
        if (k == spec.indices) {
            if (n > 3) ++out.polygons;
            add_fan(corners.data(), n, out.triangles);
        }
    }
    if (next_number(p, e, v, bad))
        throw MalformedData(face_name(f) + " has more values than its properties");
}

void read_ascii_faces(const FaceSpec &spec, const MappedBytes &buf, Faces &out,
                      Progress &progress) {
    const char *data = buf.data();
    const char *end = data + buf.size();
    const char *p = data;
    for (uint64_t line = 0; line < spec.skip_lines; ++line) {
        const char *nl = static_cast<const char *>(std::memchr(p, '\n', size_t(end - p)));
        if (nl == nullptr)
            throw TruncatedData("the data ends before the faces (after " +
                                std::to_string(line) + " of the " +
                                std::to_string(spec.skip_lines) + " lines before them)");
        p = nl + 1;
        if ((line & (kFaceGrain - 1)) == 0) progress.check();
    }
    // a face line takes at least 6 bytes ("3 0 1 2" without its newline is 7)
    out.triangles.reserve(3 * size_t(std::min<uint64_t>(spec.faces, uint64_t(end - p) / 6 + 1)));
    std::vector<int32_t> corners;
    uint64_t reported = 0;
    for (uint64_t f = 0; f < spec.faces; ++f) {
        if (p >= end)
            throw TruncatedData("the data ends after " + std::to_string(f) + " of the " +
                                std::to_string(spec.faces) + " faces");
        const char *nl = static_cast<const char *>(std::memchr(p, '\n', size_t(end - p)));
        const char *le = nl ? nl : end;
        try {
            parse_face_line(p, le, spec, f, corners, out);
        } catch (const LineEnds &short_line) {
            if (nl == nullptr) throw ends_in(f, spec.faces);  // the file's cut-off last line
            throw MalformedData(face_name(f) + " ends before its " + short_line.what);
        }
        p = nl ? nl + 1 : end;
        if ((f & (kFaceGrain - 1)) == 0) {
            progress.check();
            progress.advance(uint64_t(p - data) - reported);
            reported = uint64_t(p - data);
        }
    }
}

}  // namespace

void read_faces(const FaceSpec &spec, Faces &out, Progress &progress) {
    check_spec(spec);
    out = Faces{};
    MappedBytes buf(spec.path, spec.offset, ~uint64_t(0));
    progress.total.fetch_add(buf.size(), std::memory_order_relaxed);  // units: bytes
    progress.check();
    if (spec.encoding == Encoding::Ascii)
        read_ascii_faces(spec, buf, out, progress);
    else
        read_binary_faces(spec, buf, out, progress);
    progress.done.store(progress.total.load());  // every byte is accounted for
}

}  // namespace pointviz
