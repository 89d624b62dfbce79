#include "cullpipe/gpu/bvh_culler.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <chrono>
#include <cstring>
#include <stdexcept>
#include <string>
#include <type_traits>

#include "cullpipe/bvh/box_ops.hpp"
#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/core/prefetch.hpp"
#include "cullpipe/geom/plane_bounds.hpp"
#include "cullpipe/geom/validate.hpp"
#include "cullpipe/gpu/pass_support.hpp"
#include "cullpipe/vulkan/check.hpp"

// SPIR-V compiled from shaders/cull_bvh.comp at build time (glslangValidator --vn).
#include "cull_bvh.spv.h"
#include "refit_bvh.spv.h"

namespace cullpipe::gpu {
namespace {

constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
constexpr VkBufferUsageFlags kTexel = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT;
// The volumes, centre bounds and nodes are storage buffers too: the placing and refitting
// passes of a tree over instances write them.
constexpr VkBufferUsageFlags kWritten = kTexel | kStorage;
// Object volumes, views, nodes, the object order and the centre bounds are read through uniform
// texel buffers (see cull_bvh.comp).
constexpr std::uint32_t kTexelBindings = 1u << BINDING_BOUNDS | 1u << BINDING_VIEWS | 1u << BVH_BINDING_NODES |
                                         1u << BVH_BINDING_OBJECTS | 1u << BVH_BINDING_CENTRES |
                                         1u << BVH_BINDING_OCCLUSION_VIEWS;
// The traversal records are written and read back within the pass through a storage texel
// buffer: on lavapipe an image load gathers the lanes' records into a vector, where a
// storage-buffer load inserts each lane's words through the stack (a stall per lane and word).
constexpr std::uint32_t kRecordBindings = 1u << BVH_BINDING_RECORDS;
constexpr VkBufferUsageFlags kRecordUsage = VK_BUFFER_USAGE_STORAGE_TEXEL_BUFFER_BIT;
constexpr std::uint32_t kRefitTexelBindings =
    1u << REFIT_BINDING_NODES | 1u << REFIT_BINDING_BOUNDS | 1u << REFIT_BINDING_ORDER;
constexpr std::uint32_t kStorageBindings =
    BVH_BINDING_COUNT - std::uint32_t(std::popcount(kTexelBindings | kRecordBindings));

}  // namespace

BvhCuller::BvhCuller(const vulkan::Context& ctx)
    : ctx_(ctx),
      subtree_objects_(ctx.properties().deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU ? kCpuSubtreeObjects
                                                                                  : kGpuSubtreeObjects),
      stack_in_records_(ctx.properties().deviceType == VK_PHYSICAL_DEVICE_TYPE_CPU) {
  const VkPhysicalDeviceLimits& limits = ctx_.properties().limits;
  // A workgroup is one subgroup (cull_bvh.comp walks the subtrees of a subgroup together, on
  // a stack in shared memory): the device's subgroup size, at most BVH_CULL_GROUP_SIZE.
  VkPhysicalDeviceSubgroupProperties subgroup{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_SUBGROUP_PROPERTIES};
  VkPhysicalDeviceProperties2 properties{VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2, &subgroup, {}};
  vkGetPhysicalDeviceProperties2(ctx_.physical_device(), &properties);
  group_size_ = std::clamp<std::uint32_t>(subgroup.subgroupSize, 1, BVH_CULL_GROUP_SIZE);
  if (limits.maxComputeWorkGroupSize[0] < group_size_ || limits.maxComputeWorkGroupInvocations < group_size_)
    throw vulkan::Error("hierarchical culling needs workgroups of " + std::to_string(group_size_) + " invocations; " +
                        ctx_.info().name + " allows " + std::to_string(limits.maxComputeWorkGroupInvocations));
  const std::uint32_t stack_bytes = group_size_ * BVH_STACK_PER_INVOCATION * 4;
  if (limits.maxComputeSharedMemorySize < stack_bytes)
    throw vulkan::Error("hierarchical culling needs " + std::to_string(stack_bytes) +
                        " bytes of shared memory per workgroup; " + ctx_.info().name + " has " +
                        std::to_string(limits.maxComputeSharedMemorySize));
  if (limits.maxPerStageDescriptorStorageBuffers < kStorageBindings)
    throw vulkan::Error("hierarchical culling needs " + std::to_string(kStorageBindings) +
                        " storage buffers per stage; " + ctx_.info().name + " allows " +
                        std::to_string(limits.maxPerStageDescriptorStorageBuffers));
  detail::check_texel_format(ctx_, "hierarchical culling");
  detail::check_record_format(ctx_, "hierarchical culling");
  detail::check_subgroup_operations(ctx_,
                                    VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_ARITHMETIC_BIT |
                                        VK_SUBGROUP_FEATURE_BALLOT_BIT | VK_SUBGROUP_FEATURE_SHUFFLE_BIT,
                                    "hierarchical culling");
  resources_ = std::make_unique<detail::PassResources>(ctx_, pipeline(CullOptions{}).set_layout(), BVH_BINDING_COUNT,
                                                       kTexelBindings, kRecordBindings);
}

BvhCuller::~BvhCuller() = default;

const vulkan::ComputePipeline& BvhCuller::pipeline(const CullOptions& options) {
  const PipelineKey key{.kind = kind_,
                        .draws = options.draws,
                        .classes = options.classes,
                        .stack_in_records = stack_in_records_,
                        .occlusion_texels = detail::occlusion_texels(options)};
  return pipelines_.get(key, [&] {
    const std::string name = "hierarchical cull (" + std::string(to_string(key.kind)) + (key.draws ? ", draws" : "") +
                             (key.classes ? ", classes" : "") + (key.stack_in_records ? ", stacks in records" : "") +
                             (key.occlusion_texels ? ", occlusion" : "") + ")";
    // Specialization constants: 1 group size, 2 volume kind, 3 draws, 4 classes, 5 stacks in the
    // records, 6 occlusion, 7 texels per axis of the occlusion test, 10 its refining texels (8,
    // 9 unused).
    static_assert(BV_KIND_AABB == 0 && BV_KIND_OBB == 1 && BV_KIND_SPHERE == 2, "BvKind order must match the shader");
    std::uint32_t spec[11] = {0u,
                              group_size_,
                              std::uint32_t(key.kind),
                              key.draws ? 1u : 0u,
                              key.classes ? 1u : 0u,
                              key.stack_in_records ? 1u : 0u};
    detail::set_occlusion_constants(spec, key.occlusion_texels);
    return std::make_unique<vulkan::ComputePipeline>(
        ctx_, vulkan::ComputePipelineDesc{std::span<const std::uint32_t>(cullpipe_cull_bvh_spv), BVH_BINDING_COUNT,
                                          sizeof(BvhCullParams), spec, name.c_str(), kTexelBindings, kRecordBindings});
  });
}

void BvhCuller::upload(const bvh::FlatTree& tree, std::span<const Aabb> boxes) { upload_impl(tree, boxes); }
void BvhCuller::upload(const bvh::FlatTree& tree, std::span<const Obb> obbs) { upload_impl(tree, obbs); }
void BvhCuller::upload(const bvh::FlatTree& tree, std::span<const Sphere> spheres) { upload_impl(tree, spheres); }

template <class Volume>
void BvhCuller::upload_impl(const bvh::FlatTree& tree, std::span<const Volume> boxes) {
  const std::size_t n = boxes.size(), nodes = tree.nodes.size();
  const std::string kind(to_string(kind_of<Volume>()));
  auto bad = [&](const std::string& what) { throw std::invalid_argument("BvhCuller::upload: " + what); };
  // (An accepted range's record flags OCCLUDED ranges in its count's top bit: cull_bvh.comp.)
  if (nodes >= std::size_t(UINT32_MAX) || n >= (std::size_t(1) << 31))
    bad("too many nodes or objects (" + std::to_string(nodes) + " nodes, " + std::to_string(n) +
        " objects) for the traversal's 31-bit counts and 32-bit indices");
  // The layout flatten() gives, which the traversal relies on (skip links, nested ranges).
  std::vector<std::uint32_t> depth;
  if (const std::string why = bvh::check_flat_tree(tree, boxes, &depth); !why.empty()) bad(why);
  // The cuts: the highest subtrees of at most `limit` objects and BVH_CUT_MAX_HEIGHT levels
  // below their root, and the leaves above them (see cull_bvh.comp); one for frustum passes,
  // then one of smaller subtrees for occlusion passes, in one buffer.
  std::vector<std::uint32_t> height(nodes, 0), cuts;
  for (std::size_t i = nodes; i-- > 0;)
    if (!tree.nodes[i].leaf) height[i] = 1 + std::max(height[i + 1], height[tree.nodes[i + 1].skip]);
  auto cut = [&](std::uint32_t limit) {
    for (std::size_t i = 0; i < nodes;) {
      const bvh::FlatNode& node = tree.nodes[i];
      if (node.leaf || (node.count <= limit && height[i] <= BVH_CUT_MAX_HEIGHT)) {
        cuts.push_back(std::uint32_t(i));
        i = node.skip;
      } else {
        ++i;
      }
    }
  };
  cut(subtree_objects_);
  const std::size_t frustum_cuts = cuts.size();
  cut(std::min(subtree_objects_, kOcclusionSubtreeObjects));
  const std::uint32_t levels = depth.empty() ? 0 : *std::max_element(depth.begin(), depth.end());
  // A workgroup's walk stack holds nodes as offsets from its first cut node (cull_bvh.comp).
  auto check_spans = [&](std::size_t first, std::size_t end) {
    for (std::size_t g = first; g < end; g += group_size_) {
      const std::uint32_t last = cuts[std::min(end, g + group_size_) - 1];
      const std::size_t span = std::size_t(tree.nodes[last].skip) - cuts[g];
      if (span >= BVH_WORKGROUP_NODE_SPAN)
        throw std::length_error("BvhCuller::upload: the subtrees of one workgroup (" + std::to_string(group_size_) +
                                " cut subtrees from node " + std::to_string(cuts[g]) + ") span " +
                                std::to_string(span) + " nodes; at most " +
                                std::to_string(BVH_WORKGROUP_NODE_SPAN - 1) +
                                " are supported (use smaller subtrees: set_subtree_objects)");
    }
  };
  check_spans(0, frustum_cuts);
  check_spans(frustum_cuts, cuts.size());

  using Packed = decltype(pack(boxes[0]));
  const VkDeviceSize box_bytes = VkDeviceSize(n) * sizeof(Packed),
                     node_bytes = VkDeviceSize(nodes) * sizeof(GpuBvhNode);
  detail::check_texel_range(ctx_, box_bytes, std::to_string(n) + " " + kind + " volumes");
  detail::check_texel_range(ctx_, node_bytes, std::to_string(nodes) + " BVH nodes");
  // The object order as texels of four ids (padded).
  const VkDeviceSize order_bytes = (VkDeviceSize(n) + 3) / 4 * 16,
                     cut_bytes = VkDeviceSize(cuts.size()) * sizeof(std::uint32_t);
  detail::check_texel_range(ctx_, order_bytes, std::to_string(n) + " object ids");
  constexpr bool kBoxes = std::is_same_v<Volume, Aabb>;  // (only boxes are settled by a centre bound)
  const VkDeviceSize centre_bytes = kBoxes ? VkDeviceSize(n) * sizeof(glm::vec4) : 0;
  detail::check_texel_range(ctx_, centre_bytes, std::to_string(n) + " centre bounds");
  detail::check_storage_range(ctx_, cut_bytes, std::to_string(cuts.size()) + " BVH subtrees");
  object_count_ = node_count_ = cut_count_ = occlusion_cut_count_ = 0;  // stay 0 if an allocation below fails
  instanced_ = false;  // a tree over volumes from the host: nothing to place or refit
  pending_.clear();
  bool& dirty = descriptors_dirty_;
  detail::ensure_buffer(ctx_, bounds_, box_bytes, kWritten, "object volume buffer", dirty);
  detail::ensure_buffer(ctx_, nodes_, node_bytes, kWritten, "BVH node buffer", dirty);
  detail::ensure_buffer(ctx_, objects_, order_bytes, kTexel, "BVH object order buffer", dirty);
  detail::ensure_buffer(ctx_, cuts_, cut_bytes, kStorage, "BVH cut buffer", dirty);
  detail::ensure_buffer(ctx_, centres_, centre_bytes, kWritten, "centre bound buffer", dirty);
  // Written straight into the mapped buffers (no staging copies whose pages fault in on every
  // upload of a refitted tree).
  GpuBvhNode* gpu_nodes = nodes_.as<GpuBvhNode>().data();
  for (std::size_t i = 0; i < nodes; ++i) {
    const bvh::FlatNode& node = tree.nodes[i];
    const std::uint32_t second = node.leaf ? bvh::kNone : tree.nodes[i + 1].skip;
    gpu_nodes[i] = {node.box.min, node.first, node.box.max,        node.count,
                    node.skip,    second,     node.leaf ? 1u : 0u, depth[i]};
  }
  auto gpu_boxes = bounds_.as<Packed>();
  // Boxes also get their centre bounds (the flat pass's, in tree order), a block at a time.
  constexpr std::size_t kBlock = 256;
  std::array<Volume, kBoxes ? kBlock : 1> block;
  for (std::size_t first = 0; first < n; first += kBlock) {
    const std::size_t end = std::min(n, first + kBlock);
    for (std::size_t i = first; i < end; ++i) {  // tree order
      if (i + kGatherAhead < n) prefetch_object(&boxes[tree.objects[i + kGatherAhead]]);
      const Volume& box = boxes[tree.objects[i]];
      gpu_boxes[i] = pack(box);
      if constexpr (kBoxes) block[i - first] = box;
    }
    if constexpr (kBoxes)
      plane_bounds::aabb_centre_bounds(std::span<const Aabb>(block.data(), end - first),
                                       centres_.as<glm::vec4>().subspan(first, end - first));
  }
  if (n) std::memcpy(objects_.data(), tree.objects.data(), n * sizeof(std::uint32_t));
  if (!cuts.empty()) std::memcpy(cuts_.data(), cuts.data(), cuts.size() * sizeof(std::uint32_t));
  object_count_ = n;
  node_count_ = nodes;
  cut_count_ = frustum_cuts;
  occlusion_cut_count_ = cuts.size() - frustum_cuts;
  levels_ = levels;
  kind_ = kind_of<Volume>();
}

void BvhCuller::upload(const bvh::FlatTree& tree, const InstanceSet<Aabb>& instances) {
  const std::size_t n = instances.size(), nodes = tree.nodes.size();
  std::vector<Aabb> world(n);
  instances.world_volumes(world);
  const std::vector<std::uint32_t> words = detail::mesh_words(instances);
  const VkDeviceSize list_bytes = VkDeviceSize(n) * sizeof(GpuInstance),
                     mesh_bytes = VkDeviceSize(words.size()) * sizeof(std::uint32_t),
                     order_bytes = VkDeviceSize(nodes) * sizeof(GpuRefitEntry);
  const std::string objects = std::to_string(n) + " box instances";
  detail::check_texel_range(ctx_, list_bytes, objects + " (placing list)");
  detail::check_texel_range(ctx_, mesh_bytes, std::to_string(instances.meshes().size()) + " meshes");
  detail::check_storage_range(ctx_, VkDeviceSize(n) * sizeof(GpuAabb), objects + " (world boxes written by placing)");
  detail::check_storage_range(ctx_, VkDeviceSize(nodes) * sizeof(GpuBvhNode),
                              std::to_string(nodes) + " BVH nodes (written by refitting)");
  detail::check_texel_range(ctx_, order_bytes, std::to_string(nodes) + " BVH nodes (refitting order)");
  if (!place_pipeline_) place_pipeline_ = detail::make_place_pipeline(ctx_, BvKind::Aabb);
  for (const bool leaves : {true, false}) {  // a pipeline for the leaves, one for inner nodes
    auto& pipeline = refit_pipelines_[leaves ? 0 : 1];
    if (pipeline) continue;
    const std::uint32_t spec[1] = {leaves ? 1u : 0u};
    pipeline = std::make_unique<vulkan::ComputePipeline>(
        ctx_, vulkan::ComputePipelineDesc{
                  std::span<const std::uint32_t>(cullpipe_refit_bvh_spv), REFIT_BINDING_COUNT, sizeof(RefitParams),
                  spec, leaves ? "BVH refitting (leaves)" : "BVH refitting (inner nodes)", kRefitTexelBindings});
  }
  if (!place_resources_)
    place_resources_ = std::make_unique<detail::PassResources>(ctx_, place_pipeline_->set_layout(), PLACE_BINDING_COUNT,
                                                               detail::kPlaceTexelBindings);
  if (!refit_resources_)
    refit_resources_ = std::make_unique<detail::PassResources>(ctx_, refit_pipelines_[0]->set_layout(),
                                                               REFIT_BINDING_COUNT, kRefitTexelBindings);
  // bvh::refit below indexes by the tree's links: they are checked first.
  if (const std::string why = bvh::check_flat_structure(tree, n); !why.empty())
    throw std::invalid_argument("BvhCuller::upload: " + why);
  // The instances' own buffers first: a failure here leaves the earlier upload as it was.
  bool unused = false;
  detail::ensure_buffer(ctx_, meshes_, mesh_bytes, kTexel, "mesh volume buffer", unused);
  detail::ensure_buffer(ctx_, place_list_, list_bytes, kTexel, "placing list buffer", unused);
  detail::ensure_buffer(ctx_, refit_order_, order_bytes, kTexel, "BVH refitting order buffer", unused);
  // The tree as bvh::refit leaves it over the placed boxes: refits mark only the nodes above
  // moved objects, so every node's box must already be its children's union, as a refit on
  // the host computes it (a tree built or refitted earlier may hold looser boxes).
  bvh::FlatTree tight = tree;
  bvh::refit(tight, world);
  upload_impl(tight, std::span<const Aabb>(world));  // checks the tree; clears instanced_

  // The nodes by height (a leaf 0, an inner node one above its higher child), leaves first: a
  // refitting dispatch per height finds its children done by the ones before.
  std::vector<std::uint32_t> height(nodes, 0);
  std::uint32_t top = 0;
  for (std::size_t i = nodes; i-- > 0;) {
    if (!tree.nodes[i].leaf) height[i] = 1 + std::max(height[i + 1], height[tree.nodes[i + 1].skip]);
    top = std::max(top, height[i]);
  }
  // Every node's entry, by height and within a height by index (the depth-first order keeps
  // a dispatch's reads near each other); each node's parent, and each object's leaf (by its
  // place in the tree order): update() climbs from the leaves of the moved objects.
  std::vector<std::uint32_t> starts(nodes ? top + 2 : 1, 0), next;
  for (const std::uint32_t h : height) ++starts[h + 1];
  for (std::size_t h = 1; h < starts.size(); ++h) starts[h] += starts[h - 1];
  next.assign(starts.begin(), starts.end() - 1);
  std::vector<GpuRefitEntry> order(nodes);
  std::vector<std::uint32_t> parents(nodes, bvh::kNone), leaf_at(n, 0);
  for (std::size_t i = 0; i < nodes; ++i) {
    const bvh::FlatNode& node = tree.nodes[i];
    if (node.leaf) {
      order[next[height[i]]++] = GpuRefitEntry{std::uint32_t(i), node.first, node.count, 0};
      for (std::uint32_t k = node.first; k < node.first + node.count; ++k) leaf_at[k] = std::uint32_t(i);
    } else {
      const std::uint32_t second = tree.nodes[i + 1].skip;
      order[next[height[i]]++] = GpuRefitEntry{std::uint32_t(i), std::uint32_t(i + 1), second, 0};
      parents[i + 1] = parents[second] = std::uint32_t(i);
    }
  }
  if (mesh_bytes) std::memcpy(meshes_.data(), words.data(), mesh_bytes);
  // This upload's bytes of each buffer (one kept from a larger scene may pass a binding's limit
  // whole).
  using Range = detail::PassResources::Range;
  const VkDeviceSize bound_bytes = VkDeviceSize(n) * sizeof(GpuAabb), centre_bytes = VkDeviceSize(n) * 16,
                     node_bytes = VkDeviceSize(nodes) * sizeof(GpuBvhNode);
  auto part = [](const vulkan::Buffer& b, VkDeviceSize bytes) {
    return Range{&b, 0, std::max<VkDeviceSize>(detail::kTexelBytes, std::min(b.size(), bytes))};
  };
  const Range place[PLACE_BINDING_COUNT] = {part(place_list_, list_bytes), part(meshes_, mesh_bytes),
                                            part(bounds_, bound_bytes), part(centres_, centre_bytes)};
  place_resources_->write(0, place);
  const Range refit[REFIT_BINDING_COUNT] = {part(nodes_, node_bytes), part(nodes_, node_bytes),
                                            part(bounds_, bound_bytes), part(refit_order_, order_bytes)};
  refit_resources_->write(0, refit);

  position_.assign(n, 0);
  for (std::size_t k = 0; k < n; ++k) position_[tree.objects[k]] = std::uint32_t(k);
  queued_.assign(n, bvh::kNone);
  pending_.clear();
  mesh_words_ = words;
  refit_order_host_ = std::move(order);
  refit_starts_ = std::move(starts);
  refit_parents_ = std::move(parents);
  leaf_at_ = std::move(leaf_at);
  stale_.assign(nodes, 0);
  stale_count_ = 0;
  order_is_full_ = false;
  instanced_ = true;
}

void BvhCuller::update(const InstanceSet<Aabb>& instances, std::span<const std::uint32_t> slots) {
  if (!instanced_)
    throw std::invalid_argument("BvhCuller::update: no box instances were uploaded (call upload(tree, instances))");
  if (instances.size() != object_count_)
    throw std::invalid_argument("BvhCuller::update: the set holds " + std::to_string(instances.size()) +
                                " objects, the tree " + std::to_string(object_count_) +
                                "; a set whose size changed needs a tree over it (upload(tree, instances))");
  if (detail::mesh_words(instances) != mesh_words_)
    throw std::invalid_argument("BvhCuller::update: the set's meshes are not those uploaded (upload it again)");
  instances.check_slots(slots, "BvhCuller::update");
  for (const std::uint32_t s : slots) {
    const std::uint32_t at = position_[s];
    const GpuInstance entry = detail::list_entry(instances, s, at);
    if (queued_[at] == bvh::kNone) {
      queued_[at] = std::uint32_t(pending_.size());
      pending_.push_back(entry);
    } else {
      pending_[queued_[at]] = entry;  // placed once, as it is now
    }
    // Its leaf and the leaf's ancestors are refitted, each once: the climb stops at a node
    // already marked, whose ancestors are.
    for (std::uint32_t node = leaf_at_[at]; node != bvh::kNone && !stale_[node]; node = refit_parents_[node]) {
      stale_[node] = 1;
      ++stale_count_;
    }
  }
}

void BvhCuller::take_placements() {
  placing_ = pending_.size();
  if (placing_ == 0) return;
  // Copied for the pass; the queue and the marks stay until it is recorded (record_refit), so a
  // pass that fails before that leaves them for the next.
  std::memcpy(place_list_.data(), pending_.data(), placing_ * sizeof(GpuInstance));
  // The marked nodes' entries, by height, leaves first, in the order's own order. Past three
  // quarters of the nodes the whole order is refitted instead, written once and kept: picking
  // the marked ones out saved less than the scan cost (bench/NOTES.md, Moving instances).
  GpuRefitEntry* out = refit_order_.as<GpuRefitEntry>().data();
  refit_ranges_.clear();
  const std::size_t heights = refit_starts_.size() - 1;
  if (4 * stale_count_ > 3 * refit_order_host_.size()) {
    if (!order_is_full_) std::memcpy(out, refit_order_host_.data(), refit_order_host_.size() * sizeof(GpuRefitEntry));
    order_is_full_ = true;
    for (std::size_t h = 0; h < heights; ++h) refit_ranges_.push_back({refit_starts_[h], refit_starts_[h + 1], h == 0});
    return;
  }
  order_is_full_ = false;
  std::uint32_t written = 0;
  for (std::size_t h = 0; h < heights; ++h) {
    const std::uint32_t begin = written;
    for (std::uint32_t k = refit_starts_[h]; k < refit_starts_[h + 1]; ++k)
      if (stale_[refit_order_host_[k].node]) out[written++] = refit_order_host_[k];
    if (written > begin) refit_ranges_.push_back({begin, written, h == 0});
  }
}

void BvhCuller::record_refit(VkCommandBuffer cmd, VkQueryPool timestamps) {
  if (placing_ == 0) return;
  const VkPhysicalDeviceLimits& limits = ctx_.properties().limits;
  const std::uint32_t max_groups =
      max_groups_x_ ? std::min(max_groups_x_, limits.maxComputeWorkGroupCount[0]) : limits.maxComputeWorkGroupCount[0];
  detail::record_placing(cmd, *place_pipeline_, place_resources_->set(), placing_, max_groups);
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, timestamps, 0);
  const VkDescriptorSet set = refit_resources_->set();
  const std::uint64_t per_dispatch = std::uint64_t(max_groups) * REFIT_GROUP_SIZE;
  const vulkan::ComputePipeline* bound = nullptr;
  for (const RefitRange& range : refit_ranges_) {
    const vulkan::ComputePipeline& refit = *refit_pipelines_[range.leaves ? 0 : 1];
    if (bound != &refit) {
      vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, refit.pipeline());
      vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, refit.layout(), 0, 1, &set, 0, nullptr);
      bound = &refit;
    }
    for (std::uint64_t first = range.begin; first < range.end; first += per_dispatch) {
      const std::uint64_t count = std::min<std::uint64_t>(per_dispatch, range.end - first);
      const RefitParams params{std::uint32_t(first), std::uint32_t(count)};
      vkCmdPushConstants(cmd, refit.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
      vkCmdDispatch(cmd, vulkan::group_count(count, REFIT_GROUP_SIZE), 1, 1);
    }
    detail::record_compute_to_compute(cmd);  // the next height, and the culling, read these boxes
  }
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps, 1);
  // Recorded: the next pass places and refits only what is sent from now on.
  placing_ = 0;
  for (const GpuInstance& e : pending_) queued_[e.info.z] = bvh::kNone;
  pending_.clear();
  std::fill(stale_.begin(), stale_.end(), std::uint8_t{0});
  stale_count_ = 0;
}

