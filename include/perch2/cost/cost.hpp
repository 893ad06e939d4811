// The cost stage (PERCH eqs. 1-2, C-PERCH eq. 4, PERCH 2.0 RGB-D eq. 5): how well each rendered hypothesis
// explains the observed cloud, and how well the observed points in its volume are explained by it.
//
// Backends implement `Cost` with this interface (perch2/cpu/cost.hpp, perch2/cuda/cost.hpp):
//   explicit Cost(const CloudBatch& observed);       // spatial index + CIELAB colours built once per frame
//   CostResult evaluate(const CloudBatch& rendered, const CostRequest&, const CostSettings&) const;
//
// Definitions, per hypothesis h (rendered cloud h, observed segment s = request.observed_segment[h]):
//   J_r: rendered points of h (already without the pixels hidden by occluders: the renderer drops them)
//        that are outliers with respect to the observed points of segment s.
//   J_o: observed points of segment s inside the volume V(h) that are outliers with respect to the
//        rendered points of h. V(h) is either a convex prism (footprint polygon extruded between two heights
//        in a frame posed by the hypothesis, e.g. the model's footprint above the table in 3-DoF), or, with
//        footprint index -1, the whole segment (6-DoF: the points carrying the instance's label).
//   OUTLIER(p | C): no point of C within delta_m (inclusive). With the RGB-D cost also when the colour test
//        fails for the points of C within delta_m: ColorRule::AnyNeighbour (default): every one differs by
//        more than tau_c in CIEDE2000; ColorRule::Nearest: the nearest one (ties: the smaller index) does.
// Both terms are computed exactly by radius searches in both directions (observed -> rendered and
// rendered -> observed); there is no reverse nearest-neighbour shortcut.
// J = weight_rendered * J_r' + weight_observed * J_o', where ' is the raw count (Normalization::Counts, the
// paper's eq. 1) or the count divided by the points it was taken over (Normalization::Fractions).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <vector>

#include "perch2/color/ciede2000.hpp"
#include "perch2/core/cloud.hpp"
#include "perch2/core/device.hpp"
#include "perch2/core/error.hpp"
#include "perch2/core/mesh.hpp"
#include "perch2/core/pose.hpp"
#include "perch2/render/raster.hpp"

namespace perch2 {

/// Which neighbours within delta decide the colour test of a point.
enum class ColorRule : std::uint8_t {
  /// Some neighbour within delta must be within tau_c: eq. 2's existence test extended to colour. The
  /// default: it tolerates colour misalignment below delta (yaw grid steps on shapes ICP cannot turn,
  /// depth-colour misregistration, label edges). Measured on tests/test_search3dof.cpp's can scene: the
  /// right can at its found pose costs 5 (any) vs 37 (nearest) outliers, while the same can at the other
  /// label's place costs 393 (349 rendered points) under both rules. Points that fail evaluate CIEDE2000
  /// once per neighbour; points that pass stop at the first match.
  AnyNeighbour,
  /// The nearest neighbour within delta (ties: the smaller index) must be within tau_c: eq. 5 read literally
  /// (p'' realises the minimum distance). One CIEDE2000 evaluation per point; stricter at texture edges.
  Nearest,
};

enum class Normalization : std::uint8_t {
  Counts,     ///< J_r, J_o are outlier counts (paper eq. 1)
  Fractions,  ///< J_r / rendered points, J_o / observed points in the volume (0 when the denominator is 0)
};

struct CostSettings {
  float delta_m = 0.0075f;  ///< sensor resolution delta: neighbours farther than this do not explain, metres
  bool use_color = true;    ///< RGB-D cost (PERCH 2.0, eq. 5); false: depth only (PERCH, eq. 2)
  float tau_c = 12.5f;      ///< largest CIEDE2000 difference of two colours considered the same
  /// CIEDE2000 lightness parametric factor kL (>= 1): 1 is the standard's reference conditions (the paper's
  /// implicit choice), 2 its textile setting, which halves the weight of lightness differences (shading,
  /// exposure) against hue and chroma. Default 2: on tests/test_search3dof.cpp's can scene under 70%
  /// lighting with colour and depth noise, the right cans' best poses cost 4 and 6 (of ~350 points) at
  /// kL = 2 but 203 and 317 at kL = 1 (their colour outliers then fail the search's acceptance test),
  /// while a can at the other label's place still costs most of its points. Darker still: kL = 2 holds
  /// down to ~60% lighting, kL = 3 to ~50%, kL = 4 to ~40% (measured on that scene; larger kL also
  /// confuses labels that differ mainly in lightness, e.g. grey vs white).
  float lightness_factor = 2.f;
  /// Compare colours at equal luminance: before the CIELAB conversion every colour is scaled in linear RGB
  /// to the luminance of an 18% grey (at most 10x, so near-black stays dark), which removes what shading,
  /// shadows and exposure do to a surface (they scale its reflected light) and leaves hue and chroma to
  /// decide. A rendered model has the texture's albedo while the camera sees it lit; without this, a
  /// third of a correctly placed object's points can fail the colour test under ordinary lighting. Cost:
  /// lightness alone no longer separates colours (grey vs white); hue and chroma still do.
  bool shading_invariant = true;
  ColorRule color_rule = ColorRule::AnyNeighbour;
  Normalization normalization = Normalization::Counts;
  float weight_rendered = 1.f;  ///< weight of J_r in the total (>= 0)
  float weight_observed = 1.f;  ///< weight of J_o in the total (>= 0)
};

/// A convex prism in its own frame: the polygon (counter-clockwise in x-y, metres) extruded over
/// z in [z_min_m, z_max_m].
struct Footprint {
  std::vector<Eigen::Vector2f> polygon_xy_m;
  float z_min_m = 0.f, z_max_m = 0.f;
};

/// Per hypothesis: which observed segment it is compared with and which volume its J_o counts over.
struct CostRequest {
  std::vector<Footprint> footprints;           ///< shapes shared by hypotheses (e.g. one per model)
  std::vector<std::int32_t> observed_segment;  ///< per hypothesis: segment of the observed batch
  std::vector<std::int32_t> footprint;         ///< per hypothesis: index into footprints, -1 = whole segment
  std::vector<Pose> T_cam_volume;              ///< per hypothesis: footprint frame -> camera

