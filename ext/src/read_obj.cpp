// pointviz — reading the geometry of an OBJ file (obj.h).
#include "pointviz/readers/obj.h"

#include <cmath>
#include <cstring>
#include <limits>

#include "pointviz/readers/mapped_file.h"
#include "pointviz/readers/numbers.h"

namespace pointviz {
namespace {

/// Lines read between cancellation checks.
constexpr uint64_t kLineGrain = 1 << 16;

MalformedData at_line(uint64_t line, const std::string &what) {
    return MalformedData("line " + std::to_string(line) + ": " + what);
}

/// The next blank-separated token of [p, e): [t, p) after the call; false at the end.
bool next_token(const char *&p, const char *e, const char *&t) {
    while (p != e && is_separator(*p, false)) ++p;
    if (p == e) return false;
    t = p;
    while (p != e && !is_separator(*p, false)) ++p;
    return true;
}

/// A face corner's position index: the integer before its first '/', resolved against the
/// `defined` vertices so far (negative: relative); kept as a 0-based int64 (checked later).
bool corner_index(const char *b, const char *e, uint64_t defined, int64_t &out) {
    const char *slash = static_cast<const char *>(std::memchr(b, '/', size_t(e - b)));
    const char *end = slash ? slash : e;
    double v;
    if (!parse_number(b, end, v) || v != std::floor(v) || v == 0 || std::fabs(v) > 9.0e15)
        return false;
    out = v > 0 ? int64_t(v) - 1 : int64_t(defined) + int64_t(v);
    return true;
}

}  // namespace

ObjMesh read_obj(const std::string &path, Progress &progress) {
    MappedBytes buf(path, 0, ~uint64_t(0));
    progress.total.fetch_add(buf.size(), std::memory_order_relaxed);  // units: bytes
    const char *p = buf.data(), *end = buf.data() + buf.size();
    ObjMesh out;
    std::vector<int64_t> corners;
    std::vector<uint64_t> corner_lines;  // the line of each face's first triangle, for errors
    uint64_t line = 0, rgb = 0, reported = 0;
    while (p < end) {
        const char *nl = static_cast<const char *>(std::memchr(p, '\n', size_t(end - p)));
        const char *le = nl ? nl : end;
        const char *q = p, *t = nullptr;
        ++line;
        if ((line & (kLineGrain - 1)) == 0) {
            progress.check();
            progress.advance(uint64_t(p - buf.data()) - reported);
            reported = uint64_t(p - buf.data());
        }
        if (next_token(q, le, t) && q - t == 1 && (*t == 'v' || *t == 'f')) {
            if (*t == 'v') {
                double v[7];
                int n = 0;
                const char *u = nullptr;
                while (n < 7 && next_token(q, le, u)) {
                    if (!parse_number(u, q, v[n])) throw at_line(line, "a vertex holds a non-number");
                    ++n;
                }
                if (n < 3) throw at_line(line, "a vertex needs x, y and z");
                out.vertices.insert(out.vertices.end(), v, v + 3);
                if (n >= 6) {
                    out.colors.insert(out.colors.end(), v + 3, v + 6);
                    ++rgb;
                }
            } else {
                corners.clear();
                const char *u = nullptr;
                const uint64_t defined = out.vertices.size() / 3;
                while (next_token(q, le, u)) {
                    int64_t k;
                    if (!corner_index(u, q, defined, k))
                        throw at_line(line, "a face corner's vertex index is not a whole number");
                    corners.push_back(k);
                }
                if (corners.size() < 3)
                    throw at_line(line, "a face has " + std::to_string(corners.size()) +
                                            " corners (a polygon needs at least 3)");
                if (corners.size() > 3) ++out.polygons;
                for (size_t k = 1; k + 1 < corners.size(); ++k) {
                    for (int64_t c : {corners[0], corners[k], corners[k + 1]}) {
                        // indices past int32 (or negative) are caught by the range check below
                        out.triangles.push_back(c < 0 || c > std::numeric_limits<int32_t>::max()
                                                    ? -1 : int32_t(c));
                    }
                    corner_lines.push_back(line);
                }
            }
        }
        p = nl ? nl + 1 : end;
    }
    const uint64_t n = out.vertices.size() / 3;
    if (rgb != n) out.colors.clear();  // colours only when every vertex has them
    for (size_t k = 0; k < out.triangles.size(); ++k)
        if (out.triangles[k] < 0 || uint64_t(out.triangles[k]) >= n)
            throw at_line(corner_lines[k / 3], "a face names a vertex that is not defined (the "
                                                "file has " + std::to_string(n) + ")");
    progress.advance(buf.size() - reported);
    return out;
}

}  // namespace pointviz
