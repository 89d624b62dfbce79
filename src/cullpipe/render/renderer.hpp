#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "cullpipe/bounds/aabb_update.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/cull/software_depth.hpp"
#include "cullpipe/geom/bv_kind.hpp"
#include "cullpipe/geom/classification.hpp"
#include "cullpipe/gpu/cluster_culler.hpp"
#include "cullpipe/gpu/depth_pyramid_pass.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/render/image.hpp"
#include "cullpipe/scene/camera.hpp"
#include "cullpipe/scene/clusters.hpp"
#include "cullpipe/scene/scene.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::render {

struct RendererConfig {
  std::uint32_t width = 960;
  std::uint32_t height = 540;
  /// How the occlusion test of CullMode::Occlusion frames reads the depth pyramid: 4 texels per
  /// axis, and the objects that keeps again at 16 (fewer draws for a dearer test: from the
  /// default city camera 45 objects drawn instead of 68, against 33 owning a pixel).
  occlusion::OcclusionOptions occlusion{4, 16};
  BvKind bv = BvKind::Aabb;                                            ///< volume the culling pass tests
  bounds::AabbUpdate aabb_update = bounds::AabbUpdate::HullRecompute;  ///< world AABBs of mesh objects
  /// Back faces culled as glTF draws them: triangles wound clockwise on screen are not drawn,
  /// except those of double-sided meshes (TriangleMesh::double_sided); a mirroring instance
  /// (negative determinant) has its winding flipped. False: every face drawn.
  bool cull_back_faces = true;
  /// Cluster culling: every mesh (and the box objects' cube) split into clusters
  /// (build_clusters with `cluster_options`); culled frames run the cluster pass
  /// (gpu::ClusterCuller) after the object pass and draw the image from the kept clusters, a
  /// draw each. The meshes' triangles are stored cluster by cluster, and unculled frames draw
  /// every cluster with a draw of its own too, so a culled frame's draws are some of the unculled
  /// frame's, unchanged.
  bool clusters = false;
  ClusterOptions cluster_options;
};

/// How a frame culls: not at all, by the frustum, or by the frustum and then occlusion in two
/// phases (CullMode::Occlusion: Renderer::render says how).
enum class CullMode { None, Frustum, Occlusion };

/// What one frame drew.
struct FrameStats {
  std::size_t objects = 0;
  /// Draws the GPU issued for the image: the draw count the culling pass wrote (culled frames),
  /// else objects (with RendererConfig::clusters, clusters). With occlusion, the second phase's
  /// draws.
  std::size_t draws = 0;
  /// Occlusion frames: the first phase's draws (last frame's visible objects, depth for the
  /// pyramid) and the objects the frustum kept that the pyramid hid.
  std::size_t first_phase_draws = 0;
  std::size_t occluded = 0;
  /// Triangles the input assembler received (pipeline statistics; 0 when the device has none).
  std::uint64_t primitives = 0;
  bool primitives_counted = false;
  std::vector<Classification> classes;  ///< per object, from the culling pass (culled frames)
  /// Cluster frames (RendererConfig::clusters, culled): the cluster pairs (every object's
  /// clusters), the pairs per class (indexed by clusters::ClusterClass's value) and the clusters
  /// drawn; `draws` then counts the cluster pass's draws (a run of an object's drawn clusters
  /// is one), and so do the first phase's.
  std::size_t clusters = 0;
  std::array<std::size_t, clusters::kClusterClassCount> cluster_classes{};
  std::size_t clusters_drawn = 0;
  /// Every pair's class, in pair order (object by object, each object's clusters in order; see
  /// Renderer::cluster_instances()).
  std::vector<clusters::ClusterClass> cluster_pair_classes;
};

/// A headless Vulkan rasteriser (offscreen colour + depth, no window) that draws a scene from
/// the culling pass's output: the pass is recorded into the frame's command buffer with
/// GpuCuller::record (object-order compaction), and the frame draws with one
/// vkCmdDrawIndexedIndirectCount from its draw and count buffers. Without culling, the same
/// draws of every object are issued with vkCmdDrawIndexedIndirect, in the same object order,
/// so the two images must be identical pixel for pixel. glTF objects are drawn from their
/// triangles; box objects as their box. Each object gets a fixed colour from its id; shading
/// is flat from screen-space derivatives. Needs drawIndirectCount and multiDrawIndirect.
class Renderer {
 public:
  Renderer(const vulkan::Context& ctx, const Scene& scene, const RendererConfig& config = {});
  ~Renderer();
  Renderer(const Renderer&) = delete;
  Renderer& operator=(const Renderer&) = delete;

