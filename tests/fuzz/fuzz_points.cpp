// Fuzzes the point-file reader (load_points): the first byte picks the format (.txt, .off, .obj),
// the rest is the file.
#include <cmath>

#include "cullpipe/scene/point_io.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace cullpipe;
  if (size == 0) return 0;
  static const char* const names[3] = {"input.txt", "input.off", "input.obj"};
  const std::string path = fuzz::write_temp(data + 1, size - 1, names[data[0] % 3]);
  fuzz::expect_clean([&] {
    for (const glm::vec3& p : load_points(path))
      if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) std::abort();  // documented: finite only
  });
  return 0;
}
