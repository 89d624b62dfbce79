#pragma once
#include <glm/vec3.hpp>
#include <span>
#include <stdexcept>
#include <string>
#include <utility>

namespace cullpipe::bounds {

/// A point set a volume cannot be built from: empty, or with a NaN or infinite coordinate.
/// The message says which (e.g. "point 17 has a NaN coordinate").
class BadPoints : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// Throws BadPoints when `points` is empty or holds a non-finite coordinate.
void check_points(std::span<const glm::vec3> points);

/// Of the min/max points along the x, y and z axes, the pair farthest apart (Ericson, Real-Time
/// Collision Detection 4.3.2, MostSeparatedPointsOnAABB): indices of the two points.
std::pair<std::size_t, std::size_t> most_separated_axis_extremes(std::span<const glm::vec3> points);

}  // namespace cullpipe::bounds
