// CIEDE2000 colour difference and sRGB -> CIELAB (D65), callable on host and device.
//
// The RGB-D cost of PERCH 2.0 counts an observed point as explained only if a rendered point within the
// distance threshold also has a CIEDE2000 difference <= tau_c (paper default 12.5). This header holds the
// colour half of that test, once, for every backend:
//
//   srgb_to_lab<T>(Rgb8)        8-bit sRGB -> CIELAB: IEC 61966-2-1 companding, the sRGB/D65 matrix, and
//                               CIELAB with the D65 reference white (L in [0, 100]).
//   ciede2000<T>(Lab, Lab)      Delta E_00 with kL = kC = kH = 1, following G. Sharma, W. Wu, E. N. Dalal,
//                               "The CIEDE2000 color-difference formula: implementation notes, supplementary
//                               test data, and mathematical observations", Color Res. Appl. 30(1), 2005,
//                               equations (1)-(23), including their hue notes (zero chroma, |dh| > 180 deg,
//                               and the mean-hue cases).
//   ciede2000_srgb(rgb, rgb)    convenience for packed 0xRRGGBB colours (CloudBatch::rgb, pack_rgb()).
//
// T is float or double. Angles are computed in degrees as in the paper (the branch tests compare against 180
// and 360 exactly) and converted to radians only for trigonometry. NaN inputs give a NaN result (never a
// silent 0). No exceptions, no std:: containers: the functions run inside Thrust functors under nvcc.
#pragma once

#include <cmath>
#include <cstdint>

#include "perch2/core/device.hpp"