  /// Draws the scene seen by `camera`; waits and reads the image back. With
  /// CullMode::Occlusion, in two phases: the first draws the objects the last culled frame
  /// kept (none after construction or forget_visibility()) and reduces that depth to a
  /// pyramid; the flat pass then culls by the frustum and that pyramid, and the second phase
  /// clears and draws what it kept, in object order, so the image equals the unculled one pixel
  /// for pixel (an occluded object is strictly behind every depth it could reach). What it kept
  /// is the next frame's first phase.
  Image render(const Camera& camera, CullMode mode, FrameStats* stats = nullptr);
  Image render(const Camera& camera, bool cull, FrameStats* stats = nullptr) {
    return render(camera, cull ? CullMode::Frustum : CullMode::None, stats);
  }
  /// The depth pyramid of the last occlusion frame (null before the first).
  const gpu::DepthPyramidPass* pyramid() const { return pyramid_.get(); }
  /// The depth attachment as a pyramid source: the depth of the last pass drawn (render or
  /// pixel_owners), in the layout every pass leaves it (the caller waits for nothing: every
  /// pass has completed when it returns).
  gpu::DepthSource depth_source() const {
    return {depth_, VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL, VK_FORMAT_D32_SFLOAT, config_.width,
            config_.height};
  }
  /// The next occlusion frame starts with no visible objects (a camera cut).
  void forget_visibility() { has_visibility_ = false; }

  /// Which objects own at least one pixel of the unculled image seen by `camera`: every object
  /// drawn in object order, as render(camera, CullMode::None) draws them, each writing its id;
  /// the ids left in the image. What no culling may ever drop. (Its pipeline differs from the
  /// image's in the fragment shader only; Vulkan promises the same positions across pipelines
  /// only for an `invariant` gl_Position, which Debian 12's validation layer rejects as a
  /// decoration of gl_PerVertex, so on other drivers treat a disagreement with the image check
  /// with care.)
  std::vector<bool> pixel_owners(const Camera& camera);
  /// How many triangles own at least one pixel of the unculled image seen by `camera` (drawn as
  /// pixel_owners draws, then again writing each triangle's index within its object's draw):
  /// what cluster culling could at best submit. Empty when the device cannot read
  /// gl_PrimitiveID in a fragment shader (vulkan::Context::primitive_ids()).
  std::optional<std::uint64_t> visible_triangles(const Camera& camera);

  /// Triangles of object i (what a draw of it feeds the input assembler; a double-sided mesh's
  /// count twice when back faces are culled: it is drawn with both windings).
  std::uint64_t triangles(std::size_t object) const { return templates_[object].index_count / 3; }
  std::size_t object_count() const { return templates_.size(); }
  /// Cluster rendering: the meshes build_clusters refused, drawn as one cluster each with no
  /// back-face cone (named in the messages, as "mesh <i>: why").
  const std::vector<std::string>& cluster_fallbacks() const { return cluster_fallbacks_; }
  /// What the cluster pass culls, for checking it against clusters::classify: the clusters'
  /// local boxes, cones and OBBs (every distinct mesh's, the cube's for box objects, which has
  /// no OBB), and per object its transform (its draw's model matrix) and range of them; empty
  /// without clusters.
  const std::vector<Aabb>& cluster_boxes() const { return cluster_boxes_; }
  const std::vector<BackfaceCone>& cluster_cones() const { return cluster_cones_; }
  const std::vector<std::optional<Obb>>& cluster_obbs() const { return cluster_obbs_; }
  const std::vector<gpu::ClusterInstance>& cluster_instances() const { return cluster_instances_; }
  /// The (object, cluster) pairs: every object's cluster_count summed; 0 without clusters.
  std::size_t cluster_pair_count() const { return cluster_culler_ ? cluster_culler_->pair_count() : 0; }

  /// A debug view of a culled frame (`stats` from render() with culling, by this renderer) seen
  /// by `observer`: every object drawn as the unculled frame draws it, its triangles filled by
  /// the class the frame gave it and shaded flat (green inside, amber intersecting, violet
  /// occluded, grey outside); with clusters, every (object, cluster) pair by its cluster class
  /// (green drawn, violet occluded, blue back-facing, grey outside, dark grey of a culled
  /// object). From the frame's own camera only drawn colours can show, since nothing culled owns
  /// a pixel; from elsewhere (front_view_camera) the culled parts show. The image is the
  /// renderer's size. Throws std::invalid_argument when `stats` does not hold a class for every
  /// object (or pair).
  Image class_image(const Camera& observer, const FrameStats& stats);