CullTimings BvhCuller::refit() {
  if (pending_.empty()) return {};
  const auto start = std::chrono::steady_clock::now();
  take_placements();
  CullTimings t;
  t.gpu_ns = resources_->run([&](VkCommandBuffer cmd, VkQueryPool timestamps) {
    detail::record_entry_barrier(ctx_, cmd);
    record_refit(cmd, timestamps);
    detail::record_exit_barrier(ctx_, cmd);
  });
  t.wall_ns =
      double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  return t;
}

std::vector<Aabb> BvhCuller::node_boxes() const {
  std::vector<Aabb> boxes(node_count_);
  const auto nodes = nodes_.as<const GpuBvhNode>();
  for (std::size_t i = 0; i < node_count_; ++i) boxes[i] = {nodes[i].box_min, nodes[i].box_max};
  return boxes;
}

void BvhCuller::set_subtree_objects(std::uint32_t objects) {
  if (objects == 0) throw std::invalid_argument("BvhCuller::set_subtree_objects: 0 objects");
  subtree_objects_ = objects;
}

void BvhCuller::upload_draws(std::span<const DrawCommand> templates) {
  const VkDeviceSize bytes = VkDeviceSize(templates.size()) * sizeof(DrawCommand);
  detail::check_storage_range(ctx_, bytes, std::to_string(templates.size()) + " draw templates");
  template_count_ = 0;
  detail::ensure_buffer(ctx_, templates_, bytes, kStorage, "draw template buffer", descriptors_dirty_);
  if (bytes) std::memcpy(templates_.data(), templates.data(), bytes);
  template_count_ = templates.size();
}

