// Fuzzes the JSON readers: classify/dump files (parse_cull_case) and scene files (parse_scene).
#include <string>

#include "cullpipe/scene/cull_case_io.hpp"
#include "cullpipe/scene/scene_io.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace cullpipe;
  const std::string text(reinterpret_cast<const char*>(data), size);
  fuzz::expect_clean([&] {
    const CullCase c = parse_cull_case(text, "fuzz.json");
    cull_case_to_json(c);  // whatever parses can be written back
  });
  fuzz::expect_clean([&] {
    const Scene s = parse_scene(text, "fuzz.json");
    scene_to_json(s);
    world_aabbs(s);
  });
  return 0;
}