 private:
  void begin_frame();
  /// One pass of the scene into the colour and depth targets, cleared: the image, the objects'
  /// ids (the id pass's pipeline and objects), or depth alone; `draw` records the draws.
  enum class ScenePass { Image, Ids, Primitives, Depth, Classes };
  /// Every object drawn, as the unculled frame draws them, in one pass; the image read back.
  Image draw_everything(const Camera& camera, ScenePass pass);
  void record_scene_pass(const Camera& camera, ScenePass pass, const std::function<void()>& draw);
  /// Copies the colour image out, ends, submits and waits, and returns the image.
  Image submit_and_read();
  void create_targets();
  void create_pipelines();
  void release();

  const vulkan::Context& ctx_;
  RendererConfig config_;
  std::vector<gpu::DrawCommand> templates_;
  std::unique_ptr<gpu::GpuCuller> culler_;
  std::unique_ptr<gpu::ClusterCuller> cluster_culler_;  // RendererConfig::clusters
  std::vector<std::string> cluster_fallbacks_;
  std::vector<Aabb> cluster_boxes_;
  std::vector<BackfaceCone> cluster_cones_;
  std::vector<std::optional<Obb>> cluster_obbs_;
  std::vector<gpu::ClusterInstance> cluster_instances_;
  std::unique_ptr<gpu::DepthPyramidPass> pyramid_;
  bool has_visibility_ = false;  // the culler's draw buffer holds the last culled frame's draws
  vulkan::Buffer vertices_, indices_, objects_, id_objects_, all_draws_, readback_;
  vulkan::Buffer all_cluster_draws_;            // clusters: every pair's draw, what unculled frames issue
  vulkan::Buffer class_objects_, class_draws_;  // class_image: a coloured record and a draw per object or pair
  VkImage color_ = VK_NULL_HANDLE, depth_ = VK_NULL_HANDLE;
  VkDeviceMemory color_memory_ = VK_NULL_HANDLE, depth_memory_ = VK_NULL_HANDLE;
  VkImageView color_view_ = VK_NULL_HANDLE, depth_view_ = VK_NULL_HANDLE;
  VkRenderPass render_pass_ = VK_NULL_HANDLE;
  VkFramebuffer framebuffer_ = VK_NULL_HANDLE;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout pipeline_layout_ = VK_NULL_HANDLE;
  VkPipeline pipeline_[2] = {VK_NULL_HANDLE, VK_NULL_HANDLE};            // [reversed_z]: depth LESS or GREATER
  VkPipeline id_pipeline_[2] = {VK_NULL_HANDLE, VK_NULL_HANDLE};         // the id pass's, likewise
  VkPipeline primitive_pipeline_[2] = {VK_NULL_HANDLE, VK_NULL_HANDLE};  // triangle ids (primitive_ids())
  VkPipeline depth_pipeline_[2] = {VK_NULL_HANDLE, VK_NULL_HANDLE};      // depth only, likewise
  VkDescriptorSet id_descriptor_set_ = VK_NULL_HANDLE;                   // its objects: id_objects_
  VkDescriptorSet class_descriptor_set_ = VK_NULL_HANDLE;                // class_image's: class_objects_
  VkDescriptorPool descriptor_pool_ = VK_NULL_HANDLE;
  VkDescriptorSet descriptor_set_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkQueryPool stats_pool_ = VK_NULL_HANDLE;
};

/// A top-down debug view of a cluster frame (RendererConfig::clusters): every (object, cluster)
/// pair's box placed by its object's transform, filled by the class the frame gave it (dark grey
/// of a culled object, grey outside, blue back-facing, violet occluded, green drawn on top), the
/// frustum and the eye as top_down_image draws them.
Image cluster_top_down_image(const Renderer& renderer, const FrameStats& stats, const Camera& camera,
                             std::uint32_t size);

/// The CPU occlusion path's occluders for `scene`: its objects the renderer draws as boxes (those
/// without triangles), as it draws them (occlusion::occluder_box of the local box and the world
/// transform). Mesh objects are left out: their boxes are not inside them.
std::vector<occlusion::OccluderBox> box_occluders(const Scene& scene);

}  // namespace cullpipe::render
