// pointviz — small fixed-size vector math used by every other header.
#pragma once

#include "pointviz/isa.h"

#include <cmath>
#include <cstdint>

namespace pointviz {

/// Three floats; the only vector type of the core.
struct Vec3 {
    float x = 0.f, y = 0.f, z = 0.f;

    constexpr Vec3() = default;
    constexpr Vec3(float x_, float y_, float z_) : x(x_), y(y_), z(z_) {}
    /// Component `i` (0, 1 or 2).
    float operator[](int i) const { return i == 0 ? x : (i == 1 ? y : z); }
    float &operator[](int i) { return i == 0 ? x : (i == 1 ? y : z); }
};

POINTVIZ_ISA_BEGIN

inline Vec3 operator+(Vec3 a, Vec3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
inline Vec3 operator-(Vec3 a, Vec3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
inline Vec3 operator-(Vec3 a) { return {-a.x, -a.y, -a.z}; }
inline Vec3 operator*(Vec3 a, float s) { return {a.x * s, a.y * s, a.z * s}; }
inline Vec3 operator*(float s, Vec3 a) { return {a.x * s, a.y * s, a.z * s}; }
inline Vec3 operator*(Vec3 a, Vec3 b) { return {a.x * b.x, a.y * b.y, a.z * b.z}; }
inline Vec3 operator/(Vec3 a, float s) { return a * (1.f / s); }
inline Vec3 &operator+=(Vec3 &a, Vec3 b) { a = a + b; return a; }
inline Vec3 &operator-=(Vec3 &a, Vec3 b) { a = a - b; return a; }
inline Vec3 &operator*=(Vec3 &a, float s) { a = a * s; return a; }

inline float dot(Vec3 a, Vec3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3 cross(Vec3 a, Vec3 b) {
    return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline float length2(Vec3 a) { return dot(a, a); }
inline float length(Vec3 a) { return std::sqrt(dot(a, a)); }
/// Unit vector along `a`; `a` itself when it has zero length.
inline Vec3 normalize(Vec3 a) {
    float l = length(a);
    return l > 0.f ? a / l : a;
}
inline Vec3 vmin(Vec3 a, Vec3 b) {
    return {std::fmin(a.x, b.x), std::fmin(a.y, b.y), std::fmin(a.z, b.z)};
}
inline Vec3 vmax(Vec3 a, Vec3 b) {
    return {std::fmax(a.x, b.x), std::fmax(a.y, b.y), std::fmax(a.z, b.z)};
}
inline float max_component(Vec3 a) { return std::fmax(a.x, std::fmax(a.y, a.z)); }
/// Mirror direction `d` about unit normal `n`.
inline Vec3 reflect(Vec3 d, Vec3 n) { return d - n * (2.f * dot(d, n)); }

/// Orthonormal basis (t, b) around unit `n` (Duff et al. 2017, branchless).
inline void make_basis(Vec3 n, Vec3 &t, Vec3 &b) {
    float sign = std::copysign(1.f, n.z);
    float a = -1.f / (sign + n.z);
    float c = n.x * n.y * a;
    t = {1.f + sign * n.x * n.x * a, sign * c, -sign * n.x};
    b = {c, sign + n.y * n.y * a, -n.y};
}

POINTVIZ_ISA_END

}  // namespace pointviz
