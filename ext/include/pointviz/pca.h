// pointviz — principal axes of a symmetric 3x3 matrix (a neighbourhood's covariance), closed
// form in double precision: eigenvalues by the trigonometric solution of the characteristic
// cubic, the eigenvector of the smallest one from cross products of the rows of (A - l0 I).
#pragma once

#include <algorithm>
#include <cmath>

namespace pointviz {

/// Eigen-decomposition of a covariance: ascending eigenvalues and the unit eigenvector of the
/// smallest (the normal of a planar neighbourhood).
struct Principal {
    double l0 = 0, l1 = 0, l2 = 0;   ///< eigenvalues, l0 <= l1 <= l2
    double n[3] = {0, 0, 1};         ///< unit eigenvector of l0
    bool ok = false;                 ///< false: l0 is not separated from l1 (line or point)
};

/// `a` holds (xx, xy, xz, yy, yz, zz). `min_gap` is the smallest (l1 - l0) / l2 for which the
/// normal counts as defined (below it the neighbourhood is a line or a single position).
inline Principal principal_axes(const double a[6], double min_gap) {
    Principal out;
    double xx = a[0], xy = a[1], xz = a[2], yy = a[3], yz = a[4], zz = a[5];
    double q = (xx + yy + zz) / 3.0;
    double p1 = xy * xy + xz * xz + yz * yz;
    double p2 = (xx - q) * (xx - q) + (yy - q) * (yy - q) + (zz - q) * (zz - q) + 2.0 * p1;
    double p = std::sqrt(p2 / 6.0);
    if (!(p > 0.0)) {  // a multiple of the identity (or all zero): no direction stands out
        out.l0 = out.l1 = out.l2 = q;
        return out;
    }
    double b00 = (xx - q) / p, b11 = (yy - q) / p, b22 = (zz - q) / p;
    double b01 = xy / p, b02 = xz / p, b12 = yz / p;
    double r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) +
                      b02 * (b01 * b12 - b11 * b02));
    r = std::clamp(r, -1.0, 1.0);
    double phi = std::acos(r) / 3.0;
    constexpr double kThird = 2.0943951023931954923;  // 2 pi / 3
    out.l2 = q + 2.0 * p * std::cos(phi);
    out.l0 = q + 2.0 * p * std::cos(phi + kThird);
    out.l1 = 3.0 * q - out.l0 - out.l2;
    if (out.l1 < out.l0) std::swap(out.l0, out.l1);
    if (out.l2 < out.l1) std::swap(out.l1, out.l2);
    // rows of (A - l0 I); their cross products are parallel to the l0 eigenvector
    double r0[3] = {xx - out.l0, xy, xz}, r1[3] = {xy, yy - out.l0, yz},
           r2[3] = {xz, yz, zz - out.l0};
    auto crs = [](const double *u, const double *v, double *w) {
        w[0] = u[1] * v[2] - u[2] * v[1];
        w[1] = u[2] * v[0] - u[0] * v[2];
        w[2] = u[0] * v[1] - u[1] * v[0];
        return w[0] * w[0] + w[1] * w[1] + w[2] * w[2];
    };
    double c[3][3];
    double l[3] = {crs(r0, r1, c[0]), crs(r0, r2, c[1]), crs(r1, r2, c[2])};
    int best = int(std::max_element(l, l + 3) - l);
    if (!(l[best] > 0.0)) return out;
    double inv = 1.0 / std::sqrt(l[best]);
    for (int k = 0; k < 3; ++k) out.n[k] = c[best][k] * inv;
    out.ok = out.l1 - out.l0 > min_gap * out.l2;
    return out;
}

/// A tangent basis (t1, t2) of unit normal n: t1 = n x e (e = x axis, or y when n is close to
/// x), t2 = n x t1. The same rule as the Python side uses, so radii do not depend on the side.
inline void tangent_basis(const double n[3], double t1[3], double t2[3]) {
    double e[3] = {std::fabs(n[0]) < 0.9 ? 1.0 : 0.0, std::fabs(n[0]) < 0.9 ? 0.0 : 1.0, 0.0};
    t1[0] = n[1] * e[2] - n[2] * e[1];
    t1[1] = n[2] * e[0] - n[0] * e[2];
    t1[2] = n[0] * e[1] - n[1] * e[0];
    double l = std::sqrt(t1[0] * t1[0] + t1[1] * t1[1] + t1[2] * t1[2]);
    for (int k = 0; k < 3; ++k) t1[k] /= l;
    t2[0] = n[1] * t1[2] - n[2] * t1[1];
    t2[1] = n[2] * t1[0] - n[0] * t1[2];
    t2[2] = n[0] * t1[1] - n[1] * t1[0];
}

}  // namespace pointviz
