#pragma once
#include <cstdint>
#include <iosfwd>
#include <optional>
#include <string>
#include <vector>

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/geom/bv_kind.hpp"

namespace cullpipe::app {

/// Which implementation classifies: the GPU, the scalar CPU reference, or both (compared).
enum class Backend { Gpu, Cpu, Both };

/// Exit codes of the tool.
inline constexpr int kExitOk = 0;
inline constexpr int kExitMismatch = 1;  ///< GPU and CPU disagreed
inline constexpr int kExitBadInput = 2;  ///< bad arguments or input files
inline constexpr int kExitNoDevice = 3;  ///< Vulkan failed or no usable device
inline constexpr int kExitInternal = 4;  ///< a bug: an unexpected exception

/// Options shared by commands that use a Vulkan device.
struct DeviceOptions {
  std::string device;         ///< device name substring; empty: CULLPIPE_DEVICE or the default
  bool validation = false;    ///< Vulkan validation layers on; any message fails the command
  double gpu_memory_mib = 0;  ///< device memory budget in MiB (vulkan::ContextOptions::memory_budget); 0: none
};

/// Where a scene comes from, shared by `run` and `render`.
struct SceneOptions {
  std::string
      scene_path;  ///< a cullpipe scene JSON or a glTF file (.gltf, .glb); empty with no `generate`: the default scene
  std::string generate;  ///< "KIND:N" procedural scene instead of a file
  std::uint64_t seed = 1;
  // glTF scenes
  int gltf_scene = -1;               ///< index in scenes[]; -1: the file's default scene
  std::string camera;                ///< glTF camera name or index; empty: a camera framing the scene
  std::string obb = "dito";          ///< OBB builder for mesh objects: pca | dito | hull-face | exact
  std::string sphere = "exact";      ///< sphere builder for mesh objects: ritter | refined | exact
  std::string aabb_update = "hull";  ///< world AABBs of mesh objects: recompute | hull | transform-box | hill-climb
  // Any scene
  std::size_t instances = 1;    ///< copies of the scene
  std::string layout = "grid";  ///< grid | random placement of the copies
};

struct RunOptions : SceneOptions {
  std::string bv = "aabb";                          ///< aabb | obb | sphere
  std::string cull = "flat";                        ///< flat (every object) | bvh (hierarchical)
  std::string builder = "binned-sah";               ///< --cull bvh: builder name (bvh::builders())
  std::uint32_t leaf_size = bvh::kCullingLeafSize;  ///< --cull bvh: most objects per leaf
  Backend backend = Backend::Both;
  std::string cpu = "reference";  ///< CPU side: reference (scalar oracle) | fast (SIMD, every core, bit-exact)
  /// --cull bvh on the CPU: bvh::TraversalOptions::range_objects (unset: the fast path's
  /// default with --cpu fast, 0 with --cpu reference; the GPU traversal always uses 0).
  std::optional<std::uint32_t> range_objects;
  std::size_t views = 1;  ///< views along the camera path around the scene
  std::string json_path;  ///< summary as JSON
  std::string dump_path;  ///< planes, volumes and classes (classify schema)
  DeviceOptions device;
  /// Two-phase occlusion frames through the renderer (run_occlusion), `frames` of them along the
  /// path of `views` cameras, at width x height, the test reading `texels` texels per axis.
  bool occlusion = false;
  /// With occlusion: the renderer culls clusters too, and every (object, cluster) pair's class
  /// is checked against clusters::classify on each frame's pyramid.
  bool clusters = false;
  std::size_t frames = 1;
  std::uint32_t texels = 4;
  std::uint32_t refine_texels = 16;  ///< occlusion: the second test's texels per axis (0: none)
  std::uint32_t width = 960, height = 540;
  std::uint32_t software_divisor = 4;  ///< the CPU path's depth buffer: each side of the viewport over this
};

struct RenderOptions : SceneOptions {
  std::string bv = "aabb";
  std::size_t view = 0;  ///< which view of a `views`-camera path around the scene (0: the scene's camera)
  std::size_t views = 1;
  bool no_cull = false;              ///< draw every object instead of the culling pass's draws
  bool check = false;                ///< render both ways and require identical images
  bool occlusion = false;            ///< two-phase occlusion frames (render::CullMode::Occlusion)
  std::size_t frames = 1;            ///< frames along the camera path from `view`, visibility carried
  std::uint32_t texels = 4;          ///< occlusion: texels per axis the test reads (2, 4, 8, 16)
  std::uint32_t refine_texels = 16;  ///< occlusion: the second test's texels per axis (0: none)
  bool clusters = false;             ///< cluster culling after the object pass (RendererConfig::clusters)
  float cone_weight = 0.25f;         ///< --clusters: meshoptimizer's cone weight (ClusterOptions)
  bool all_faces = false;            ///< draw back faces too (RendererConfig::cull_back_faces = false)
  std::uint32_t width = 960, height = 540;
  std::string out_path;       ///< PNG
  std::string top_down_path;  ///< optional top-down debug PNG
  std::string front_path;     ///< optional front debug PNG (render::front_view_camera)
  DeviceOptions device;
};

struct BvhOptions : SceneOptions {
  std::vector<std::string> builders{"binned-sah"};  ///< names (bvh::builders()), or "all"
  std::uint32_t leaf_size = 4;
  bool sah_leaves = false;   ///< top-down builders: leaves where the SAH says, leaf_size a cap
  float object_cost = 1.0f;  ///< with sah_leaves: an object in a leaf against a node test
  std::size_t repeats = 1;   ///< builds per builder; the median time is reported
  unsigned threads = 1;      ///< threads of the builders that run on several; 0: every core
  std::string json_path;
};

struct ClassifyOptions {
  std::string input_path;  ///< JSON file, or "-" for standard input
  Backend backend = Backend::Both;
  DeviceOptions device;
};

struct GenerateOptions {
  std::string spec;  ///< KIND:N
  std::uint64_t seed = 1;
  std::string out_path;
};

struct BoundsOptions {
  std::string model_path;   ///< glTF file (.gltf or .glb): one report per mesh
  std::string points_path;  ///< or a points file: .txt (x y z per line), .off or .obj
  std::string json_path;    ///< every builder's volume (classify schema), name and time
};

/// Each command writes its report to `out`, errors to `err`, and returns an exit code.
/// Exceptions do not escape: they are reported on `err` with the matching exit code.
int run_command(const RunOptions& options, std::ostream& out, std::ostream& err);
struct LoadedScene;
/// `run --occlusion` on a loaded scene (run_command's checks done; `bv` parsed).
int run_occlusion(const RunOptions& options, const LoadedScene& loaded, BvKind bv, std::ostream& out,
                  std::ostream& err);
int classify_command(const ClassifyOptions& options, std::ostream& out, std::ostream& err);
int generate_command(const GenerateOptions& options, std::ostream& out, std::ostream& err);
int devices_command(std::ostream& out, std::ostream& err);
int bounds_command(const BoundsOptions& options, std::ostream& out, std::ostream& err);
int render_command(const RenderOptions& options, std::ostream& out, std::ostream& err);
int bvh_command(const BvhOptions& options, std::ostream& out, std::ostream& err);
/// Every builder name with its description, one per line, plus the parametric top-down form.
void list_bvh_builders(std::ostream& out);

/// The default scene shipped in scenes/: found next to the source tree the tool was built
/// from, or under <prefix>/share/cullpipe/scenes relative to the executable.
std::string default_scene_path();

}  // namespace cullpipe::app
