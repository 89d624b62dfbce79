#pragma once
#include <cstdint>
#include <string>
#include <vector>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/scene/camera.hpp"

namespace cullpipe::render {

/// An 8-bit RGBA image, rows top to bottom.
struct Image {
  std::uint32_t width = 0;
  std::uint32_t height = 0;
  std::vector<std::uint8_t> rgba;  ///< width * height * 4 bytes

  bool operator==(const Image&) const = default;
};

/// Writes a PNG (stb_image_write). Throws InputError naming the path on failure.
void write_png(const std::string& path, const Image& image);

/// Pixels that differ between two images of the same size (SIZE_MAX when the sizes differ).
std::size_t count_different_pixels(const Image& a, const Image& b);

/// Colours of the classes in debug images.
inline constexpr std::uint32_t kColorInside = 0x3cb44bff;        ///< green
inline constexpr std::uint32_t kColorIntersecting = 0xf0b400ff;  ///< amber
inline constexpr std::uint32_t kColorOutside = 0x5a5f69ff;       ///< grey
inline constexpr std::uint32_t kColorOccluded = 0x8c5ac8ff;      ///< violet
inline constexpr std::uint32_t kColorBackFacing = 0x3c82dcff;    ///< blue (clusters facing away)
inline constexpr std::uint32_t kColorObjectCulled = 0x3a3d44ff;  ///< dark grey (clusters of culled objects)

/// A top-down (looking down -y) debug view drawn on the CPU: every object's world AABB
/// footprint in the x-z plane, filled by its class (outside first, so visible objects stay on
/// top), the frustum's edges projected onto the plane (its far end at `far_limit` from the
/// eye when the far plane is infinite or farther) and the eye. `size` pixels on the longer
/// side of the area shown (the objects' and the frustum's extent).
Image top_down_image(const std::vector<Aabb>& world_boxes, const std::vector<Classification>& classes,
                     const Camera& camera, std::uint32_t size);
/// The same view with each box filled by its own colour (RGBA, 0xRRGGBBAA), in the order given
/// (later boxes on top).
Image top_down_image(const std::vector<Aabb>& world_boxes, const std::vector<std::uint32_t>& colors,
                     const Camera& camera, std::uint32_t size);

/// An orthographic camera looking along -z at `bounds` (a scene's) and `camera`'s eye, from in
/// front of both (the +z side), y up; the view holds their x-y extent with a margin, at
/// `aspect` (width / height). The front debug view of Renderer::class_image.
Camera front_view_camera(const Aabb& bounds, const Camera& camera, float aspect);

/// Draws `camera`'s frustum edges in white and its eye in red over `image`, an image seen by
/// `observer`: each edge clipped to the observer's near plane and to the image. A far plane
/// that is infinite or farther than `far_limit` from the eye is drawn at `far_limit`.
void draw_frustum(Image& image, const Camera& observer, const Camera& camera, float far_limit);

}  // namespace cullpipe::render
