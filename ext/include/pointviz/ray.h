// pointviz — rays and their footprint cones.
#pragma once

#include <limits>

#include "pointviz/vec.h"

namespace pointviz {

constexpr float kInf = std::numeric_limits<float>::infinity();

/// A ray with a unit direction, a parameter interval and a footprint cone.
///
/// The footprint is the width of the pixel's beam at distance t: `width0 + spread * t`. Primary
/// rays have width0 = 0 and spread = the camera's pixel angle; a reflected ray carries the width
/// it had on the mirror. Level of detail compares node sizes with this footprint; spread = 0
/// means "no footprint known": trace at full detail.
struct Ray {
    Vec3 o;                 ///< origin, in the tree's local frame
    Vec3 d;                 ///< unit direction
    float tmin = 0.f;       ///< hits closer than this are ignored
    float tmax = kInf;      ///< hits farther than this are ignored
    float width0 = 0.f;     ///< footprint width at the origin
    float spread = 0.f;     ///< footprint growth per unit distance (radians for small angles)

    /// Beam width at parameter t.
    float footprint(float t) const { return width0 + spread * t; }
};

}  // namespace pointviz