void BvhCuller::update_descriptors() {
  if (!descriptors_dirty_ && written_pyramid_ == pyramid_generation_) return;
  static_assert(BINDING_BOUNDS == 0 && BINDING_CLASSES == 1 && BINDING_VISIBLE == 2 && BINDING_COUNTERS == 3 &&
                BINDING_VIEWS == 4 && BINDING_DRAW_TEMPLATES == 5 && BINDING_DRAWS == 6 && BVH_BINDING_NODES == 7 &&
                BVH_BINDING_OBJECTS == 8 && BVH_BINDING_CUTS == 9 && BVH_BINDING_RECORDS == 10 &&
                BVH_BINDING_CENTRES == 11 && BVH_BINDING_PYRAMID == 12 && BVH_BINDING_OCCLUSION_VIEWS == 13 &&
                BVH_BINDING_COUNT == 14);
  const vulkan::Buffer* const buffers[BVH_BINDING_COUNT] = {
      &bounds_, &classes_, &visible_, &counters_, &views_,   &templates_, &draws_,
      &nodes_,  &objects_, &cuts_,    &records_,  &centres_, pyramid_,    &occlusion_views_};
  resources_->write(buffers);
  written_pyramid_ = pyramid_generation_;
  descriptors_dirty_ = false;
}