  std::size_t size() const { return observed_segment.size(); }
  /// Appends a hypothesis whose volume is footprint `f` posed at T_cam_volume (f = -1: whole segment).
  void add(std::int32_t segment, std::int32_t f = -1, const Pose& T = Pose::Identity()) {
    observed_segment.push_back(segment), footprint.push_back(f), T_cam_volume.push_back(T);
  }
};

/// One hypothesis' cost and the counts behind it.
struct CostBreakdown {
  std::int32_t rendered_points = 0;          ///< points of the rendered cloud
  std::int32_t rendered_inliers = 0;         ///< ... explained by the observed points
  std::int32_t rendered_depth_outliers = 0;  ///< ... with no observed point within delta
  std::int32_t rendered_color_outliers = 0;  ///< ... with observed points within delta, none matching colour
  std::int32_t observed_in_volume = 0;       ///< observed points inside the hypothesis' volume
  std::int32_t observed_depth_outliers = 0;  ///< ... with no rendered point within delta
  std::int32_t observed_color_outliers = 0;  ///< ... with rendered points within delta, none matching colour
  float J_r = 0.f, J_o = 0.f;                ///< after normalisation, before weighting
  float total = 0.f;                         ///< weight_rendered * J_r + weight_observed * J_o

  std::int32_t observed_unexplained() const { return observed_depth_outliers + observed_color_outliers; }
  std::int32_t rendered_outliers() const { return rendered_depth_outliers + rendered_color_outliers; }
};

struct CostResult {
  std::vector<CostBreakdown> hypotheses;
  std::size_t size() const { return hypotheses.size(); }
};

// ---- device-callable pieces shared by every backend ----------------------------------------------------

/// Point classes of the outlier test.
enum PointClass : std::uint8_t { kInlier = 0, kDepthOutlier = 1, kColorOutlier = 2 };

/// Accumulates the neighbours of one point (within delta) and classifies it. Feed every neighbour to
/// visit(); the result does not depend on the visiting order.
struct OutlierVote {
  Lab<float> lab;            ///< the point's colour
  const Lab<float>* others;  ///< colours of the searched cloud (global index)
  float tau_c;
  float kL;
  bool use_color;
  bool any_rule;
  bool found = false, color_match = false;
  float best_d2 = 0.f;
  std::int32_t best = -1;

