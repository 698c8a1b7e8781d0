// pointviz — reading a Wavefront OBJ file's geometry at disk speed: its vertex positions (with
// the common "v x y z r g b" colour extension) and its faces' position indices as triangles
// (polygons as fans). Texture coordinates, normals, groups, materials, lines and points are
// skipped: a surfel takes its normal from the faces around its vertex.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "pointviz/progress.h"
#include "pointviz/readers/data_errors.h"

namespace pointviz {

/// The geometry of an OBJ file.
struct ObjMesh {
    std::vector<double> vertices;    ///< (n, 3)
    std::vector<double> colors;      ///< (n, 3) when every vertex line has r g b, else empty
    std::vector<int32_t> triangles;  ///< (m, 3) 0-based vertex indices
    uint64_t polygons = 0;           ///< faces with more than three corners (split into fans)
};

/// Reads `path`. Face corners are "v", "v/vt", "v//vn" or "v/vt/vn"; a position index is
/// 1-based, or negative (counted back from the last vertex defined before the face). Throws
/// MalformedData (naming the line, 1-based: a vertex without three numbers, a face with fewer
/// than three corners or an index that is not an integer or names no vertex), std::runtime_error
/// (I/O) or Cancelled.
ObjMesh read_obj(const std::string &path, Progress &progress);

}  // namespace pointviz
