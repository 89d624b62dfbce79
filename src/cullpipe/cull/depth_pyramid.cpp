#include "cullpipe/cull/depth_pyramid.hpp"

#include <bit>
#include <cmath>
#include <stdexcept>
#include <string>

namespace cullpipe::occlusion {

std::vector<PyramidLevel> pyramid_levels(std::uint32_t width, std::uint32_t height) {
  if (width == 0 || height == 0)
    throw std::invalid_argument("depth pyramid: a " + std::to_string(width) + "x" + std::to_string(height) +
                                " depth image has no pixels");
  std::vector<PyramidLevel> levels;
  std::size_t offset = 0;
  for (;;) {
    levels.push_back({width, height, offset});
    offset += std::size_t(width) * height;
    if (width == 1 && height == 1) return levels;
    width = width > 1 ? width / 2 : 1;
    height = height > 1 ? height / 2 : 1;
  }
}

namespace {

/// The source range [first, last] of a texel t of a level of `size` texels whose source level
/// has `source` texels: 2t and 2t + 1, the last texel to the source's end.
void source_range(std::uint32_t t, std::uint32_t size, std::uint32_t source, std::uint32_t& first,
                  std::uint32_t& last) {
  first = source > 1 ? 2 * t : 0;
  last = t + 1 == size ? source - 1 : 2 * t + 1;
}

}  // namespace

DepthPyramid build_depth_pyramid(std::span<const float> depth, std::uint32_t width, std::uint32_t height,
                                 bool reversed_z) {
  DepthPyramid p;
  p.levels = pyramid_levels(width, height);
  if (depth.size() != std::size_t(width) * height)
    throw std::invalid_argument("depth pyramid: " + std::to_string(depth.size()) + " depth values for a " +
                                std::to_string(width) + "x" + std::to_string(height) + " image");
  p.width = width;
  p.height = height;
  p.reversed_z = reversed_z;
  const PyramidLevel& last = p.levels.back();
  p.texels.resize(last.offset + std::size_t(last.width) * last.height);
  std::copy(depth.begin(), depth.end(), p.texels.begin());
  for (std::size_t k = 1; k < p.levels.size(); ++k) {
    const PyramidLevel &src = p.levels[k - 1], &dst = p.levels[k];
    for (std::uint32_t y = 0; y < dst.height; ++y) {
      std::uint32_t y0, y1;
      source_range(y, dst.height, src.height, y0, y1);
      for (std::uint32_t x = 0; x < dst.width; ++x) {
        std::uint32_t x0, x1;
        source_range(x, dst.width, src.width, x0, x1);
        float farthest = p.texels[src.offset + std::size_t(y0) * src.width + x0];
        for (std::uint32_t sy = y0; sy <= y1; ++sy)
          for (std::uint32_t sx = x0; sx <= x1; ++sx) {
            const float d = p.texels[src.offset + std::size_t(sy) * src.width + sx];
            // A NaN wins and stays: it occludes nothing, nor may any texel above it.
            if (!std::isnan(farthest) && (std::isnan(d) || (reversed_z ? d < farthest : d > farthest))) farthest = d;
          }
        p.texels[dst.offset + std::size_t(y) * dst.width + x] = farthest;
      }
    }
  }
  return p;
}

namespace {

// The float k steps away from zero (a positive x: up; a negative one: down), on the bits.
float away_from_zero(float x, std::uint32_t k) { return std::bit_cast<float>(std::bit_cast<std::uint32_t>(x) + k); }
// The float k steps towards zero from a positive x.
float towards_zero(float x, std::uint32_t k) { return std::bit_cast<float>(std::bit_cast<std::uint32_t>(x) - k); }

}  // namespace

float unorm_depth_float(std::uint32_t q, unsigned bits, bool reversed_z) {
  if (bits != 16 && bits != 24)
    throw std::invalid_argument("unorm depth of " + std::to_string(bits) + " bits (16 or 24 are supported)");
  const std::uint32_t n = (1u << bits) - 1u;
  q &= n;
  const float step = static_cast<float>(1.0 / double(n));                        // fl(1/N); the shader gets these bits
  if (!reversed_z) return away_from_zero(static_cast<float>(q + 1u) * step, 3);  // >= (q + 1) / N
  if (q == 0) return -away_from_zero(step, 3);                                   // <= -1 / N
  if (q == 1) return 0.0f;                                                       // (q - 1) / N, exactly
  return towards_zero(static_cast<float>(q - 1u) * step, 3);                     // <= (q - 1) / N
}

DepthPyramid build_unorm_depth_pyramid(std::span<const std::uint32_t> depth, unsigned bits, std::uint32_t width,
                                       std::uint32_t height, bool reversed_z) {
  unorm_depth_float(0, bits, reversed_z);  // (checks bits)
  std::vector<float> floats(depth.size());
  for (std::size_t i = 0; i < depth.size(); ++i) floats[i] = unorm_depth_float(depth[i], bits, reversed_z);
  return build_depth_pyramid(floats, width, height, reversed_z);
}

}  // namespace cullpipe::occlusion
