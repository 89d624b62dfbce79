#pragma once
#include <glm/vec3.hpp>
#include <span>
#include <stdexcept>
#include <string>

namespace cullpipe::bounds {

/// A point set a volume cannot be built from: empty, or with a NaN or infinite coordinate.
/// The message says which (e.g. "point 17 has a NaN coordinate").
class BadPoints : public std::invalid_argument {
 public:
  using std::invalid_argument::invalid_argument;
};

/// Throws BadPoints when `points` is empty or holds a non-finite coordinate.
void check_points(std::span<const glm::vec3> points);

}  // namespace cullpipe::bounds