  /// Adds a neighbour. known_failure: its colour is known to fail the colour test with this point (see
  /// FailedColours), so CIEDE2000 is skipped. Returns true if CIEDE2000 ran and failed.
  PERCH2_HD bool operator()(std::int32_t index, float d2, bool known_failure = false) {
    if (!found || d2 < best_d2 || (d2 == best_d2 && index < best)) best_d2 = d2, best = index;
    found = true;
    if (!use_color || !any_rule || color_match || known_failure) return false;
    color_match = ciede2000<float>(lab, others[index], kL) <= tau_c;
    return !color_match;
  }
  /// True once no further neighbour can change result(): a depth-only inlier, or an AnyNeighbour colour
  /// match (searches may stop there).
  PERCH2_HD bool done() const { return found && (!use_color || (any_rule && color_match)); }
  PERCH2_HD std::uint8_t result() const {
    if (!found) return kDepthOutlier;
    if (!use_color) return kInlier;
    const bool ok = any_rule ? color_match : ciede2000<float>(lab, others[best], kL) <= tau_c;
    return ok ? kInlier : kColorOutlier;
  }
};

/// J_o without a search of its own. The J_r search of a rendered point p of hypothesis h visits every
/// observed point o of h's segment within delta of p; those with o inside V(h) are exactly the pairs a J_o
/// search of o among h's rendered points would visit (the squared distance is symmetric bit for bit:
/// (a - b)^2 == (b - a)^2, summed over x, y, z in the same order). So each observed point of V(h) keeps a
/// record filled from the J_r search: flags (kPairFound, kPairColorMatch) and, for ColorRule::Nearest, the
/// smallest pair_key(d2, p). Flags only get set and the key only decreases, so the record does not depend on
/// the order in which pairs arrive (threads may update it concurrently with atomics).
enum : std::uint32_t { kPairFound = 1u, kPairColorMatch = 2u };
constexpr std::uint64_t kNoPair = ~std::uint64_t(0);

/// Rendered colours known to fail the AnyNeighbour colour test with an observed point: per observed point
/// and direction (J_r evaluates CIEDE2000(rendered, observed), J_o CIEDE2000(observed, rendered), kept apart
/// since rounding need not be symmetric) a direct-mapped set of kFailedSlots packed-rgb keys. Lab is a
/// function of the packed rgb, so a remembered colour fails again and skipping its CIEDE2000 is exact;
/// whatever a slot holds did fail, so a slot overwritten or read by a racing thread is still safe. Rendered
/// objects show few colours: on bench_search3dof's seed-8 scene 0 a 4-entry set per observed point skipped
/// 53% of the J_r evaluations.
struct FailedColours {
  static constexpr int kSlots = 8;
  std::uint32_t* keys;  ///< [observed point][kSlots], 0 = empty
  /// The key of a packed colour (0, never stored, for values outside 0xRRGGBB).
  PERCH2_HD static std::uint32_t key(std::uint32_t rgb) { return rgb < 0x1000000u ? rgb + 1u : 0u; }
  PERCH2_HD std::uint32_t* slot(std::int32_t observed, std::uint32_t key) const {
    return keys + std::int64_t(observed) * kSlots + ((key * 2654435761u) >> 29);
  }
};

/// The colour half of OutlierVote for one observed point: lab is its colour, rendered the searched colours.
struct PairColorTest {
  float tau_c;
  float kL;
  bool use_color;
  bool any_rule;

