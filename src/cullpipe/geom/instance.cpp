#include "cullpipe/geom/instance.hpp"

#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>

#include "cullpipe/geom/rounding.hpp"

namespace cullpipe {

namespace {

// The shaders' select forms (shaders/shared/instance.glsl), so a tie between -0 and +0 picks
// the same operand on both sides.
float min_of(float a, float b) { return b < a ? b : a; }
float max_of(float a, float b) { return a < b ? b : a; }
// Decided on the bits, as the shader decides it (a device may treat infinities freely).
bool finite_bits(float f) { return (std::bit_cast<std::uint32_t>(f) & 0x7f800000u) != 0x7f800000u; }

constexpr float kRelativeWidening = 0x1p-20f;
constexpr float kAbsoluteWidening = 0x1p-120f;

}  // namespace

Transform3x4 Transform3x4::from_mat4(const glm::mat4& m) {
  for (int c = 0; c < 4; ++c)
    for (int r = 0; r < 4; ++r)
      if (!std::isfinite(m[c][r]))
        throw std::invalid_argument("transform: row " + std::to_string(r) + " column " + std::to_string(c) +
                                    " is not finite");
  if (m[0][3] != 0.0f || m[1][3] != 0.0f || m[2][3] != 0.0f || m[3][3] != 1.0f)
    throw std::invalid_argument("transform: the last row is (" + std::to_string(m[0][3]) + ", " +
                                std::to_string(m[1][3]) + ", " + std::to_string(m[2][3]) + ", " +
                                std::to_string(m[3][3]) + "), not (0, 0, 0, 1): not an affine transform");
  Transform3x4 t;
  for (int r = 0; r < 3; ++r) t.rows[static_cast<std::size_t>(r)] = {m[0][r], m[1][r], m[2][r], m[3][r]};
  return t;
}

glm::mat4 Transform3x4::to_mat4() const {
  glm::mat4 m(1.0f);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) m[c][r] = rows[static_cast<std::size_t>(r)][c];
  return m;
}

std::string invalid_reason(const Transform3x4& t) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 4; ++c) {
      const float v = t.rows[static_cast<std::size_t>(r)][c];
      if (std::isnan(v)) return "row " + std::to_string(r) + " column " + std::to_string(c) + " is NaN";
      if (std::isinf(v)) return "row " + std::to_string(r) + " column " + std::to_string(c) + " is infinite";
    }
  return {};
}

float max_scale(const Transform3x4& t) {
  double m[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[r][c] = t.rows[static_cast<std::size_t>(r)][c];
  // G = M^T M; sigma_max^2 is its largest eigenvalue, at most any row sum of |G| (Gershgorin)
  // and at most its trace (the squared Frobenius norm).
  double g[3][3], trace = 0.0, gershgorin = 0.0;
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) g[a][b] = m[0][a] * m[0][b] + m[1][a] * m[1][b] + m[2][a] * m[2][b];
  for (int a = 0; a < 3; ++a) {
    trace += g[a][a];
    gershgorin = std::max(gershgorin, std::abs(g[a][0]) + std::abs(g[a][1]) + std::abs(g[a][2]));
  }
  // Each bound is a sum of a few double products (relative error below 2^-50) and sqrt rounds
  // once: 1 + 2^-40 covers both before rounding up to a float.
  const double sigma = std::sqrt(std::min(trace, gershgorin)) * (1.0 + 0x1p-40);
  return round_up(sigma);
}

Aabb instance_volume(const Aabb& local, const Transform3x4& t) {
  // Mirrored by instance_aabb() in shaders/shared/instance.glsl: same operations, same order.
  Aabb world;
  for (int i = 0; i < 3; ++i) {
    const glm::vec4& row = t.rows[static_cast<std::size_t>(i)];
    float lo[3], hi[3], magnitude[3];
    for (int j = 0; j < 3; ++j) {
      const float a = row[j] * local.min[j], b = row[j] * local.max[j];
      lo[j] = min_of(a, b);
      hi[j] = max_of(a, b);
      magnitude[j] = max_of(std::abs(a), std::abs(b));
    }
    const float low = ((lo[0] + lo[1]) + lo[2]) + row.w;
    const float high = ((hi[0] + hi[1]) + hi[2]) + row.w;
    const float sum = ((magnitude[0] + magnitude[1]) + magnitude[2]) + std::abs(row.w);
    const float widening = sum * kRelativeWidening + kAbsoluteWidening;
    if (finite_bits(sum)) {
      world.min[i] = low - widening;
      world.max[i] = high + widening;
    } else {
      world.min[i] = -std::numeric_limits<float>::infinity();
      world.max[i] = std::numeric_limits<float>::infinity();
    }
  }
  return world;
}

Sphere instance_volume(const Sphere& local, const Transform3x4& t, float scale) {
  // Mirrored by instance_sphere() in shaders/shared/instance.glsl.
  Sphere world;
  float magnitude[3];
  for (int i = 0; i < 3; ++i) {
    const glm::vec4& row = t.rows[static_cast<std::size_t>(i)];
    const float x = row.x * local.center.x, y = row.y * local.center.y, z = row.z * local.center.z;
    world.center[i] = ((x + y) + z) + row.w;
    magnitude[i] = ((std::abs(x) + std::abs(y)) + std::abs(z)) + std::abs(row.w);
  }
  const float scaled = local.radius * scale;
  const float widening = (scaled + ((magnitude[0] + magnitude[1]) + magnitude[2])) * kRelativeWidening;
  world.radius = (scaled + widening) + kAbsoluteWidening;
  if (!finite_bits(world.radius)) world = {glm::vec3(0.0f), std::numeric_limits<float>::infinity()};
  return world;
}

Obb instance_volume(const Obb& local, const Transform3x4& t) {
  // The box is the cube [-h, h] in its own frame: frame and transform composed in double.
  glm::dmat4 frame(1.0), m(1.0);
  for (int k = 0; k < 3; ++k) frame[k] = glm::dvec4(glm::dvec3(local.basis[k]), 0.0);
  frame[3] = glm::dvec4(glm::dvec3(local.center), 1.0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) m[j][i] = double(t.rows[static_cast<std::size_t>(i)][j]);
  return Obb::from_transformed_aabb(Aabb{-local.half_extents, local.half_extents}, m * frame);
}

}  // namespace cullpipe
