#include "cullpipe/geom/cone.hpp"

#include <bit>
#include <cmath>
#include <cstdint>

#include "cullpipe/geom/rounding.hpp"

namespace cullpipe {

namespace {

bool finite_bits(float f) { return (std::bit_cast<std::uint32_t>(f) & 0x7f800000u) != 0x7f800000u; }

// Margins of the float test (docs/numerics.md, Back-face cones), for roundings of at most 2^-23
// (nearest or toward zero, as Vulkan allows): 2^-17 of the eye's magnitudes (twice its error
// bound, 2^-18, itself 4x the 5 * 2^-23 the analysis needs), 2^-19 of the apex's and the eye's
// coordinates (the rounding of d, of the dot product and of the axis's length: 7 * 2^-23
// needed), 2^-16 on the squared comparison (nine roundings of 2^-23 needed), and 2^-100 added to
// both the margin and the squared bound, which covers subnormal results and their flushing.
constexpr float kEyeMargin = 0x1p-17f;
constexpr float kCoordinateMargin = 0x1p-19f;
constexpr float kSquareMargin = 1.0f + 0x1p-16f;
constexpr float kTiny = 0x1p-100f;
constexpr double kSmallestNormal = 0x1p-126;
// Largest det conditioning (sum of |terms| over |det|) for which the double inverse's entries are
// within 2^-30 of the exact ones, relative to each entry.
constexpr double kMaxConditioning = 0x1p20;

}  // namespace

InverseFrame inverse_frame(const Transform3x4& t) {
  InverseFrame f;
  if (!invalid_reason(t).empty()) return f;
  double m[3][3], tr[3];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m[r][c] = t.rows[std::size_t(r)][c];
    tr[r] = t.rows[std::size_t(r)][3];
  }
  // Cofactors: each a difference of two exact products of floats, so accurate to 2^-53 of
  // itself. The determinant's error is 3 * 2^-53 of the sum of its terms' magnitudes.
  double cof[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const int r1 = (r + 1) % 3, r2 = (r + 2) % 3, c1 = (c + 1) % 3, c2 = (c + 2) % 3;
      cof[r][c] = m[r1][c1] * m[r2][c2] - m[r1][c2] * m[r2][c1];
    }
  const double det = m[0][0] * cof[0][0] + m[0][1] * cof[0][1] + m[0][2] * cof[0][2];
  const double terms = std::abs(m[0][0] * cof[0][0]) + std::abs(m[0][1] * cof[0][1]) + std::abs(m[0][2] * cof[0][2]);
  if (!(det != 0.0) || !std::isfinite(det) || !(terms <= kMaxConditioning * std::abs(det))) return f;
  for (int r = 0; r < 3; ++r) {
    double a[3], b = 0.0, magnitude = 0.0;
    for (int c = 0; c < 3; ++c) {
      a[c] = cof[c][r] / det;  // the inverse is the adjugate (transposed cofactors) over det
      b -= a[c] * tr[c];
      magnitude += std::abs(a[c] * tr[c]);
    }
    for (int c = 0; c < 3; ++c) f.inverse.rows[std::size_t(r)][c] = float(a[c]);
    f.inverse.rows[std::size_t(r)][3] = float(b);
    f.translation_magnitude[r] = round_up(magnitude * (1.0 + 0x1p-40));
  }
  // A value below the smallest normal float may be read as zero (a device that flushes
  // subnormals): its error would be absolute, not relative, so such an inverse is not used.
  bool normal = true;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 4; ++c) {
      const double v = std::abs(double(f.inverse.rows[std::size_t(r)][c]));
      normal = normal && (v == 0.0 || v >= kSmallestNormal);
    }
    const double tm = f.translation_magnitude[r];
    normal = normal && (tm == 0.0 || tm >= kSmallestNormal);
  }
  f.usable = normal && invalid_reason(f.inverse).empty() && finite_bits(f.translation_magnitude.x) &&
             finite_bits(f.translation_magnitude.y) && finite_bits(f.translation_magnitude.z);
  return f;
}

bool facing_away(const BackfaceCone& cone, const InverseFrame& frame, const glm::vec3& eye) {
  // Mirrored by cone_facing_away() in shaders/shared/cone.glsl: same operations, same order.
  if (!frame.usable || !cone.usable()) return false;
  float local[3], magnitude[3];
  for (int i = 0; i < 3; ++i) {
    const glm::vec4& row = frame.inverse.rows[std::size_t(i)];
    const float x = row.x * eye.x, y = row.y * eye.y, z = row.z * eye.z;
    local[i] = ((x + y) + z) + row.w;
    magnitude[i] = (((std::abs(x) + std::abs(y)) + std::abs(z)) + std::abs(row.w)) + frame.translation_magnitude[i];
  }
  const float d0 = cone.apex.x - local[0], d1 = cone.apex.y - local[1], d2 = cone.apex.z - local[2];
  const float along = (d0 * cone.axis.x + d1 * cone.axis.y) + d2 * cone.axis.z;
  const float squared = (d0 * d0 + d1 * d1) + d2 * d2;
  const float coordinates = ((std::abs(cone.apex.x) + std::abs(cone.apex.y)) + std::abs(cone.apex.z)) +
                            ((std::abs(local[0]) + std::abs(local[1])) + std::abs(local[2]));
  const float margin =
      (((magnitude[0] + magnitude[1]) + magnitude[2]) * kEyeMargin + coordinates * kCoordinateMargin) + kTiny;
  const float x = along - margin;
  const float x2 = x * x;
  const float bound = (((cone.cutoff * cone.cutoff) * squared) * kSquareMargin) + kTiny;
  return x > 0.0f && finite_bits(margin) && finite_bits(squared) && finite_bits(x2) && x2 >= bound;
}

}  // namespace cullpipe
