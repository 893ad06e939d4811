// Device-callable building blocks: one function-qualifier macro and small POD math types.
// Everything here compiles with g++ (host only) and with nvcc (host + device), like Sophus' SOPHUS_FUNC.
#pragma once

#include <cmath>
#include <cstdint>

#if defined(__CUDACC__)
#define PERCH2_HD __host__ __device__
#else
#define PERCH2_HD
#endif

namespace perch2 {

PERCH2_HD inline int min_int(int a, int b) {
  return a < b ? a : b;
}
PERCH2_HD inline int max_int(int a, int b) {
  return a > b ? a : b;
}

/// min/max that compile to single instructions (fminf/fmaxf are libm calls on x86 for NaN semantics).
/// NaN: if either argument is NaN the result is b (the comparison fails), so a caller whose first argument
/// may be NaN gets fminf/fmaxf's answer by passing the never-NaN value second.
PERCH2_HD inline float min_f(float a, float b) {
  return a < b ? a : b;
}
PERCH2_HD inline float max_f(float a, float b) {
  return a > b ? a : b;
}

/// floor/ceil to int for |x| < 2^31 without libm calls (floorf/ceilf are calls on baseline x86-64).
PERCH2_HD inline int floor_int(float x) {
  const int i = int(x);
  return i - (x < float(i));
}
PERCH2_HD inline int ceil_int(float x) {
  const int i = int(x);
  return i + (x > float(i));
}

/// The bits of a float and back. Non-negative floats order like their bit patterns (NaN above +inf).
PERCH2_HD inline std::uint32_t float_bits(float f) {
  union {
    float f;
    std::uint32_t u;
  } x{f};
  return x.u;
}
PERCH2_HD inline float bits_float(std::uint32_t u) {
  union {
    std::uint32_t u;
    float f;
  } x{u};
  return x.f;
}

/// (d2, index) as one integer that orders like the pair for d2 >= 0: a minimum picks the nearest point and
/// breaks exact ties by the smaller index (the kNN order, perch2/knn/scan.hpp).
PERCH2_HD inline std::uint64_t pair_key(float d2, std::int32_t index) {
  return (std::uint64_t(float_bits(d2)) << 32) | std::uint32_t(index);
}

struct Vec2f {
  float x, y;
};

struct Vec3f {
  float x, y, z;
};

PERCH2_HD inline Vec3f operator+(Vec3f a, Vec3f b) {
  return {a.x + b.x, a.y + b.y, a.z + b.z};
}
PERCH2_HD inline Vec3f operator-(Vec3f a, Vec3f b) {
  return {a.x - b.x, a.y - b.y, a.z - b.z};
}
PERCH2_HD inline Vec3f operator*(float s, Vec3f a) {
  return {s * a.x, s * a.y, s * a.z};
}
PERCH2_HD inline float dot(Vec3f a, Vec3f b) {
  return a.x * b.x + a.y * b.y + a.z * b.z;
}
PERCH2_HD inline Vec3f cross(Vec3f a, Vec3f b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
PERCH2_HD inline float squared_norm(Vec3f a) {
  return dot(a, a);
}

/// Row-major 3x3 matrix.
struct Mat3f {
  float m[9];
  PERCH2_HD float operator()(int r, int c) const { return m[3 * r + c]; }
};

PERCH2_HD inline Vec3f operator*(const Mat3f& A, Vec3f v) {
  return {A.m[0] * v.x + A.m[1] * v.y + A.m[2] * v.z, A.m[3] * v.x + A.m[4] * v.y + A.m[5] * v.z,
          A.m[6] * v.x + A.m[7] * v.y + A.m[8] * v.z};
}

/// Rigid transform p_dst = R p_src + t (e.g. T_cam_obj maps object points into the camera frame).
struct Rigid3f {
  Mat3f R;
  Vec3f t;
  PERCH2_HD Vec3f operator*(Vec3f p) const { return R * p + t; }
};

/// 8-bit sRGB colour.
struct Rgb8 {
  std::uint8_t r, g, b;
};

PERCH2_HD inline std::uint32_t pack_rgb(Rgb8 c) {
  return (std::uint32_t(c.r) << 16) | (std::uint32_t(c.g) << 8) | std::uint32_t(c.b);
}
PERCH2_HD inline Rgb8 unpack_rgb(std::uint32_t p) {
  return {std::uint8_t((p >> 16) & 0xFF), std::uint8_t((p >> 8) & 0xFF), std::uint8_t(p & 0xFF)};
}

}  // namespace perch2
