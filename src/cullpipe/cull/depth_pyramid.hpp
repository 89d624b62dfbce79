#pragma once
// A depth pyramid: a depth image and a chain of coarser levels whose texels hold the farthest
// depth of every pixel they cover, built bit for bit alike on the CPU (here) and on the GPU
// (gpu::DepthPyramidPass). The occlusion tests (cull/occlusion.hpp) read it.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

namespace cullpipe::occlusion {

/// One level of a pyramid, as stored: row-major floats from `offset` (in floats) in one array.
struct PyramidLevel {
  std::uint32_t width = 0, height = 0;
  std::size_t offset = 0;
  bool operator==(const PyramidLevel&) const = default;
};

/// The levels of the pyramid of a width x height depth image: level 0 is the image itself;
/// level k + 1 is max(1, w_k / 2) x max(1, h_k / 2) (integer halves), down to 1x1. Texel x of
/// level k + 1 covers texels 2x and 2x + 1 of level k, and the last texel of a row also the
/// third one an odd width leaves over (likewise for columns and heights), so every texel
/// covers whole pixels and together they cover each pixel once. Throws std::invalid_argument
/// for a zero width or height.
std::vector<PyramidLevel> pyramid_levels(std::uint32_t width, std::uint32_t height);

/// The texel of a level of width `level_width` covering pixel column x:
/// min(x >> level, level_width - 1) (and likewise rows). Texel t of level k covers pixels
/// [t 2^k, (t + 1) 2^k), and the last texel everything from t 2^k to the image's edge.
constexpr std::uint32_t texel_of(std::uint32_t pixel, unsigned level, std::uint32_t level_width) {
  const std::uint32_t t = pixel >> level;
  return t < level_width ? t : level_width - 1;
}

/// A built pyramid. `reversed_z`: depth 1 is nearest (GREATER depth test), so the farthest depth
/// of a texel is its smallest; otherwise 0 is nearest (LESS) and the farthest is the largest.
struct DepthPyramid {
  std::uint32_t width = 0, height = 0;  ///< of the depth image (level 0)
  bool reversed_z = false;
  std::vector<PyramidLevel> levels;
  std::vector<float> texels;  ///< every level, level k from levels[k].offset

  float at(unsigned level, std::uint32_t x, std::uint32_t y) const {
    const PyramidLevel& l = levels[level];
    return texels[l.offset + std::size_t(y) * l.width + x];
  }
};

/// Builds the pyramid of a width x height depth image (row-major, y down as Vulkan stores it):
/// level 0 is a copy; a texel of a coarser level is the farthest of the texels it covers,
/// taken in row-major order with a strict comparison (a later value replaces the kept one only
/// when strictly farther), as shaders/depth_pyramid.comp does, so that ties of -0 and +0 and
/// NaN resolve alike on both. (A NaN kept as farthest occludes nothing; rasterised depth is
/// never NaN.) Throws std::invalid_argument when depth.size() != width * height or either is 0.
DepthPyramid build_depth_pyramid(std::span<const float> depth, std::uint32_t width, std::uint32_t height,
                                 bool reversed_z);

/// Depth stored as unsigned normalised integers of `bits` bits (16: D16_UNORM; 24: the depth of
/// X8_D24_UNORM_PACK32 and D24_UNORM_S8_UINT), value q meaning q / (2^bits - 1). A fragment's
/// depth is converted to that format before its depth test, so a stored q lets through every
/// fragment whose depth converts to q or nearer: up to (q + 1) / N with N = 2^bits - 1 (q - 1
/// under reversed-Z), the conversion rounding by at most one step. unorm_depth_float gives the
/// float a pyramid keeps for q: that bound, rounded outward (the product (q +- 1) fl(1/N), then
/// three float steps farther; docs/numerics.md, Depth pyramids), in float operations the GPU
/// repeats bit for bit. Throws std::invalid_argument for bits other than 16 or 24.
float unorm_depth_float(std::uint32_t q, unsigned bits, bool reversed_z);
/// build_depth_pyramid of unorm depth: every value through unorm_depth_float first (values past
/// `bits` bits are masked off, as the high byte of a 24-bit depth copy is undefined).
DepthPyramid build_unorm_depth_pyramid(std::span<const std::uint32_t> depth, unsigned bits, std::uint32_t width,
                                       std::uint32_t height, bool reversed_z);

}  // namespace cullpipe::occlusion
