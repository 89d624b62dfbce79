#pragma once
#include <glm/vec3.hpp>
#include <string>
#include <vector>

namespace cullpipe {

/// Reads a point set. By extension:
///   .off  Object File Format: "OFF", then "nv nf ne", then nv lines of x y z (faces ignored);
///   .obj  Wavefront OBJ: every "v x y z [w]" line (other records ignored);
///   other plain text: one point per line as three numbers; blank lines and lines starting
///         with '#' are ignored.
/// Throws InputError naming the file and line for anything else, including NaN/Inf values,
/// numbers beyond float range, and a file with no points.
std::vector<glm::vec3> load_points(const std::string& path);

}  // namespace cullpipe
