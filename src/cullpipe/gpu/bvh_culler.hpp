#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "cullpipe/bvh/bvh.hpp"
#include "cullpipe/cull/instances.hpp"
#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/frustum.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/compute_pipeline.hpp"
#include "cullpipe/vulkan/context.hpp"

namespace cullpipe::gpu {

/// Hierarchical frustum culling of a flattened BVH on a Vulkan device (shaders/cull_bvh.comp),
/// in one dispatch: the tree is cut into subtrees of at most subtree_objects() objects, one
/// invocation per subtree and view, which tests the nodes from the root down to its subtree;
/// a workgroup is one subgroup (the device's subgroup size, at most BVH_CULL_GROUP_SIZE), and
/// it walks its subtrees together, every lane taking a node of any of them each round; every
/// node test is counted once per view. OUTSIDE drops a subtree, INSIDE
/// accepts its object range with no further tests, INTERSECTING descends; objects of
/// INTERSECTING leaves are tested on the planes the leaf straddles (boxes first by their centre
/// bound, the flat pass's, and in full where it leaves them open). Any number of views per
/// pass, each with its own outputs. Classes and test counts equal bvh::cull_hierarchical bit
/// for bit; the visible set equals flat culling's. Objects are AABBs, OBBs or spheres (a tree
/// over OBBs or spheres is built over bvh::enclosing_boxes; its nodes are tested with
/// bvh::classify_masked_margin, so every class equals flat culling's). With a depth pyramid
/// (CullOptions::pyramid) nodes and objects are also tested for occlusion in the same dispatch,
/// and an occluded node skips its subtree's occlusion tests: classes and counts equal
/// occlusion::cull_hierarchical's, so every class equals the flat pass's. Visible ids and draws
/// come in GPU arrival order (CullOptions::ordered is not supported). Not thread-safe.
class BvhCuller {
 public:
  explicit BvhCuller(const vulkan::Context& ctx);
  ~BvhCuller();
  BvhCuller(const BvhCuller&) = delete;
  BvhCuller& operator=(const BvhCuller&) = delete;

