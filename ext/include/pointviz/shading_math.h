// pointviz — the shading's own sine, cosine and lobe power (render.cpp): cheaper than libm's
// sincosf and powf on the lit ground's samples, within a few units in the last place
// (tests/cpp/core_tests.cpp, test_shading_math, against double precision).
#pragma once

#include <cmath>

namespace pointviz {

/// cos and sin of a turn's fraction u in [0, 1) (the angle 2 pi u): u taken to the nearest
/// quarter turn k / 4 (exactly: u - k / 4 is a float subtraction of nearby values), the rest
/// r in [-pi/4, pi/4] into Taylor polynomials of degree 9 (sine) and 10 (cosine), whose
/// truncation is below 4e-10 there, then rotated by k quarter turns: the error is the float
/// rounding of r and of the sums (a test bounds it against double precision). Replaces libm's
/// sincosf on the lights' and sky rays' sample directions (2.3-2.6 % of a far frame).
inline void turn_sincos(float u, float &c, float &s) {
    const int k = int(u * 4.f + 0.5f);   // 0..4
    const float r = (u - float(k) * 0.25f) * (2.f * 3.14159265358979f);
    const float r2 = r * r;
    const float sr = r * (1.f + r2 * (-1.f / 6.f + r2 * (1.f / 120.f + r2 * (-1.f / 5040.f + r2 * (1.f / 362880.f)))));
    const float cr = 1.f + r2 * (-0.5f + r2 * (1.f / 24.f + r2 * (-1.f / 720.f + r2 * (1.f / 40320.f + r2 * (-1.f / 3628800.f)))));
    switch (k & 3) {
        case 0: c = cr; s = sr; break;
        case 1: c = -sr; s = cr; break;
        case 2: c = -cr; s = -sr; break;
        default: c = sr; s = -cr; break;
    }
}

/// x^e for x in [0, 1] (a Blinn-Phong lobe): by squaring when e is a whole number in
/// [1, 1024] (the materials' shininess, 48 by default), else std::pow. Each product rounds
/// once, so the relative error is below e ulp (48: 2.9e-6); powf was 3.1-3.5 % of a far frame.
inline float lobe_pow(float x, float e) {
    if (!(e >= 1.f && e <= 1024.f) || float(int(e)) != e) return std::pow(x, e);
    unsigned n = unsigned(e);
    float r = 1.f, b = x;
    for (;;) {
        if (n & 1u) r *= b;
        n >>= 1;
        if (!n) break;
        b *= b;
    }
    return r;
}

}  // namespace pointviz