namespace perch2 {

/// A CIELAB colour: L* in [0, 100], a* and b* unbounded (about [-128, 128] for sRGB).
template <class T>
struct Lab {
  T L, a, b;
};

namespace color_math {
// One overload set for float and double that nvcc accepts in device code and g++ on the host (the C
// functions from <cmath>/<math.h>; the float ones avoid silent promotion to double on the device).
PERCH2_HD inline float sqrt_(float x) {
  return ::sqrtf(x);
}
PERCH2_HD inline double sqrt_(double x) {
  return ::sqrt(x);
}
PERCH2_HD inline float cbrt_(float x) {
  return ::cbrtf(x);
}
PERCH2_HD inline double cbrt_(double x) {
  return ::cbrt(x);
}
PERCH2_HD inline float pow_(float x, float y) {
  return ::powf(x, y);
}
PERCH2_HD inline double pow_(double x, double y) {
  return ::pow(x, y);
}
PERCH2_HD inline float exp_(float x) {
  return ::expf(x);
}
PERCH2_HD inline double exp_(double x) {
  return ::exp(x);
}
PERCH2_HD inline float sin_(float x) {
  return ::sinf(x);
}
PERCH2_HD inline double sin_(double x) {
  return ::sin(x);
}
PERCH2_HD inline float cos_(float x) {
  return ::cosf(x);
}
PERCH2_HD inline double cos_(double x) {
  return ::cos(x);
}
PERCH2_HD inline float atan2_(float y, float x) {
  return ::atan2f(y, x);
}
PERCH2_HD inline double atan2_(double y, double x) {
  return ::atan2(y, x);
}
PERCH2_HD inline float abs_(float x) {
  return ::fabsf(x);
}
PERCH2_HD inline double abs_(double x) {
  return ::fabs(x);
}

template <class T>
PERCH2_HD inline T deg_to_rad(T deg) {
  return deg * T(3.14159265358979323846 / 180.0);
}
template <class T>
PERCH2_HD inline T rad_to_deg(T rad) {
  return rad * T(180.0 / 3.14159265358979323846);
}
template <class T>
PERCH2_HD inline T pow7(T x) {
  const T x2 = x * x;
  return x2 * x2 * x2 * x;
}

/// sRGB electro-optical transfer (IEC 61966-2-1): 8-bit code value -> linear RGB in [0, 1].
template <class T>
PERCH2_HD inline T srgb_to_linear(std::uint8_t code) {
  const T c = T(code) / T(255);
  return c <= T(0.04045) ? c / T(12.92) : pow_((c + T(0.055)) / T(1.055), T(2.4));
}

/// CIELAB companding f(t), with the exact CIE constants epsilon = 216/24389 and kappa = 24389/27
/// (the rationals behind the rounded 0.008856 and 903.3, which make f continuous).
template <class T>
PERCH2_HD inline T lab_f(T t) {
  const T epsilon = T(216.0 / 24389.0);
  const T kappa = T(24389.0 / 27.0);
  return t > epsilon ? cbrt_(t) : (kappa * t + T(16)) / T(116);
}

/// Hue angle h' in degrees, [0, 360) (360 only by rounding, equivalent in every use); 0 for a neutral
/// colour (a' = b = 0), as Sharma et al. eq. (4).
template <class T>
PERCH2_HD inline T hue_deg(T b, T a_prime) {
  if (b == T(0) && a_prime == T(0)) return T(0);
  const T h = rad_to_deg(atan2_(b, a_prime));
  return h < T(0) ? h + T(360) : h;
}
}  // namespace color_math

/// D65 reference white of the sRGB matrix below (XYZ with Y = 1): the matrix rows sum to it.
struct D65White {
  static constexpr double X = 0.95047, Y = 1.0, Z = 1.08883;
};

/// Linear sRGB (1 = reference white; larger values allowed) -> CIELAB (D65). Matrix: linear sRGB -> XYZ for
/// the D65 white (IEC 61966-2-1, as tabulated by B. Lindbloom).
template <class T = float>
PERCH2_HD inline Lab<T> linear_rgb_to_lab(T r, T g, T b) {
  using namespace color_math;
  const T X = T(0.4124564) * r + T(0.3575761) * g + T(0.1804375) * b;
  const T Y = T(0.2126729) * r + T(0.7151522) * g + T(0.0721750) * b;
  const T Z = T(0.0193339) * r + T(0.1191920) * g + T(0.9503041) * b;
  const T fx = lab_f(X / T(D65White::X)), fy = lab_f(Y / T(D65White::Y)), fz = lab_f(Z / T(D65White::Z));
  return {T(116) * fy - T(16), T(500) * (fx - fy), T(200) * (fy - fz)};
}

/// 8-bit sRGB -> CIELAB (D65). White (255, 255, 255) maps to L = 100, a = b = 0; black to L = a = b = 0.
template <class T = float>
PERCH2_HD inline Lab<T> srgb_to_lab(Rgb8 c) {
  using namespace color_math;
  return linear_rgb_to_lab<T>(srgb_to_linear<T>(c.r), srgb_to_linear<T>(c.g), srgb_to_linear<T>(c.b));
}

/// CIEDE2000 colour difference Delta E_00 between two CIELAB colours (kC = kH = 1; the lightness parametric
/// factor kL defaults to 1, the reference conditions; kL = 2 is the standard's textile setting, which halves
/// the weight of lightness differences, e.g. for shading), symmetric and zero for identical colours.
/// Unitless; about 1 is a just-noticeable difference.
template <class T>
PERCH2_HD inline T ciede2000(const Lab<T>& lab1, const Lab<T>& lab2, T kL = T(1)) {
  using namespace color_math;
  const T k25_pow7 = T(6103515625.0);  // 25^7

  // (2)-(6): chroma correction G of a*, then C' and h' per colour.
  const T C1 = sqrt_(lab1.a * lab1.a + lab1.b * lab1.b);
  const T C2 = sqrt_(lab2.a * lab2.a + lab2.b * lab2.b);
  const T C_mean7 = pow7((C1 + C2) / T(2));
  const T G = T(0.5) * (T(1) - sqrt_(C_mean7 / (C_mean7 + k25_pow7)));
  const T a1p = (T(1) + G) * lab1.a, a2p = (T(1) + G) * lab2.a;
  const T C1p = sqrt_(a1p * a1p + lab1.b * lab1.b), C2p = sqrt_(a2p * a2p + lab2.b * lab2.b);
  const T h1p = hue_deg(lab1.b, a1p), h2p = hue_deg(lab2.b, a2p);

  // (8)-(10): differences. The hue difference takes the short way round and is 0 if either chroma is 0.
  const T dLp = lab2.L - lab1.L;
  const T dCp = C2p - C1p;
  const T C1pC2p = C1p * C2p;
  T dhp = T(0);
  if (C1pC2p != T(0)) {
    dhp = h2p - h1p;
    if (dhp > T(180))
      dhp -= T(360);
    else if (dhp < T(-180))
      dhp += T(360);
  }
  const T dHp = T(2) * sqrt_(C1pC2p) * sin_(deg_to_rad(dhp / T(2)));

  // (12)-(14): means. The mean hue is the sum if either chroma is 0, else the mid-angle on the short arc.
  // (With a zero chroma Delta H' = 0, and the mean hue only weights Delta H' through S_H and R_T, so that
  // case cannot change Delta E; it is kept to follow the paper, whose intermediate values it reproduces.)
  const T Lp_mean = (lab1.L + lab2.L) / T(2);
  const T Cp_mean = (C1p + C2p) / T(2);
  const T h_sum = h1p + h2p;
  T hp_mean = h_sum;
  if (C1pC2p != T(0)) {
    if (abs_(h1p - h2p) <= T(180))
      hp_mean = h_sum / T(2);
    else if (h_sum < T(360))
      hp_mean = (h_sum + T(360)) / T(2);
    else
      hp_mean = (h_sum - T(360)) / T(2);
  }

  // (15)-(22): weighting functions and the rotation term.
  const T Tw =
      T(1) - T(0.17) * cos_(deg_to_rad(hp_mean - T(30))) + T(0.24) * cos_(deg_to_rad(T(2) * hp_mean)) +
      T(0.32) * cos_(deg_to_rad(T(3) * hp_mean + T(6))) - T(0.20) * cos_(deg_to_rad(T(4) * hp_mean - T(63)));
  const T dtheta_arg = (hp_mean - T(275)) / T(25);
  const T dtheta_deg = T(30) * exp_(-dtheta_arg * dtheta_arg);
  const T Cp_mean7 = pow7(Cp_mean);
  const T R_C = T(2) * sqrt_(Cp_mean7 / (Cp_mean7 + k25_pow7));
  const T Lm50_sq = (Lp_mean - T(50)) * (Lp_mean - T(50));
  const T S_L = T(1) + T(0.015) * Lm50_sq / sqrt_(T(20) + Lm50_sq);
  const T S_C = T(1) + T(0.045) * Cp_mean;
  const T S_H = T(1) + T(0.015) * Cp_mean * Tw;
  const T R_T = -sin_(deg_to_rad(T(2) * dtheta_deg)) * R_C;

  // (23). |R_T| < 2 makes the form positive definite; the clamp only removes rounding below 0 and keeps NaN.
  const T l = dLp / (kL * S_L), c = dCp / S_C, h = dHp / S_H;
  const T sum = l * l + c * c + h * h + R_T * c * h;
  return sqrt_(sum < T(0) ? T(0) : sum);
}

/// CIEDE2000 between two packed 0xRRGGBB sRGB colours (the CloudBatch::rgb format), in float.
PERCH2_HD inline float ciede2000_srgb(std::uint32_t rgb_a, std::uint32_t rgb_b) {
  return ciede2000(srgb_to_lab<float>(unpack_rgb(rgb_a)), srgb_to_lab<float>(unpack_rgb(rgb_b)));
}

}  // namespace perch2