  /// Uploads a flattened tree over `boxes` (as bvh::flatten lays it out), replacing any
  /// earlier upload; call again after a refit. Throws std::invalid_argument when the tree is
  /// not one over these boxes (ids out of range or repeated, links or object ranges not nested
  /// as flatten nests them, boxes invalid or not enclosing), std::length_error when a buffer
  /// would exceed one texel buffer view (maxTexelBufferElements) or, for the cut's list of
  /// subtrees, one storage buffer, or when one workgroup's cut subtrees span 2^25 nodes or more
  /// (BVH_WORKGROUP_NODE_SPAN; far past any default cut), and std::invalid_argument for 2^31
  /// objects or more. Boxes also get a centre bound each
  /// (16 bytes, in tree order), which settles most of a straddling leaf's boxes with one texel
  /// (as the flat pass does). O(nodes + objects).
  void upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes);
  /// The same for OBBs or spheres; the tree's boxes must enclose bvh::enclosing_box of each.
  void upload(const bvh::FlatTree& tree, std::span<const Obb> obbs);
  void upload(const bvh::FlatTree& tree, std::span<const Sphere> spheres);
  /// A tree over moving boxes: uploads `tree` (as bvh::flatten lays it out; its object ids are
  /// the set's slots) with the set's meshes and instances, its node boxes refitted on the host
  /// to instances.world_volumes() (whatever boxes it came with), and culls their world boxes as
  /// upload(refitted tree, world boxes) would. From then on update() sends only the objects that
  /// moved, and the next pass first places them on the device (the placing pass GpuCuller runs,
  /// bit for bit InstanceSet::world_volumes), then refits the nodes above them there from the
  /// leaves up (shaders/refit_bvh.comp, a dispatch per height: bvh::refit's boxes bit for bit),
  /// then culls: no volume or node box travels from the host while the tree's topology stays. Its classes equal
  /// bvh::cull_hierarchical's on the refitted tree and the set's world volumes, object by object. A tree whose quality
  /// has worn down (bvh::DynamicTree decides when, on the host) or a set whose size changed is uploaded again. Throws
  /// as upload(tree, boxes) does for a tree whose links, ranges or ids are not flatten's (before anything changes).
  void upload(const bvh::FlatTree& tree, const InstanceSet<Aabb>& instances);
  /// Sends what moved in the set uploaded last: the transforms and mesh indices of `slots`
  /// (InstanceSet::changed_slots(), ascending). Updates that no pass has placed yet merge, each
  /// object placed once. Only their leaves and the leaves' ancestors are refitted (marked here,
  /// climbing until a node already marked): a refit costs what moved, not the whole tree.
  /// Throws std::invalid_argument, sending nothing, when no set was uploaded, its size or meshes
  /// changed (upload a tree over it again), or a slot is out of order or range.
  void update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots);
  /// Objects the next pass (or refit()) places and refits the tree for.
  std::size_t pending_placements() const { return pending_.size(); }
  /// Places and refits what update() sent, submits and waits, without culling (record() does the
  /// same before it culls). Its times: the GPU's between timestamps around the refit alone (after
  /// the placing), and the wall time of recording, submission and waiting (both 0 when nothing
  /// was pending).
  CullTimings refit();
  /// The tree's node boxes as the device holds them, depth first: after a pass or refit() has
  /// completed, the boxes the last refit wrote (a host tree's quality can be measured on them).
  std::vector<Aabb> node_boxes() const;

  /// The cut's size: the traversal's invocations take subtrees of at most this many objects
  /// (and BVH_CUT_MAX_HEIGHT levels below their root), or single leaves. Fewer, larger subtrees
  /// mean fewer redundant tests of the nodes above them and fewer workgroups to share the walks.
  /// Default: kCpuSubtreeObjects on a CPU device (lavapipe runs few invocations at a time, so
  /// fewer, larger subtrees serve it best), else kGpuSubtreeObjects (more invocations for a wide
  /// GPU; not tuned on one). Takes effect at the next upload; throws std::invalid_argument for 0.
  static constexpr std::uint32_t kCpuSubtreeObjects = 4096, kGpuSubtreeObjects = 128;
  /// Passes with occlusion take their own cut, of subtrees of at most this many objects (and
  /// subtree_objects()): lavapipe ends every loop of an invocation once its loops together have
  /// run 65535 iterations, and each object tested for occlusion costs up to 1 + texels_per_axis
  /// of them, and as many again plus refine_texels_per_axis when it is read a second time
  /// (at most 34), so a workgroup's objects are kept to a few thousand (bench/NOTES.md, The GPU
  /// passes on lavapipe).
  static constexpr std::uint32_t kOcclusionSubtreeObjects = 512;
  void set_subtree_objects(std::uint32_t objects);
  std::uint32_t subtree_objects() const { return subtree_objects_; }
  /// Where the walk keeps its per-workgroup stacks: in the records image (default on a CPU
  /// device: lavapipe loads shared memory lane by lane, an image by gathers) or in shared
  /// memory (default on a GPU). The answers are the same; tests switch it to cover both.
  void set_walk_stack_in_records(bool in_records) { stack_in_records_ = in_records; }
  bool walk_stack_in_records() const { return stack_in_records_; }
  /// Workgroups along x before the dispatch folds into y; 0 means the device limit
  /// (maxComputeWorkGroupCount[0]). Tests set it low to exercise the fold.
  void set_max_groups_per_dispatch(std::uint32_t groups) { max_groups_x_ = groups; }
  /// The kind of the volumes uploaded last.
  BvKind kind() const { return kind_; }

  /// One draw template per object, by object id (see GpuCuller::upload_draws).
  void upload_draws(std::span<const DrawCommand> templates);

  /// Culls against every view in one submission and waits (see GpuCuller::cull). Over OBBs or
  /// spheres the frusta need unit plane normals (bvh::require_unit_normals; Frustum's factories
  /// make them), else std::invalid_argument.
  CullResult cull(std::span<const Frustum> views, const CullOptions& options = {});
  /// Records the pass into the caller's command buffer (see GpuCuller::record for the rules).
  void record(VkCommandBuffer cmd, std::span<const Frustum> views, const CullOptions& options = {});
  /// The results of the last recorded pass, once its submission has completed.
  CullResult read_results() const;

  /// Output buffers of the last pass, laid out as GpuCuller's.
  const vulkan::Buffer& draw_buffer() const { return draws_; }
  const vulkan::Buffer& counter_buffer() const { return counters_; }
  std::size_t last_visible_capacity() const { return last_capacity_; }

  std::size_t object_count() const { return object_count_; }
  std::size_t node_count() const { return node_count_; }
  /// Levels of the tree.
  std::uint32_t levels() const { return levels_; }
  /// Subtrees of the cut, one invocation each per view; of the occlusion passes' cut.
  std::size_t cut_count() const { return cut_count_; }
  std::size_t occlusion_cut_count() const { return occlusion_cut_count_; }

 private:
  void prepare(std::span<const Frustum> views, const CullOptions& options);
  void record_passes(VkCommandBuffer cmd, VkQueryPool timestamps);
  /// One variant of cull_bvh.comp.
  struct PipelineKey {
    BvKind kind = BvKind::Aabb;
    bool draws = false;             // write indirect draws
    bool classes = false;           // write the per-object classes
    bool stack_in_records = false;  // the walk's stack in the records image, not shared memory
    // Test the kept nodes and objects against the depth pyramid: detail::occlusion_texels's
    // packed texels and refining texels (0: no occlusion test).
    std::uint32_t occlusion_texels = 0;
    auto operator<=>(const PipelineKey&) const = default;
  };
  const vulkan::ComputePipeline& pipeline(const CullOptions& options);  // for kind_ and stack_in_records_
  template <class Volume>
  void upload_impl(const bvh::FlatTree& tree, std::span<const Volume> volumes);
  void update_descriptors();
  void take_placements();  // the pending placements into the list, for this pass
  // Places and refits what take_placements() took; timestamps 0 and 1 around the refit alone.
  void record_refit(VkCommandBuffer cmd, VkQueryPool timestamps = VK_NULL_HANDLE);

  const vulkan::Context& ctx_;
  std::uint32_t group_size_ = BVH_CULL_GROUP_SIZE;  // the device's subgroup size, at most this
  std::uint32_t subtree_objects_;
  // On a CPU device the walk stacks live in the records image, not in shared memory (see
  // STACK_IN_RECORDS in cull_bvh.comp).
  bool stack_in_records_ = false;
  std::uint32_t max_groups_x_ = 0;
  detail::PipelineCache<PipelineKey> pipelines_;
  BvKind kind_ = BvKind::Aabb;
  vulkan::Buffer bounds_, classes_, visible_, counters_, views_, templates_, draws_;
  vulkan::Buffer nodes_, objects_, cuts_, records_;
  vulkan::Buffer centres_;                   // AABBs: centre and bound per object in tree order (BVH_BINDING_CENTRES)
  vulkan::Buffer occlusion_views_;           // GpuOcclusionView per view (BVH_BINDING_OCCLUSION_VIEWS)
  vulkan::Buffer no_pyramid_;                // bound to BVH_BINDING_PYRAMID in passes without occlusion
  const vulkan::Buffer* pyramid_ = nullptr;  // the buffer bound to BVH_BINDING_PYRAMID
  // The pyramid the descriptors hold, by DepthPyramidPass::generation() (0: none).
  std::uint64_t written_pyramid_ = ~std::uint64_t{0}, pyramid_generation_ = 0;
  // Instances (upload(tree, instances)): the meshes' words (to recognise the set), each slot's
  // place in the tree order, the placements no pass has taken (and where each position's is,
  // kNone if nowhere). For the refit: every node's entry by height, each node's parent, each
  // position's leaf, the nodes marked for the next refit, and the runs of the device's order
  // the pass being recorded refits (one height each); and the two passes.
  bool instanced_ = false;
  std::vector<std::uint32_t> mesh_words_, position_, queued_;
  std::vector<GpuInstance> pending_;
  std::vector<GpuRefitEntry> refit_order_host_;                        // every node, by height
  std::vector<std::uint32_t> refit_starts_, refit_parents_, leaf_at_;  // each height's start in it
  std::vector<std::uint8_t> stale_;
  std::size_t stale_count_ = 0;
  bool order_is_full_ = false;  // refit_order_ holds the whole order (not a marked part)
  struct RefitRange {
    std::uint32_t begin, end;
    bool leaves;
  };
  std::vector<RefitRange> refit_ranges_;
  std::size_t placing_ = 0;  // list entries the pass being recorded places
  vulkan::Buffer meshes_, place_list_, refit_order_;
  std::unique_ptr<vulkan::ComputePipeline> place_pipeline_, refit_pipelines_[2];  // refitting: leaves, inner nodes
  std::unique_ptr<detail::PassResources> place_resources_, refit_resources_;
  // After the buffers: destroyed first, it waits for the device (own devices) before they go.
  std::unique_ptr<detail::PassResources> resources_;
  std::size_t object_count_ = 0, node_count_ = 0, template_count_ = 0;
  std::uint32_t levels_ = 0;
  std::size_t cut_count_ = 0, occlusion_cut_count_ = 0, groups_per_view_ = 0, group_x_ = 0, group_y_ = 0;
  std::size_t last_capacity_ = 0, last_view_count_ = 0;
  CullOptions last_options_;
  bool descriptors_dirty_ = true;
};

}  // namespace cullpipe::gpu