void BvhCuller::prepare(std::span<const Frustum> views, const CullOptions& options) {
  if (options.ordered)
    throw std::invalid_argument(
        "hierarchical culling writes visible ids in arrival order; CullOptions::ordered is not supported");
  if (options.draws && template_count_ != object_count_)
    throw std::invalid_argument("draw commands requested, but " + std::to_string(template_count_) +
                                " draw templates were uploaded for " + std::to_string(object_count_) +
                                " objects (call upload_draws)");
  const std::size_t v = views.size();
  detail::check_occlusion(ctx_, options, v);
  for (const Frustum& f : views) {
    if (f.plane_count > MAX_FRUSTUM_PLANES) throw std::invalid_argument("a frustum has more than 6 planes");
    if (kind_ != BvKind::Aabb) bvh::require_unit_normals(f, "BvhCuller");
  }
  const std::size_t capacity = options.visible_capacity ? options.visible_capacity : object_count_;
  // Workgroups never straddle views; the dispatch folds into y past maxComputeWorkGroupCount[0].
  const VkPhysicalDeviceLimits& limits = ctx_.properties().limits;
  const std::size_t pass_cuts = options.pyramid ? occlusion_cut_count_ : cut_count_;
  groups_per_view_ = (pass_cuts + group_size_ - 1) / group_size_;
  const std::size_t groups = groups_per_view_ * v;
  const std::size_t max_x =
      max_groups_x_ ? std::min(max_groups_x_, limits.maxComputeWorkGroupCount[0]) : limits.maxComputeWorkGroupCount[0];
  group_x_ = std::min<std::size_t>(std::max<std::size_t>(groups, 1), max_x);
  group_y_ = (groups + group_x_ - 1) / group_x_;
  if (group_y_ > limits.maxComputeWorkGroupCount[1])
    throw std::length_error(std::to_string(v) + " views of " + std::to_string(pass_cuts) + " BVH subtrees need " +
                            std::to_string(groups) + " workgroups; " + ctx_.info().name + " dispatches at most " +
                            std::to_string(max_x) + " x " + std::to_string(limits.maxComputeWorkGroupCount[1]));
  const std::string views_x = std::to_string(v) + " views x ";
  auto check = [&](VkDeviceSize bytes, const std::string& what) { detail::check_storage_range(ctx_, bytes, what); };
  const VkDeviceSize outputs = VkDeviceSize(object_count_) * v * sizeof(std::uint32_t);
  const VkDeviceSize visible = VkDeviceSize(capacity) * v * sizeof(std::uint32_t);
  const VkDeviceSize draw_bytes = options.draws ? VkDeviceSize(capacity) * v * sizeof(DrawCommand) : 0;
  // A cut subtree has at most as many records as objects: one scratch slot per object and view.
  // A record per object and view, then (stacks in the records) each workgroup's walk stack.
  const VkDeviceSize stack_records =
      stack_in_records_ ? VkDeviceSize(groups_per_view_) * v * group_size_ * BVH_STACK_PER_INVOCATION : 0;
  const VkDeviceSize record_bytes = (VkDeviceSize(object_count_) * v + stack_records) * detail::kRecordBytes;
  detail::check_texel_range(ctx_, VkDeviceSize(v) * sizeof(GpuFrustum), std::to_string(v) + " views");
  check(VkDeviceSize(v) * sizeof(ViewCounters), std::to_string(v) + " view counters");
  check(outputs, views_x + std::to_string(object_count_) + " objects of output");
  check(visible, views_x + std::to_string(capacity) + " visible ids");
  check(draw_bytes, views_x + std::to_string(capacity) + " draw commands");
  detail::check_record_range(ctx_, record_bytes,
                             views_x + std::to_string(object_count_) + " objects of traversal records");
  bool& dirty = descriptors_dirty_;
  detail::ensure_buffer(ctx_, bounds_, 0, kWritten, "object volume buffer", dirty);
  detail::ensure_buffer(ctx_, nodes_, 0, kWritten, "BVH node buffer", dirty);
  detail::ensure_buffer(ctx_, centres_, 0, kWritten, "centre bound buffer", dirty);
  detail::ensure_buffer(ctx_, objects_, 0, kTexel, "BVH object order buffer", dirty);
  detail::ensure_buffer(ctx_, cuts_, 0, kStorage, "BVH cut buffer", dirty);
  detail::ensure_buffer(ctx_, templates_, 0, kStorage, "draw template buffer", dirty);
  detail::ensure_buffer(ctx_, classes_, outputs, kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT, "classification buffer",
                        dirty);
  detail::ensure_buffer(ctx_, visible_, visible, kStorage, "visible-id buffer", dirty);
  detail::ensure_buffer(ctx_, counters_, v * sizeof(ViewCounters),
                        kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
                        "counter buffer", dirty);
  detail::ensure_buffer(ctx_, views_, v * sizeof(GpuFrustum), kTexel, "view buffer", dirty);
  detail::ensure_buffer(ctx_, draws_, draw_bytes, kStorage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "draw buffer", dirty);
  detail::ensure_buffer(ctx_, records_, record_bytes, kRecordUsage, "BVH traversal record buffer", dirty);
  detail::ensure_buffer(ctx_, no_pyramid_, 16, kStorage, "empty pyramid buffer", dirty);
  detail::ensure_buffer(ctx_, occlusion_views_, (options.pyramid ? v : 1) * sizeof(GpuOcclusionView), kTexel,
                        "occlusion view buffer", dirty);
  pyramid_ = options.pyramid ? &options.pyramid->texels() : &no_pyramid_;
  pyramid_generation_ = options.pyramid ? options.pyramid->generation() : 0;
  update_descriptors();
  if (options.pyramid) detail::write_occlusion_views(options, occlusion_views_.as<GpuOcclusionView>());
  auto gpu_views = views_.as<GpuFrustum>();
  for (std::size_t i = 0; i < v; ++i) {
    gpu_views[i] = pack(views[i]);
    gpu_views[i].settle_margin = plane_bounds::settle_margin(views[i]);
  }
  last_capacity_ = capacity;
  last_view_count_ = v;
  last_options_ = options;
  pipeline(options);
}

