#include "cullpipe/render/image.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <glm/ext/vector_double2.hpp>
#include <glm/ext/vector_double4.hpp>
#include <glm/geometric.hpp>
#include <glm/mat4x4.hpp>
#include <glm/matrix.hpp>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

#include "cullpipe/scene/scene.hpp"

#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>

namespace cullpipe::render {
namespace {

struct Canvas {
  Image& image;
  void put(int x, int y, std::uint32_t rgba) {
    if (x < 0 || y < 0 || x >= int(image.width) || y >= int(image.height)) return;
    std::uint8_t* p = image.rgba.data() + (std::size_t(y) * image.width + std::size_t(x)) * 4;
    p[0] = std::uint8_t(rgba >> 24);
    p[1] = std::uint8_t(rgba >> 16);
    p[2] = std::uint8_t(rgba >> 8);
    p[3] = std::uint8_t(rgba);
  }
  void fill(int x0, int y0, int x1, int y1, std::uint32_t rgba) {
    x0 = std::max(x0, 0), y0 = std::max(y0, 0);
    x1 = std::min(x1, int(image.width) - 1), y1 = std::min(y1, int(image.height) - 1);
    for (int y = y0; y <= y1; ++y)
      for (int x = x0; x <= x1; ++x) put(x, y, rgba);
  }
  void line(int x0, int y0, int x1, int y1, std::uint32_t rgba) {  // Bresenham
    const int dx = std::abs(x1 - x0), dy = -std::abs(y1 - y0), sx = x0 < x1 ? 1 : -1, sy = y0 < y1 ? 1 : -1;
    int err = dx + dy;
    for (int guard = 0; guard < 1 << 16; ++guard) {
      put(x0, y0, rgba);
      if (x0 == x1 && y0 == y1) break;
      const int e2 = 2 * err;
      if (e2 >= dy) err += dy, x0 += sx;
      if (e2 <= dx) err += dx, y0 += sy;
    }
  }
};

std::uint32_t darker(std::uint32_t c) {
  const auto ch = [&](int shift) { return std::uint32_t(((c >> shift) & 0xff) * 3 / 5) << shift; };
  return ch(24) | ch(16) | ch(8) | (c & 0xff);
}

// The frustum's corners: the clip-space corners unprojected; a far plane that is infinite or
// farther than `far_limit` from the eye is cut there so the drawing stays readable. Bit k of the
// index set: +x (k = 0), +y (k = 1), far (k = 2).
std::array<glm::vec3, 8> frustum_corners(const Camera& camera, float far_limit) {
  Camera cut = camera;
  if (!cut.orthographic) {
    cut.infinite_far = false;
    cut.far_plane = std::min(camera.infinite_far ? far_limit : camera.far_plane, far_limit);
    cut.far_plane = std::max(cut.far_plane, cut.near_plane * 2.0f);
  }
  const glm::mat4 inv = glm::inverse(cut.view_proj());
  std::array<glm::vec3, 8> corners;
  for (int i = 0; i < 8; ++i) {
    const glm::vec4 clip((i & 1) ? 1.0f : -1.0f, (i & 2) ? 1.0f : -1.0f, (i & 4) ? 1.0f : 0.0f, 1.0f);
    const glm::vec4 w = inv * clip;
    corners[std::size_t(i)] = glm::vec3(w) / w.w;
  }
  return corners;
}

// Frustum edges as corner pairs: near quad, far quad, and the four side edges.
constexpr int kFrustumEdges[12][2] = {{0, 1}, {1, 3}, {3, 2}, {2, 0}, {4, 5}, {5, 7},
                                      {7, 6}, {6, 4}, {0, 4}, {1, 5}, {2, 6}, {3, 7}};

}  // namespace

void write_png(const std::string& path, const Image& image) {
  if (image.width == 0 || image.height == 0 || image.rgba.size() != std::size_t(image.width) * image.height * 4)
    throw InputError(path + ": cannot write an empty or inconsistent image");
  // Encoded in memory, then written atomically: a failed or interrupted write never leaves a
  // truncated PNG in place of an earlier one.
  std::string png;
  const auto append = [](void* context, void* data, int size) {
    static_cast<std::string*>(context)->append(static_cast<const char*>(data), std::size_t(size));
  };
  if (!stbi_write_png_to_func(append, &png, int(image.width), int(image.height), 4, image.rgba.data(),
                              int(image.width * 4)))
    throw InputError(path + ": cannot encode the PNG image");
  write_file_atomic(path, png);
}

std::size_t count_different_pixels(const Image& a, const Image& b) {
  if (a.width != b.width || a.height != b.height || a.rgba.size() != b.rgba.size())
    return std::numeric_limits<std::size_t>::max();
  std::size_t n = 0;
  for (std::size_t i = 0; i < a.rgba.size(); i += 4)
    if (a.rgba[i] != b.rgba[i] || a.rgba[i + 1] != b.rgba[i + 1] || a.rgba[i + 2] != b.rgba[i + 2] ||
        a.rgba[i + 3] != b.rgba[i + 3])
      ++n;
  return n;
}

Image top_down_image(const std::vector<Aabb>& world_boxes, const std::vector<Classification>& classes,
                     const Camera& camera, std::uint32_t size) {
  // Outside, then occluded, intersecting and inside on top.
  const Classification order[4] = {Classification::Outside, Classification::Occluded, Classification::Intersecting,
                                   Classification::Inside};
  const std::uint32_t colors[4] = {kColorOutside, kColorOccluded, kColorIntersecting, kColorInside};
  std::vector<Aabb> boxes;
  std::vector<std::uint32_t> box_colors;
  for (int pass = 0; pass < 4; ++pass)
    for (std::size_t i = 0; i < world_boxes.size() && i < classes.size(); ++i)
      if (classes[i] == order[pass]) boxes.push_back(world_boxes[i]), box_colors.push_back(colors[pass]);
  return top_down_image(boxes, box_colors, camera, size);
}

Image top_down_image(const std::vector<Aabb>& world_boxes, const std::vector<std::uint32_t>& colors,
                     const Camera& camera, std::uint32_t size) {
  float lo_x = camera.eye.x, hi_x = camera.eye.x, lo_z = camera.eye.z, hi_z = camera.eye.z;
  for (const Aabb& b : world_boxes) {
    lo_x = std::min(lo_x, b.min.x), hi_x = std::max(hi_x, b.max.x);
    lo_z = std::min(lo_z, b.min.z), hi_z = std::max(hi_z, b.max.z);
  }
  const float extent = std::max({hi_x - lo_x, hi_z - lo_z, 1e-3f});
  const float far_limit = 2.0f * extent + glm::length(camera.target - camera.eye);
  const std::array<glm::vec3, 8> corners = frustum_corners(camera, far_limit);
  for (int i = 0; i < 8; ++i) {
    lo_x = std::min(lo_x, corners[std::size_t(i)].x), hi_x = std::max(hi_x, corners[std::size_t(i)].x);
    lo_z = std::min(lo_z, corners[std::size_t(i)].z), hi_z = std::max(hi_z, corners[std::size_t(i)].z);
  }
  const float span = std::max({hi_x - lo_x, hi_z - lo_z, 1e-3f}) * 1.04f;
  const float cx = 0.5f * (lo_x + hi_x), cz = 0.5f * (lo_z + hi_z);
  const float w_world = std::max(hi_x - lo_x, 1e-3f) * 1.04f, h_world = std::max(hi_z - lo_z, 1e-3f) * 1.04f;
  Image img;
  const float scale = float(size) / span;
  img.width = std::max<std::uint32_t>(16, std::uint32_t(std::ceil(w_world * scale)));
  img.height = std::max<std::uint32_t>(16, std::uint32_t(std::ceil(h_world * scale)));
  img.rgba.assign(std::size_t(img.width) * img.height * 4, 0);
  Canvas c{img};
  c.fill(0, 0, int(img.width) - 1, int(img.height) - 1, 0x16181dff);
  const auto px = [&](float x) { return int(std::floor((x - cx) * scale + 0.5f * float(img.width))); };
  const auto pz = [&](float z) { return int(std::floor((z - cz) * scale + 0.5f * float(img.height))); };

  for (std::size_t i = 0; i < world_boxes.size() && i < colors.size(); ++i) {
    const Aabb& b = world_boxes[i];
    const std::uint32_t color = colors[i];
    const int x0 = px(b.min.x), x1 = px(b.max.x), z0 = pz(b.min.z), z1 = pz(b.max.z);
    c.fill(x0, z0, x1, z1, color);
    if (x1 - x0 > 3 && z1 - z0 > 3) {
      c.line(x0, z0, x1, z0, darker(color)), c.line(x1, z0, x1, z1, darker(color));
      c.line(x1, z1, x0, z1, darker(color)), c.line(x0, z1, x0, z0, darker(color));
    }
  }
  for (const auto& e : kFrustumEdges) {
    const glm::vec3& a = corners[std::size_t(e[0])];
    const glm::vec3& b = corners[std::size_t(e[1])];
    c.line(px(a.x), pz(a.z), px(b.x), pz(b.z), 0xffffffff);
  }
  c.fill(px(camera.eye.x) - 3, pz(camera.eye.z) - 3, px(camera.eye.x) + 3, pz(camera.eye.z) + 3, 0xff4040ff);
  return img;
}

Camera front_view_camera(const Aabb& bounds, const Camera& camera, float aspect) {
  float lo_x = camera.eye.x, hi_x = camera.eye.x, lo_y = camera.eye.y, hi_y = camera.eye.y;
  float lo_z = camera.eye.z, hi_z = camera.eye.z;
  if (bounds.min.x <= bounds.max.x) {
    lo_x = std::min(lo_x, bounds.min.x), hi_x = std::max(hi_x, bounds.max.x);
    lo_y = std::min(lo_y, bounds.min.y), hi_y = std::max(hi_y, bounds.max.y);
    lo_z = std::min(lo_z, bounds.min.z), hi_z = std::max(hi_z, bounds.max.z);
  }
  const float a = aspect > 0.0f && std::isfinite(aspect) ? aspect : 1.0f;
  const float half_height = std::max({0.5f * (hi_y - lo_y), 0.5f * (hi_x - lo_x) / a, 1e-3f}) * 1.06f;
  const float depth = std::max(hi_z - lo_z, 1e-3f);
  Camera front;
  front.orthographic = true;
  front.ortho_half_height = half_height;
  front.aspect = a;
  // From in front of everything, at a distance of a twentieth of the depth shown.
  const float margin = 0.05f * depth + 1e-3f;
  front.eye = {0.5f * (lo_x + hi_x), 0.5f * (lo_y + hi_y), hi_z + margin};
  front.target = front.eye - glm::vec3(0.0f, 0.0f, 1.0f);
  front.up = {0.0f, 1.0f, 0.0f};
  front.near_plane = 0.5f * margin;
  front.far_plane = depth + 2.0f * margin;
  return front;
}

void draw_frustum(Image& image, const Camera& observer, const Camera& camera, float far_limit) {
  const glm::mat4 view_proj = observer.view_proj();
  const double w_min = observer.orthographic ? -std::numeric_limits<double>::infinity() : observer.near_plane;
  const double width = image.width, height = image.height;
  Canvas canvas{image};
  // A world point in the observer's clip space, in double.
  const auto clip = [&](const glm::vec3& p) { return glm::dvec4(view_proj * glm::vec4(p, 1.0f)); };
  const auto pixel = [&](const glm::dvec4& c) {
    return glm::dvec2((c.x / c.w * 0.5 + 0.5) * width, (c.y / c.w * 0.5 + 0.5) * height);
  };
  const std::array<glm::vec3, 8> corners = frustum_corners(camera, far_limit);
  for (const auto& e : kFrustumEdges) {
    glm::dvec4 a = clip(corners[std::size_t(e[0])]), b = clip(corners[std::size_t(e[1])]);
    // In front of the observer's near plane only (w is the distance along its view).
    if (a.w < w_min && b.w < w_min) continue;
    if (a.w < w_min) a += (b - a) * ((w_min - a.w) / (b.w - a.w));
    if (b.w < w_min) b += (a - b) * ((w_min - b.w) / (a.w - b.w));
    glm::dvec2 p = pixel(a), q = pixel(b);
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(q.x) || !std::isfinite(q.y)) continue;
    // Liang-Barsky against the image widened by a pixel, so the line stays in int range.
    double t0 = 0.0, t1 = 1.0;
    const glm::dvec2 d = q - p;
    const double lo[2] = {-1.0, -1.0}, hi[2] = {width + 1.0, height + 1.0};
    bool visible = true;
    for (int axis = 0; axis < 2 && visible; ++axis) {
      for (const auto& [num, den] : {std::pair{p[axis] - lo[axis], -d[axis]}, std::pair{hi[axis] - p[axis], d[axis]}}) {
        if (den == 0.0) {
          if (num < 0.0) visible = false;
        } else {
          const double t = num / den;
          if (den < 0.0)
            t0 = std::max(t0, t);
          else
            t1 = std::min(t1, t);
        }
      }
    }
    if (!visible || t0 > t1 || !std::isfinite(t0) || !std::isfinite(t1)) continue;
    const glm::dvec2 from = p + d * t0, to = p + d * t1;
    canvas.line(int(std::floor(from.x)), int(std::floor(from.y)), int(std::floor(to.x)), int(std::floor(to.y)),
                0xffffffff);
  }
  const glm::dvec4 eye = clip(camera.eye);
  if (eye.w >= w_min && eye.w > 0.0) {
    const glm::dvec2 e = pixel(eye);
    if (std::isfinite(e.x) && std::isfinite(e.y) && e.x > -8.0 && e.y > -8.0 && e.x < width + 8.0 && e.y < height + 8.0)
      canvas.fill(int(std::floor(e.x)) - 3, int(std::floor(e.y)) - 3, int(std::floor(e.x)) + 3,
                  int(std::floor(e.y)) + 3, 0xff4040ff);
  }
}

}  // namespace cullpipe::render
