// Device-callable math of the registration stage: SO(3) exponential, rigid-transform composition, symmetric
// 3x3 helpers (smallest eigenvector in closed form or by Jacobi rotations) and a small
// dense Cholesky (LDL^T) solve for the per-hypothesis 6x6 / 3x3 normal equations.
// Everything is PERCH2_HD, float, without std containers or exceptions, so Thrust functors can call it.
#pragma once

#include <cmath>

#include "perch2/core/device.hpp"

namespace perch2::reg {

PERCH2_HD inline bool is_finite(Vec3f v) {
  return fabsf(v.x) <= 3.4e38f && fabsf(v.y) <= 3.4e38f && fabsf(v.z) <= 3.4e38f;  // false for NaN and inf
}

PERCH2_HD inline Mat3f mat3_identity() {
  return {{1, 0, 0, 0, 1, 0, 0, 0, 1}};
}

PERCH2_HD inline Mat3f mat3_mul(const Mat3f& A, const Mat3f& B) {
  Mat3f C{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      C.m[3 * r + c] = A.m[3 * r] * B.m[c] + A.m[3 * r + 1] * B.m[3 + c] + A.m[3 * r + 2] * B.m[6 + c];
  return C;
}

/// Rodrigues: exp([w]x) for a rotation vector w (radians). Uses the Taylor form for tiny angles.
PERCH2_HD inline Mat3f so3_exp(Vec3f w) {
  const float th2 = dot(w, w);
  float a, b;  // R = I + a [w]x + b [w]x^2
  if (th2 < 1e-8f) {
    a = 1.f - th2 / 6.f;
    b = 0.5f - th2 / 24.f;
  } else {
    const float th = sqrtf(th2);
    a = sinf(th) / th;
    b = (1.f - cosf(th)) / th2;
  }
  const float x = w.x, y = w.y, z = w.z;
  // [w]x^2 = w w^T - th2 I
  Mat3f R{};
  R.m[0] = 1.f + b * (x * x - th2);
  R.m[1] = -a * z + b * x * y;
  R.m[2] = a * y + b * x * z;
  R.m[3] = a * z + b * x * y;
  R.m[4] = 1.f + b * (y * y - th2);
  R.m[5] = -a * x + b * y * z;
  R.m[6] = -a * y + b * x * z;
  R.m[7] = a * x + b * y * z;
  R.m[8] = 1.f + b * (z * z - th2);
  return R;
}

/// Left-multiplied increment about a pivot: G(p) = exp([w]x) (p - c) + c + v; returns G * T.
PERCH2_HD inline Rigid3f apply_increment(const Rigid3f& T, Vec3f w, Vec3f v, Vec3f c) {
  const Mat3f dR = so3_exp(w);
  Rigid3f out;
  out.R = mat3_mul(dR, T.R);
  out.t = dR * (T.t - c) + c + v;
  return out;
}

/// Symmetric 3x3 matrix, upper triangle.
struct Sym3 {
  float xx, xy, xz, yy, yz, zz;
};

PERCH2_HD inline Sym3 sym3_add(Sym3 a, Sym3 b) {
  return {a.xx + b.xx, a.xy + b.xy, a.xz + b.xz, a.yy + b.yy, a.yz + b.yz, a.zz + b.zz};
}

PERCH2_HD inline Vec3f sym3_mul(Sym3 a, Vec3f v) {
  return {a.xx * v.x + a.xy * v.y + a.xz * v.z, a.xy * v.x + a.yy * v.y + a.yz * v.z,
          a.xz * v.x + a.yz * v.y + a.zz * v.z};
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix (cyclic Jacobi rotations), or the
/// zero vector if the matrix is zero or not finite. `middle_eigenvalue` receives the middle eigenvalue.
PERCH2_HD inline Vec3f smallest_eigenvector_jacobi(Sym3 s, float* middle_eigenvalue = nullptr) {
  float a[3][3] = {{s.xx, s.xy, s.xz}, {s.xy, s.yy, s.yz}, {s.xz, s.yz, s.zz}};
  float v[3][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}};
  const float scale = fabsf(s.xx) + fabsf(s.yy) + fabsf(s.zz);
  if (!(scale > 0.f) || !(scale < 3.0e38f)) {
    if (middle_eigenvalue) *middle_eigenvalue = 0.f;
    return {0.f, 0.f, 0.f};
  }
  for (int sweep = 0; sweep < 12; ++sweep) {
    const float off = fabsf(a[0][1]) + fabsf(a[0][2]) + fabsf(a[1][2]);
    if (off <= 1e-9f * scale) break;
    for (int p = 0; p < 2; ++p)
      for (int q = p + 1; q < 3; ++q) {
        if (a[p][q] == 0.f) continue;
        const float theta = (a[q][q] - a[p][p]) / (2.f * a[p][q]);
        const float t = (theta >= 0.f ? 1.f : -1.f) / (fabsf(theta) + sqrtf(theta * theta + 1.f));
        const float c = 1.f / sqrtf(t * t + 1.f), sn = t * c;
        for (int k = 0; k < 3; ++k) {  // A <- A J
          const float akp = a[k][p], akq = a[k][q];
          a[k][p] = c * akp - sn * akq;
          a[k][q] = sn * akp + c * akq;
        }
        for (int k = 0; k < 3; ++k) {  // A <- J^T A
          const float apk = a[p][k], aqk = a[q][k];
          a[p][k] = c * apk - sn * aqk;
          a[q][k] = sn * apk + c * aqk;
        }
        for (int k = 0; k < 3; ++k) {  // V <- V J
          const float vkp = v[k][p], vkq = v[k][q];
          v[k][p] = c * vkp - sn * vkq;
          v[k][q] = sn * vkp + c * vkq;
        }
      }
  }
  int lo = 0;
  if (a[1][1] < a[lo][lo]) lo = 1;
  if (a[2][2] < a[lo][lo]) lo = 2;
  if (middle_eigenvalue) {
    const int i1 = (lo + 1) % 3, i2 = (lo + 2) % 3;
    *middle_eigenvalue = min_f(a[i1][i1], a[i2][i2]);
  }
  Vec3f n{v[0][lo], v[1][lo], v[2][lo]};
  const float len = sqrtf(dot(n, n));
  return len > 0.f ? (1.f / len) * n : Vec3f{0.f, 0.f, 0.f};
}

/// Unit eigenvector of the smallest eigenvalue of a symmetric 3x3 matrix, or the zero vector if the matrix
/// is zero or not finite. Closed form (about 5x cheaper than Jacobi rotations): the eigenvalue from the
/// trigonometric solution of the characteristic cubic of the matrix shifted by its mean eigenvalue and
/// scaled to unit trace, the vector as the longest cross product of two rows of A - lambda I. That is
/// accurate to ~1e-7 / g radians, g the gap to the middle eigenvalue relative to the trace; when
/// g < ~1e-3 (no clear smallest direction) the Jacobi rotations decide instead.
PERCH2_HD inline Vec3f smallest_eigenvector(Sym3 s) {
  const float scale = fabsf(s.xx) + fabsf(s.yy) + fabsf(s.zz);
  if (!(scale > 0.f) || !(scale < 3.0e38f)) return {0.f, 0.f, 0.f};
  const float inv = 1.f / scale, mean = (s.xx + s.yy + s.zz) * (1.f / 3.f);
  const float a = (s.xx - mean) * inv, b = (s.yy - mean) * inv, c = (s.zz - mean) * inv;
  const float d = s.xy * inv, e = s.yz * inv, f = s.xz * inv;
  const float p2 = (a * a + b * b + c * c + 2.f * (d * d + e * e + f * f)) * (1.f / 6.f);
  if (p2 > 1e-12f) {
    const float p = sqrtf(p2);
    const float det = a * (b * c - e * e) - d * (d * c - e * f) + f * (d * e - b * f);
    const float r = min_f(max_f(det / (2.f * p2 * p), -1.f), 1.f);
    const float lambda = 2.f * p * cosf(acosf(r) * (1.f / 3.f) + 2.09439510f);  // the smallest root
    const Vec3f r0{a - lambda, d, f}, r1{d, b - lambda, e}, r2{f, e, c - lambda};
    Vec3f best = cross(r0, r1);
    float n2 = dot(best, best);
    const Vec3f c02 = cross(r0, r2), c12 = cross(r1, r2);
    if (dot(c02, c02) > n2) best = c02, n2 = dot(c02, c02);
    if (dot(c12, c12) > n2) best = c12, n2 = dot(c12, c12);
    // sqrt(n2) ~ (middle - smallest) * (largest - smallest) / trace^2.
    if (n2 > 1e-6f && n2 < 3.0e38f) return (1.f / sqrtf(n2)) * best;
  }
  return smallest_eigenvector_jacobi(s);
}

/// Solves A x = b for a symmetric positive-definite N x N matrix (row-major, only the lower triangle read)
/// by LDL^T without pivoting. Returns false if a pivot is not positive and finite.
template <int N>
PERCH2_HD inline bool ldlt_solve(const float* A, const float* b, float* x) {
  float L[N][N];
  float D[N];
  for (int j = 0; j < N; ++j) {
    float d = A[j * N + j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k] * D[k];
    if (!(d > 0.f) || !(d < 3.0e38f)) return false;
    D[j] = d;
    L[j][j] = 1.f;
    for (int i = j + 1; i < N; ++i) {
      float s = A[i * N + j];
      for (int k = 0; k < j; ++k) s -= L[i][k] * L[j][k] * D[k];
      L[i][j] = s / d;
    }
  }
  float y[N];
  for (int i = 0; i < N; ++i) {
    float s = b[i];
    for (int k = 0; k < i; ++k) s -= L[i][k] * y[k];
    y[i] = s;
  }
  for (int i = N - 1; i >= 0; --i) {
    float s = y[i] / D[i];
    for (int k = i + 1; k < N; ++k) s -= L[k][i] * x[k];
    x[i] = s;
  }
  return true;
}

/// Index of entry (r, c), r <= c, of a symmetric 6x6 matrix stored as its 21-entry upper triangle.
PERCH2_HD inline int sym6_index(int r, int c) {
  return r * 6 - r * (r - 1) / 2 + (c - r);
}

}  // namespace perch2::reg
