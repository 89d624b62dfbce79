// cullpipe: frustum culling on Vulkan compute, checked against a scalar CPU reference.
#include <CLI/CLI.hpp>
#include <iostream>
#include <map>

#include "cullpipe/app/commands.hpp"
#include "cullpipe/cull/cpu_bvh_culler.hpp"

using namespace cullpipe::app;

namespace {

const std::map<std::string, Backend> kBackends{{"gpu", Backend::Gpu}, {"cpu", Backend::Cpu}, {"both", Backend::Both}};

void add_device_options(CLI::App* cmd, DeviceOptions& d) {
  cmd->add_option("--device", d.device,
                  "Vulkan device name substring (default: $CULLPIPE_DEVICE, else first GPU, else lavapipe)");
  cmd->add_flag("--validate", d.validation, "Enable Vulkan validation layers; any message fails the command");
  cmd->add_option("--gpu-memory", d.gpu_memory_mib,
                  "Device memory budget in MiB; past it a clear out-of-memory error (default: no budget)")
      ->check(CLI::NonNegativeNumber);
}

// Options choosing and building the scene, shared by `run` and `render`.
// The occlusion test's reads: --texels and --refine-texels.
void add_texel_options(CLI::App* cmd, std::uint32_t& texels, std::uint32_t& refine) {
  cmd->add_option("--texels", texels, "--occlusion: texels per axis the test reads: 2 | 4 | 8 | 16")
      ->capture_default_str()
      ->check(CLI::IsMember({2u, 4u, 8u, 16u}));
  cmd->add_option("--refine-texels", refine,
                  "--occlusion: objects the --texels test keeps are tested again at this many texels per axis "
                  "(0: not; 4 | 8 | 16; none at or below --texels)")
      ->capture_default_str()
      ->check(CLI::IsMember({0u, 4u, 8u, 16u}));
}

void add_scene_options(CLI::App* cmd, SceneOptions& s) {
  auto* scene_opt = cmd->add_option(
      "--scene", s.scene_path, "Scene file: cullpipe-scene JSON, or glTF (.gltf, .glb); default: scenes/default.json");
  cmd->add_option("--generate", s.generate,
                  "Procedural scene KIND:N, KIND = uniform | clustered | city | streets | meshes")
      ->excludes(scene_opt);
  cmd->add_option("--seed", s.seed, "Seed for --generate and --layout random")->capture_default_str();
  cmd->add_option("--gltf-scene", s.gltf_scene, "glTF: index of the scene to load (default: the file's default scene)");
  cmd->add_option("--camera", s.camera,
                  "glTF: camera name or index in cameras[] (default: a camera framing the scene)");
  cmd->add_option("--obb", s.obb, "glTF: OBB builder: pca | dito | hull-face | exact")->capture_default_str();
  cmd->add_option("--sphere", s.sphere, "glTF: sphere builder: ritter | refined | exact")->capture_default_str();
  cmd->add_option("--aabb-update", s.aabb_update,
                  "glTF: world AABB method: recompute | hull | transform-box | hill-climb")
      ->capture_default_str();
  cmd->add_option("--instances", s.instances, "Repeat the scene this many times (scale tests)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->add_option("--layout", s.layout, "Placement of --instances copies: grid | random")->capture_default_str();
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "cullpipe: culls scene objects against view frusta with Vulkan compute shaders and checks every GPU answer "
      "against a scalar CPU reference.\nWith no subcommand, runs the default scene (same as `cullpipe run`)."};
  app.require_subcommand(0, 1);

  RunOptions run;
  CLI::App* run_cmd = app.add_subcommand("run", "Cull a scene on the GPU and/or the CPU and compare, view by view");
  add_scene_options(run_cmd, run);
  run_cmd->add_option("--bv", run.bv, "Bounding volume: aabb | obb | sphere")
      ->capture_default_str()
      ->check(CLI::IsMember({"aabb", "obb", "sphere"}));
  run_cmd
      ->add_option("--cull", run.cull, "flat (test every object) | bvh (hierarchical: INSIDE subtrees accepted whole)")
      ->capture_default_str()
      ->check(CLI::IsMember({"flat", "bvh"}));
  run_cmd->add_option("--builder", run.builder, "--cull bvh: BVH builder (see `cullpipe bvh --list`)")
      ->capture_default_str();
  run_cmd->add_option("--leaf-size", run.leaf_size, "--cull bvh: most objects per leaf")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1024u));
  run_cmd->add_option("--backend", run.backend, "gpu | cpu | both (both compares them)")
      ->transform(CLI::CheckedTransformer(kBackends))
      ->default_str("both");
  run_cmd
      ->add_option("--cpu", run.cpu,
                   "CPU side: reference (scalar oracle) | fast (SIMD on every core, bit-exact with the reference)")
      ->capture_default_str()
      ->check(CLI::IsMember({"reference", "fast"}));
  run_cmd->add_option(
      "--range-objects", run.range_objects,
      "--cull bvh on the CPU: a straddling node of at most N objects tests its objects instead of descending "
      "(default: " +
          std::to_string(cullpipe::fast::CpuBvhCullOptions::default_range_objects(cullpipe::BvKind::Aabb)) +
          " for AABBs and spheres, " +
          std::to_string(cullpipe::fast::CpuBvhCullOptions::default_range_objects(cullpipe::BvKind::Obb)) +
          " for OBBs with --cpu fast, 0 with --cpu reference; the GPU always descends to the leaves; no effect with "
          "--cull flat or --backend gpu)");
  run_cmd->add_option("--views", run.views, "Number of views on a camera path around the scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  run_cmd->add_flag("--occlusion", run.occlusion,
                    "Two-phase occlusion frames through the renderer, each checked against the reference on its "
                    "depth pyramid and against the objects owning a pixel");
  run_cmd->add_flag("--clusters", run.clusters,
                    "Also cull the kept objects' clusters (with --occlusion, which it implies), each (object, cluster) "
                    "pair checked against the reference on every frame");
  run_cmd->add_option("--frames", run.frames, "--occlusion: frames along the path of --views cameras")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t(1), std::size_t(100000)));
  add_texel_options(run_cmd, run.texels, run.refine_texels);
  run_cmd->add_option("--width", run.width, "--occlusion: depth image width")
      ->capture_default_str()
      ->check(CLI::Range(1u, 16384u));
  run_cmd->add_option("--height", run.height, "--occlusion: depth image height")
      ->capture_default_str()
      ->check(CLI::Range(1u, 16384u));
  run_cmd
      ->add_option("--software-divisor", run.software_divisor,
                   "--occlusion: the CPU path's depth buffer is the viewport divided by this on each side")
      ->capture_default_str()
      ->check(CLI::Range(1u, 64u));
  run_cmd->add_option("--json", run.json_path, "Write a summary as JSON");
  run_cmd->add_option("--dump", run.dump_path, "Write planes, volumes and classes (the classify schema)");
  add_device_options(run_cmd, run.device);

  RenderOptions render;
  CLI::App* render_cmd =
      app.add_subcommand("render", "Draw a scene from the culling pass's indirect draws into a PNG (headless Vulkan)");
  add_scene_options(render_cmd, render);
  render_cmd->add_option("--out", render.out_path, "Output PNG")->required();
  render_cmd->add_option("--top-down", render.top_down_path,
                         "Also write a top-down debug PNG: the frustum and every object by class");
  render_cmd->add_option("--front", render.front_path,
                         "Also write a front debug PNG (orthographic, looking along -z): every object, or with "
                         "--clusters every cluster, filled by class, with the frustum");
  render_cmd->add_option("--bv", render.bv, "Bounding volume the culling pass tests: aabb | obb | sphere")
      ->capture_default_str()
      ->check(CLI::IsMember({"aabb", "obb", "sphere"}));
  render_cmd->add_flag("--no-cull", render.no_cull, "Draw every object (no culling pass)");
  render_cmd->add_flag("--occlusion", render.occlusion,
                       "Also cull occluded objects: two phases per frame, last frame's visible objects first");
  render_cmd
      ->add_option("--frames", render.frames,
                   "Frames along the camera path from --view (visibility carries from frame to frame)")
      ->capture_default_str()
      ->check(CLI::Range(std::size_t(1), std::size_t(100000)));
  add_texel_options(render_cmd, render.texels, render.refine_texels);
  render_cmd->add_flag("--clusters", render.clusters,
                       "Also cull clusters of the kept objects' meshes (frustum, back-face cone, occlusion with "
                       "--occlusion) and draw the kept clusters");
  render_cmd
      ->add_option("--cone-weight", render.cone_weight,
                   "--clusters: 0 splits meshes for compact clusters, towards 1 for narrow normal cones")
      ->capture_default_str()
      ->check(CLI::Range(0.0f, 1.0f));
  render_cmd->add_flag("--all-faces", render.all_faces, "Draw back faces too (no back-face culling, no cone test)");
  render_cmd->add_flag("--check", render.check,
                       "Also draw without culling and require the same image, pixel for pixel (exit 1 if not)");
  render_cmd->add_option("--views", render.views, "Camera path of this many views around the scene")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  render_cmd->add_option("--view", render.view, "Which view of the path to draw (0: the scene's camera)")
      ->capture_default_str();
  render_cmd->add_option("--width", render.width, "Image width")->capture_default_str()->check(CLI::Range(1u, 16384u));
  render_cmd->add_option("--height", render.height, "Image height")
      ->capture_default_str()
      ->check(CLI::Range(1u, 16384u));
  add_device_options(render_cmd, render.device);

  BvhOptions bvh;
  bool list_builders = false;
  CLI::App* bvh_cmd =
      app.add_subcommand("bvh", "Build the scene's BVH with one or more builders and print quality and build time");
  add_scene_options(bvh_cmd, bvh);
  bvh_cmd->add_option("--builder", bvh.builders, "Builder name(s), or all; see --list")->capture_default_str();
  bvh_cmd->add_option("--leaf-size", bvh.leaf_size, "Most objects per leaf")
      ->capture_default_str()
      ->check(CLI::Range(1u, 1024u));
  bvh_cmd->add_flag("--sah-leaves", bvh.sah_leaves,
                    "Top-down builders: leaves where the SAH says, --leaf-size a cap (built with leaves of one, "
                    "then collapsed)");
  bvh_cmd
      ->add_option("--object-cost", bvh.object_cost,
                   "--sah-leaves: the cost of an object in a leaf against a node test's 1 (below 1: larger leaves)")
      ->capture_default_str()
      ->check(CLI::Range(1e-6f, 1e6f));
  bvh_cmd->add_option("--repeats", bvh.repeats, "Builds per builder; the median time is reported")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  bvh_cmd
      ->add_option("--threads", bvh.threads,
                   "Threads of the builders that run on several (binned-sah, agglomerative-local: the same tree on "
                   "any number); 0: every core")
      ->capture_default_str()
      ->check(CLI::Range(0u, 256u));
  bvh_cmd->add_option("--json", bvh.json_path, "Write every builder's metrics as JSON");
  bvh_cmd->add_flag("--list", list_builders, "List the builders and exit");

  ClassifyOptions classify;
  CLI::App* classify_cmd =
      app.add_subcommand("classify", "Classify volumes against frusta given in a JSON file (- for stdin)");
  classify_cmd->add_option("file", classify.input_path, "JSON: {\"frustum\": ..., \"volumes\": [...]}")->required();
  classify_cmd->add_option("--backend", classify.backend, "gpu | cpu | both")
      ->transform(CLI::CheckedTransformer(kBackends))
      ->default_str("both");
  add_device_options(classify_cmd, classify.device);

  GenerateOptions generate;
  CLI::App* generate_cmd = app.add_subcommand("generate", "Write a procedural scene to a file");
  generate_cmd->add_option("spec", generate.spec, "KIND:N, KIND = uniform | clustered | city | streets | meshes")
      ->required();
  generate_cmd->add_option("--seed", generate.seed, "Seed")->capture_default_str();
  generate_cmd->add_option("--out", generate.out_path, "Output scene file")->required();

  CLI::App* devices_cmd = app.add_subcommand("devices", "List Vulkan devices");

  BoundsOptions bounds;
  CLI::App* bounds_cmd = app.add_subcommand("bounds", "Build every bounding volume of a point set and compare them");
  auto* model_opt = bounds_cmd->add_option("file", bounds.model_path, "glTF file (.gltf, .glb): one report per mesh");
  bounds_cmd->add_option("--points", bounds.points_path, "Points file: x y z per line (.txt), .off or .obj")
      ->excludes(model_opt);
  bounds_cmd->add_option("--json", bounds.json_path, "Write every volume (classify schema) with builder name and time");

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int code = app.exit(e);
    return code == 0 ? 0 : kExitBadInput;
  }

  if (*classify_cmd) return classify_command(classify, std::cout, std::cerr);
  if (*generate_cmd) return generate_command(generate, std::cout, std::cerr);
  if (*devices_cmd) return devices_command(std::cout, std::cerr);
  if (*bounds_cmd) return bounds_command(bounds, std::cout, std::cerr);
  if (*render_cmd) return render_command(render, std::cout, std::cerr);
  if (*bvh_cmd) {
    if (list_builders) {
      list_bvh_builders(std::cout);
      return kExitOk;
    }
    return bvh_command(bvh, std::cout, std::cerr);
  }
  return run_command(run, std::cout, std::cerr);
}
