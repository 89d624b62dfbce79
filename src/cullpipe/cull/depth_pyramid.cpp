#include "cullpipe/cull/depth_pyramid.hpp"

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

}  // namespace cullpipe::occlusion