  /// The colour test of pair (observed colour lab, rendered point p): CIEDE2000 with the observed colour
  /// first, as the OutlierVote of the observed point would run it.
  PERCH2_HD bool matches(Lab<float> lab, const Lab<float>* rendered, std::int32_t p) const {
    return ciede2000<float>(lab, rendered[p], kL) <= tau_c;
  }
  /// PointClass of the observed point from its record; equal to OutlierVote::result() over the same pairs.
  PERCH2_HD std::uint8_t result(std::uint32_t flags, std::uint64_t nearest, Lab<float> lab,
                                const Lab<float>* rendered) const {
    if (!(flags & kPairFound)) return kDepthOutlier;
    if (!use_color) return kInlier;
    const bool ok = any_rule ? (flags & kPairColorMatch) != 0u
                             : matches(lab, rendered, std::int32_t(nearest & 0xffffffffu));
    return ok ? kInlier : kColorOutlier;
  }
};

/// Device form of a posed prism: camera -> footprint frame, the polygon, the height range, and a bounding
/// sphere in the camera frame (candidates outside it are never inside).
struct VolumeView {
  Rigid3f T_vol_cam;
  std::int32_t vertex_begin = 0, vertex_end = 0;  ///< into the polygon vertex array
  float z_min_m = 0.f, z_max_m = 0.f;
  Vec3f centre_cam{0.f, 0.f, 0.f};
  float radius_m = 0.f;
};

/// True if camera-frame point p lies inside the prism (boundary included).
PERCH2_HD inline bool inside_volume(const VolumeView& v, const Vec2f* vertices, Vec3f p_cam) {
  const Vec3f p = v.T_vol_cam * p_cam;
  if (!(p.z >= v.z_min_m && p.z <= v.z_max_m)) return false;
  for (std::int32_t i = v.vertex_begin; i < v.vertex_end; ++i) {
    const Vec2f a = vertices[i], b = vertices[i + 1 < v.vertex_end ? i + 1 : v.vertex_begin];
    if ((b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x) < 0.f) return false;
  }
  return true;
}

// ---- host helpers shared by every backend --------------------------------------------------------------

namespace cost_detail {

/// Convex hull (counter-clockwise, no collinear points) of 2-D points (Andrew's monotone chain).
inline std::vector<Eigen::Vector2f> convex_hull(std::vector<Eigen::Vector2f> pts) {
  std::sort(pts.begin(), pts.end(), [](const Eigen::Vector2f& a, const Eigen::Vector2f& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  pts.erase(std::unique(pts.begin(), pts.end()), pts.end());
  if (pts.size() < 3) return pts;
  auto turn = [](const Eigen::Vector2f& o, const Eigen::Vector2f& a, const Eigen::Vector2f& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2f> h(2 * pts.size());
  std::size_t k = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    while (k >= 2 && turn(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  for (std::size_t i = pts.size() - 1, t = k + 1; i-- > 0;) {
    while (k >= t && turn(h[k - 2], h[k - 1], pts[i]) <= 0) --k;
    h[k++] = pts[i];
  }
  h.resize(k - 1);
  // Vertices closer than a micrometre (rounding of one vertex computed twice) would make zero-length edges.
  std::vector<Eigen::Vector2f> out;
  for (const auto& p : h)
    if (out.empty() || (p - out.back()).norm() > 1e-6f) out.push_back(p);
  while (out.size() > 1 && (out.back() - out.front()).norm() <= 1e-6f) out.pop_back();
  return out;
}

}  // namespace cost_detail

/// The prism a model occupies standing on a table: the convex hull of its vertices' x-y in the table-aligned
/// frame T_place_obj (object -> placement frame, z up, table at z = 0), from z_floor_m (above the table, so
/// table readings never count) to the model's top.
inline Footprint table_footprint(const Mesh& model, const Pose& T_place_obj, float z_floor_m) {
  std::vector<Eigen::Vector2f> xy;
  float top = -std::numeric_limits<float>::infinity();
  for (const auto& v : model.vertices) {
    const Eigen::Vector3f p = T_place_obj * v;
    xy.emplace_back(p.x(), p.y());
    top = std::max(top, p.z());
  }
  Footprint f;
  f.polygon_xy_m = cost_detail::convex_hull(std::move(xy));
  f.z_min_m = z_floor_m;
  f.z_max_m = top;
  return f;
}

namespace cost_detail {

inline void check_settings(const CostSettings& s) {
  if (!(std::isfinite(s.delta_m) && s.delta_m > 0))
    throw InvalidInput("CostSettings::delta_m", "must be finite and > 0");
  if (!(std::isfinite(s.tau_c) && s.tau_c >= 0))
    throw InvalidInput("CostSettings::tau_c", "must be finite, >= 0");
  if (!(std::isfinite(s.lightness_factor) && s.lightness_factor >= 1))
    throw InvalidInput("CostSettings::lightness_factor", "must be finite and >= 1");
  if (s.color_rule != ColorRule::AnyNeighbour && s.color_rule != ColorRule::Nearest)
    throw InvalidInput("CostSettings::color_rule", "unknown value");
  if (s.normalization != Normalization::Counts && s.normalization != Normalization::Fractions)
    throw InvalidInput("CostSettings::normalization", "unknown value");
  if (!(std::isfinite(s.weight_rendered) && s.weight_rendered >= 0))
    throw InvalidInput("CostSettings::weight_rendered", "must be finite and >= 0");
  if (!(std::isfinite(s.weight_observed) && s.weight_observed >= 0))
    throw InvalidInput("CostSettings::weight_observed", "must be finite and >= 0");
}

inline void check_cloud(const CloudBatch& c, const std::string& name) {
  c.validate(name);
  for (std::size_t i = 0; i < c.size(); ++i)
    if (!(std::isfinite(c.x[i]) && std::isfinite(c.y[i]) && std::isfinite(c.z[i])))
      throw InvalidInput(name, "point " + std::to_string(i) + " is not finite");
}

inline void check_footprint(const Footprint& f, std::size_t i) {
  const std::string who = "CostRequest::footprints[" + std::to_string(i) + "]";
  const auto& p = f.polygon_xy_m;
  if (p.size() < 3) throw InvalidInput(who, "polygon needs at least 3 vertices");
  for (const auto& v : p)
    if (!v.allFinite()) throw InvalidInput(who, "polygon has a non-finite vertex");
  if (!(std::isfinite(f.z_min_m) && std::isfinite(f.z_max_m) && f.z_max_m >= f.z_min_m))
    throw InvalidInput(who, "needs finite z_min_m <= z_max_m");
  for (std::size_t k = 0; k < p.size(); ++k) {
    const Eigen::Vector2f a = p[k], b = p[(k + 1) % p.size()], c = p[(k + 2) % p.size()];
    if ((b - a).x() * (c - b).y() - (b - a).y() * (c - b).x() < 0)
      throw InvalidInput(who, "polygon must be convex and counter-clockwise");
  }
}

}  // namespace cost_detail

/// Throws InvalidInput for an empty observed batch, malformed or non-finite points.
inline void validate_cost_observed(const CloudBatch& observed) {
  cost_detail::check_cloud(observed, "cost: observed cloud");
  if (observed.num_clouds() == 0) throw InvalidInput("cost: observed cloud", "has no segments");
}

/// Throws InvalidInput for zero hypotheses, mismatched sizes, non-finite points or poses, bad footprints,
/// out-of-range indices or bad settings. Shared by every backend so all reject the same inputs alike.
inline void validate_cost_request(const CloudBatch& rendered, const CostRequest& r, std::size_t num_segments,
                                  const CostSettings& s) {
  cost_detail::check_settings(s);
  cost_detail::check_cloud(rendered, "cost: rendered clouds");
  const std::size_t n = rendered.num_clouds();
  if (n == 0) throw InvalidInput("cost: rendered clouds", "no hypotheses to score");
  if (r.observed_segment.size() != n || r.footprint.size() != n || r.T_cam_volume.size() != n)
    throw InvalidInput("CostRequest",
                       "needs one observed_segment, footprint and T_cam_volume per rendered "
                       "cloud (" +
                           std::to_string(n) + "), got " + std::to_string(r.observed_segment.size()) + ", " +
                           std::to_string(r.footprint.size()) + ", " + std::to_string(r.T_cam_volume.size()));
  for (std::size_t i = 0; i < r.footprints.size(); ++i) cost_detail::check_footprint(r.footprints[i], i);
  for (std::size_t h = 0; h < n; ++h) {
    const std::string who = "CostRequest hypothesis " + std::to_string(h);
    if (r.observed_segment[h] < 0 || std::size_t(r.observed_segment[h]) >= num_segments)
      throw InvalidInput(who, "observed segment " + std::to_string(r.observed_segment[h]) +
                                  " out of range (" + std::to_string(num_segments) + " segments)");
    if (r.footprint[h] < -1 || r.footprint[h] >= std::int32_t(r.footprints.size()))
      throw InvalidInput(who, "footprint " + std::to_string(r.footprint[h]) + " out of range (" +
                                  std::to_string(r.footprints.size()) + " footprints, -1 = whole segment)");
    if (r.footprint[h] >= 0 && !is_valid_pose(r.T_cam_volume[h]))
      throw InvalidInput(who, "T_cam_volume is not a finite rigid transform");
  }
}

/// Flat device-ready form of a request's volumes (the polygon vertices and one VolumeView per hypothesis;
/// radius_m = -1 marks "whole segment").
struct PackedVolumes {
  std::vector<Vec2f> vertices;
  std::vector<VolumeView> views;
};

inline PackedVolumes pack_volumes(const CostRequest& r) {
  PackedVolumes out;
  std::vector<std::int32_t> begin;
  for (const auto& f : r.footprints) {
    begin.push_back(std::int32_t(out.vertices.size()));
    for (const auto& v : f.polygon_xy_m) out.vertices.push_back({v.x(), v.y()});
  }
  out.views.resize(r.size());
  for (std::size_t h = 0; h < r.size(); ++h) {
    VolumeView& v = out.views[h];
    if (r.footprint[h] < 0) {
      v.radius_m = -1.f;
      continue;
    }
    const Footprint& f = r.footprints[std::size_t(r.footprint[h])];
    v.T_vol_cam = to_rigid(r.T_cam_volume[h].inverse());
    v.vertex_begin = begin[std::size_t(r.footprint[h])];
    v.vertex_end = v.vertex_begin + std::int32_t(f.polygon_xy_m.size());
    v.z_min_m = f.z_min_m, v.z_max_m = f.z_max_m;
    const float zc = 0.5f * (f.z_min_m + f.z_max_m), hz = 0.5f * (f.z_max_m - f.z_min_m);
    float r2 = 0.f;
    for (const auto& p : f.polygon_xy_m) r2 = std::max(r2, p.squaredNorm());
    // Widened by a relative and absolute slack so rounding in the transform never drops a boundary point.
    v.radius_m = std::sqrt(r2 + hz * hz) * 1.001f + 1e-4f;
    v.centre_cam = to_vec3(r.T_cam_volume[h] * Eigen::Vector3f(0.f, 0.f, zc));
  }
  return out;
}

/// Fills J_r, J_o and the total of a breakdown from its counts (host, identical on every backend).
inline void finish_cost(CostBreakdown& b, const CostSettings& s) {
  const float r_out = float(b.rendered_outliers()), o_out = float(b.observed_unexplained());
  if (s.normalization == Normalization::Fractions) {
    b.J_r = b.rendered_points > 0 ? r_out / float(b.rendered_points) : 0.f;
    b.J_o = b.observed_in_volume > 0 ? o_out / float(b.observed_in_volume) : 0.f;
  } else {
    b.J_r = r_out, b.J_o = o_out;
  }
  b.total = s.weight_rendered * b.J_r + s.weight_observed * b.J_o;
}

/// The CIELAB colour the colour test compares for a packed sRGB colour (see
/// CostSettings::shading_invariant).
PERCH2_HD inline Lab<float> comparison_lab(std::uint32_t rgb, bool shading_invariant) {
  const Rgb8 c = unpack_rgb(rgb);
  float r = color_math::srgb_to_linear<float>(c.r), g = color_math::srgb_to_linear<float>(c.g),
        b = color_math::srgb_to_linear<float>(c.b);
  if (shading_invariant) {
    constexpr float kGrey = 0.18f, kMaxGain = 10.f;  // target luminance (L* ~ 50), largest scale
    const float Y = 0.2126729f * r + 0.7151522f * g + 0.0721750f * b;
    const float gain = kGrey / (Y > kGrey / kMaxGain ? Y : kGrey / kMaxGain);
    r *= gain, g *= gain, b *= gain;
  }
  return linear_rgb_to_lab<float>(r, g, b);
}

/// Comparison colours of a batch's points (CloudBatch::rgb, packed sRGB). Rendered batches repeat few colours
/// (bench_search3dof's seed-8 scene 0: 8,857 distinct in 1.9 M points), so conversions are remembered in a
/// direct-mapped table by packed colour: the same function of the same value, identical results.
inline std::vector<Lab<float>> lab_colors(const CloudBatch& c, bool shading_invariant) {
  constexpr int kBits = 14;
  std::vector<std::uint64_t> key(std::size_t(1) << kBits, ~std::uint64_t(0));  // no packed colour
  std::vector<Lab<float>> value(key.size());
  std::vector<Lab<float>> out(c.size());
  for (std::size_t i = 0; i < c.size(); ++i) {
    const std::uint32_t rgb = c.rgb[i];
    const std::size_t slot = (rgb * 2654435761u) >> (32 - kBits);
    if (key[slot] != rgb) key[slot] = rgb, value[slot] = comparison_lab(rgb, shading_invariant);
    out[i] = value[slot];
  }
  return out;
}

}  // namespace perch2