void BvhCuller::record_passes(VkCommandBuffer cmd, VkQueryPool timestamps) {
  const std::size_t view_count = last_view_count_;
  detail::record_entry_barrier(ctx_, cmd);
  record_refit(cmd);  // objects that moved, placed and their tree refitted before it is walked
  vkCmdFillBuffer(cmd, counters_.handle(), 0, view_count * sizeof(ViewCounters), 0);
  // Objects no pass reaches are OUTSIDE; without class readback the buffer is left as is.
  if (object_count_ && last_options_.classes)
    vkCmdFillBuffer(cmd, classes_.handle(), 0, VkDeviceSize(object_count_) * view_count * 4, CLASS_OUTSIDE);
  detail::record_transfer_to_compute(cmd);
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, timestamps, 0);

  const bool occlusion = last_options_.pyramid != nullptr;
  const std::size_t pass_cuts = occlusion ? occlusion_cut_count_ : cut_count_;
  if (pass_cuts != 0) {
    BvhCullParams params{};
    params.object_count = std::uint32_t(object_count_);
    params.view_count = std::uint32_t(view_count);
    params.visible_capacity = std::uint32_t(last_capacity_);
    params.cut_count = std::uint32_t(pass_cuts);
    params.groups_per_view = std::uint32_t(groups_per_view_);
    params.cut_offset = occlusion ? std::uint32_t(cut_count_) : 0u;
    const vulkan::ComputePipeline& pipe = pipeline(last_options_);
    VkDescriptorSet set = resources_->set();
    vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
    vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &set, 0, nullptr);
    vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
    vkCmdDispatch(cmd, std::uint32_t(group_x_), std::uint32_t(group_y_), 1);
  }
  if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps, 1);
  detail::record_exit_barrier(ctx_, cmd);
}

void BvhCuller::record(VkCommandBuffer cmd, std::span<const Frustum> views, const CullOptions& options) {
  if (views.empty()) throw std::invalid_argument("BvhCuller::record: no views");
  prepare(views, options);
  take_placements();
  record_passes(cmd, VK_NULL_HANDLE);
}

CullResult BvhCuller::read_results() const {
  return detail::read_outputs({counters_, classes_, visible_, draws_}, object_count_, last_view_count_, last_capacity_,
                              last_options_);
}

CullResult BvhCuller::cull(std::span<const Frustum> views, const CullOptions& options) {
  if (views.empty()) return {};
  return detail::timed_pass(
      *resources_,
      [&] {
        prepare(views, options);
        take_placements();
      },
      [&](VkCommandBuffer cmd, VkQueryPool timestamps) { record_passes(cmd, timestamps); },
      [&] { return read_results(); });
}

}  // namespace cullpipe::gpu
