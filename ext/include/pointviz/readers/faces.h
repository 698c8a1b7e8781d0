// pointviz — reading a PLY file's face element at disk speed: each record's vertex-index list
// as triangles (polygons as fans), every index checked against the vertex count. The header is
// parsed by the Python reader (pointviz/readers/ply.py), which also reads the vertex rows
// (table.h); this reads the records it describes and never trusts a count it has not checked.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "pointviz/progress.h"
#include "pointviz/readers/data_errors.h"
#include "pointviz/readers/numbers.h"
#include "pointviz/readers/table.h"

namespace pointviz {

/// One property of a face record, in file order: a scalar (`list` false, type `item`) or a
/// list (a `count`, then that many `item`s).
struct FaceProperty {
    bool list = false;
    Scalar count = Scalar::U8;
    Scalar item = Scalar::I32;
};

/// The face element of one PLY file.
struct FaceSpec {
    std::string path;
    /// Binary: the first byte of the face records. ASCII: the first byte of the data (right
    /// after the header); the faces start `skip_lines` lines later.
    uint64_t offset = 0;
    uint64_t skip_lines = 0;      ///< ASCII: lines before the faces (the vertex rows)
    Encoding encoding = Encoding::Ascii;
    std::vector<FaceProperty> properties;
    uint32_t indices = 0;         ///< which property is the vertex-index list
    uint64_t faces = 0;           ///< records to read
    uint64_t vertices = 0;        ///< every index must lie in [0, vertices)
};

/// The triangles of a face element.
struct Faces {
    std::vector<int32_t> triangles;  ///< (count, 3) vertex indices, row-major
    uint64_t polygons = 0;           ///< records with more than three corners (split into fans)
};

/// Reads the face records `spec` describes into `out`. A record of n >= 3 corners becomes the
/// n - 2 triangles (v0, v[k], v[k+1]) of a fan, in file order. Throws TruncatedData (the data
/// ends first), MalformedData (a record with fewer than three corners, an index that is not an
/// integer in [0, vertices), an ASCII token that is not a number or a line with too few or too
/// many values; the message names the face, 0-based), std::runtime_error (I/O, a bad spec) or
/// Cancelled.
void read_faces(const FaceSpec &spec, Faces &out, Progress &progress);

}  // namespace pointviz
