#include <ostream>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/app/guard.hpp"
#include "cullpipe/scene/generators.hpp"
#include "cullpipe/scene/scene_io.hpp"

namespace cullpipe::app {

int generate_command(const GenerateOptions& o, std::ostream& out, std::ostream& err) {
  return guarded(err, [&]() -> int {
    if (o.out_path.empty()) throw InputError("generate: --out FILE is required");
    const auto [kind, n] = parse_generate_spec(o.spec);
    const Scene scene = generate_scene(kind, n, o.seed);
    save_scene(o.out_path, scene);
    out << "wrote " << o.out_path << ": " << scene.name << ", " << scene.objects.size() << " objects\n";
    return kExitOk;
  });
}

}  // namespace cullpipe::app
