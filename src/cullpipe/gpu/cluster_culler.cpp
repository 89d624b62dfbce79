#include "cullpipe/gpu/cluster_culler.hpp"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>

#include "cullpipe/gpu/layout.hpp"
#include "cullpipe/gpu/pass_support.hpp"
#include "cullpipe/vulkan/check.hpp"

// SPIR-V compiled from shaders/ at build time.
#include "cluster_expand.spv.h"
#include "cluster_scatter.spv.h"
#include "compact_scan.spv.h"
#include "cull_clusters.spv.h"

namespace cullpipe::gpu {

namespace {

constexpr std::uint32_t kBindingCount = CLUSTER_BINDING_COUNT;
constexpr std::uint32_t kTexelBindings = 1u << BINDING_BOUNDS | 1u << BINDING_VIEWS | 1u << BINDING_CENTRES |
                                         1u << BINDING_OCCLUSION_VIEWS | 1u << CLUSTER_BINDING_PAIRS |
                                         1u << CLUSTER_BINDING_OBBS;
constexpr VkBufferUsageFlags kTexel = VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT;
constexpr VkBufferUsageFlags kStorage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
enum Shader { Cull = 0, Scan = 1, Scatter = 2, Expand = 3, ExpandWrite = 4 };

}  // namespace

ClusterCuller::ClusterCuller(const vulkan::Context& ctx) : ctx_(ctx) {
  detail::check_subgroup_operations(ctx_, VK_SUBGROUP_FEATURE_BASIC_BIT | VK_SUBGROUP_FEATURE_ARITHMETIC_BIT,
                                    "the cluster pass");
  detail::check_texel_format(ctx_, "the cluster pass");
  const auto& limits = ctx_.properties().limits;
  group_size_ =
      std::min({FLAT_CULL_GROUP_SIZE, limits.maxComputeWorkGroupSize[0], limits.maxComputeWorkGroupInvocations});
  max_groups_ = limits.maxComputeWorkGroupCount[0];
  const vulkan::ComputePipeline& first = pipeline(Cull);
  resources_ = std::make_unique<detail::PassResources>(ctx_, first.set_layout(), kBindingCount, kTexelBindings);
  resources_->ensure_sets(2);  // the cluster passes', and the listing's
  bool dirty = false;
  detail::ensure_buffer(ctx_, counters_, sizeof(ViewCounters),
                        kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
                        "cluster counter buffer", dirty);
  detail::ensure_buffer(ctx_, views_, sizeof(GpuFrustum), kTexel, "cluster view buffer", dirty);
  detail::ensure_buffer(ctx_, occlusion_views_, sizeof(GpuOcclusionView), kTexel, "cluster occlusion view buffer",
                        dirty);
  detail::ensure_buffer(ctx_, no_pyramid_, 16, kStorage, "empty pyramid buffer", dirty);
  detail::ensure_buffer(ctx_, no_classes_, 16, kStorage, "empty object class buffer", dirty);
  upload({}, {}, {});
}

ClusterCuller::~ClusterCuller() {
  if (ctx_.owns_device()) vkDeviceWaitIdle(ctx_.device());
}

const vulkan::ComputePipeline& ClusterCuller::pipeline(int which, bool occlusion, bool object_classes,
                                                       std::uint32_t texels, std::uint32_t refine) {
  if (which != Cull) occlusion = false, texels = 4, refine = 0;
  if (which != Expand && which != ExpandWrite) object_classes = false;
  // (texels and refine are at most 16: five bits each.)
  const std::uint32_t key =
      std::uint32_t(which) | (occlusion ? 1u : 0u) << 3 | (object_classes ? 1u : 0u) << 4 | texels << 5 | refine << 10;
  std::unique_ptr<vulkan::ComputePipeline>& slot = pipelines_[key];
  if (!slot) {
    // Specialization constants: 1 group size, 3 draws (scatter), 4 pairs per invocation (1),
    // 6 occlusion, 7 its texels per axis, 8 the object pass's classes, 9 the listing's stage,
    // 10 the occlusion test's refining texels.
    const std::uint32_t spec[11] = {0u,
                                    group_size_,
                                    1u,
                                    1u,
                                    1u,
                                    1u,
                                    occlusion ? 1u : 0u,
                                    texels,
                                    object_classes ? 1u : 0u,
                                    which == ExpandWrite ? 1u : 0u,
                                    refine};
    std::span<const std::uint32_t> spirv;
    std::string name;
    switch (which) {
      case Cull:
        spirv = cullpipe_cull_clusters_spv, name = "cluster cull";
        break;
      case Scan:
        spirv = cullpipe_compact_scan_spv, name = "cluster compaction scan";
        break;
      case Scatter:
        spirv = cullpipe_cluster_scatter_spv, name = "cluster draws";
        break;
      default:
        spirv = cullpipe_cluster_expand_spv, name = "cluster listing";
    }
    slot = std::make_unique<vulkan::ComputePipeline>(
        ctx_, vulkan::ComputePipelineDesc{spirv, kBindingCount, sizeof(ClusterCullParams), spec, name.c_str(),
                                          kTexelBindings});
  }
  return *slot;
}

void ClusterCuller::upload(std::span<const Aabb> boxes, std::span<const BackfaceCone> cones,
                           std::span<const ClusterInstance> instances, std::span<const std::optional<Obb>> obbs) {
  if (boxes.size() != cones.size())
    throw std::invalid_argument("ClusterCuller::upload: " + std::to_string(boxes.size()) + " boxes and " +
                                std::to_string(cones.size()) + " cones");
  if (!obbs.empty() && obbs.size() != boxes.size())
    throw std::invalid_argument("ClusterCuller::upload: " + std::to_string(boxes.size()) + " boxes and " +
                                std::to_string(obbs.size()) + " OBBs");
  std::uint64_t pairs = 0, obb_pairs = 0;
  for (std::size_t i = 0; i < instances.size(); ++i) {
    const ClusterInstance& in = instances[i];
    const std::string at = "ClusterCuller::upload: instance " + std::to_string(i) + ": ";
    if (std::uint64_t(in.first_cluster) + in.cluster_count > boxes.size())
      throw std::invalid_argument(at + "clusters " + std::to_string(in.first_cluster) + "+" +
                                  std::to_string(in.cluster_count) + " past the " + std::to_string(boxes.size()) +
                                  " clusters");
    if (const std::string why = invalid_reason(in.transform); !why.empty())
      throw std::invalid_argument(at + "transform " + why);
    pairs += in.cluster_count;
    if (!obbs.empty())
      for (std::uint32_t c = 0; c < in.cluster_count; ++c) obb_pairs += obbs[in.first_cluster + c].has_value();
  }
  if (pairs > std::numeric_limits<std::uint32_t>::max() || instances.size() > std::numeric_limits<std::uint32_t>::max())
    throw std::length_error("ClusterCuller::upload: " + std::to_string(pairs) + " pairs, more than 2^32 - 1");
  const std::uint64_t groups = (pairs + group_size_ - 1) / group_size_;
  if (groups > max_groups_)
    throw std::length_error("ClusterCuller::upload: " + std::to_string(pairs) + " pairs need " +
                            std::to_string(groups) + " workgroups, more than one dispatch may have on " +
                            ctx_.info().name + " (maxComputeWorkGroupCount[0] " + std::to_string(max_groups_) + ")");
  const VkDeviceSize pair_bytes = std::max<VkDeviceSize>(pairs * 16, 16);
  detail::check_texel_range(ctx_, pair_bytes, "the cluster pairs");
  detail::check_texel_range(ctx_, std::max<VkDeviceSize>(boxes.size() * CLUSTER_TEXELS * 16, 16), "the clusters");
  detail::check_texel_range(ctx_, std::max<VkDeviceSize>(instances.size() * CLUSTER_INSTANCE_TEXELS * 16, 16),
                            "the cluster instances");
  detail::check_storage_range(ctx_, std::max<VkDeviceSize>(pairs * sizeof(DrawCommand), 16), "the cluster draws");
  const VkDeviceSize obb_bytes = std::max<VkDeviceSize>(obb_pairs * sizeof(GpuObb), 16);
  detail::check_texel_range(ctx_, obb_bytes, "the clusters' placed OBBs");

  // New buffers first: a failed allocation leaves the culler as it was.
  vulkan::Buffer clusters(ctx_, std::max<VkDeviceSize>(boxes.size() * CLUSTER_TEXELS * 16, 16), kTexel,
                          "cluster buffer");
  vulkan::Buffer inst(ctx_, std::max<VkDeviceSize>(instances.size() * CLUSTER_INSTANCE_TEXELS * 16, 16), kTexel,
                      "cluster instance buffer");
  vulkan::Buffer pair_buffer(ctx_, pair_bytes, kTexel, "cluster pair buffer");
  vulkan::Buffer pair_obbs(ctx_, obb_bytes, kTexel, "cluster OBB buffer");
  vulkan::Buffer templates(ctx_, std::max<VkDeviceSize>(pairs * sizeof(DrawCommand), 16), kStorage,
                           "cluster draw template buffer");
  vulkan::Buffer classes(ctx_, std::max<VkDeviceSize>(pairs * 4, 16), kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                         "cluster class buffer");
  vulkan::Buffer visible(ctx_, std::max<VkDeviceSize>(pairs * 4, 16), kStorage, "cluster visible buffer");
  vulkan::Buffer draws(ctx_, std::max<VkDeviceSize>(pairs * sizeof(DrawCommand), 16),
                       kStorage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "cluster draw buffer");
  vulkan::Buffer group_counts(ctx_, std::max<VkDeviceSize>(groups * 8, 16), kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                              "cluster group count buffer");
  const std::uint64_t instance_groups = (instances.size() + group_size_ - 1) / group_size_;
  vulkan::Buffer expand_counts(ctx_, std::max<VkDeviceSize>(instance_groups * 8, 16),
                               kStorage | VK_BUFFER_USAGE_TRANSFER_DST_BIT, "cluster listing count buffer");
  vulkan::Buffer active(ctx_, (CLUSTER_ACTIVE_HEADER + pairs) * 4, kStorage | VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
                        "listed cluster buffer");
  for (vulkan::Buffer* b : {&clusters, &inst, &pair_buffer, &pair_obbs, &templates})
    if (!b->mapped()) throw vulkan::Error("the cluster pass needs host-visible memory for its inputs");

  auto* cw = static_cast<vec4*>(clusters.data());
  for (std::size_t c = 0; c < boxes.size(); ++c) {
    cw[CLUSTER_TEXELS * c + 0] = vec4(boxes[c].min, cones[c].cutoff);
    cw[CLUSTER_TEXELS * c + 1] = vec4(boxes[c].max, 0.0f);
    cw[CLUSTER_TEXELS * c + 2] = vec4(cones[c].apex, 0.0f);
    cw[CLUSTER_TEXELS * c + 3] = vec4(cones[c].axis, 0.0f);
  }
  auto* iw = static_cast<vec4*>(inst.data());
  auto* pw = static_cast<uvec4*>(pair_buffer.data());
  auto* ow = static_cast<GpuObb*>(pair_obbs.data());
  std::uint32_t placed = 0;
  std::size_t p = 0;
  for (std::size_t i = 0; i < instances.size(); ++i) {
    const ClusterInstance& in = instances[i];
    const InverseFrame frame = inverse_frame(in.transform);
    vec4* w = iw + CLUSTER_INSTANCE_TEXELS * i;
    for (int r = 0; r < 3; ++r) {
      w[r] = in.transform.rows[std::size_t(r)];
      w[3 + r] = frame.inverse.rows[std::size_t(r)];
    }
    w[6] = vec4(frame.translation_magnitude, std::bit_cast<float>(frame.usable && in.backface ? 1u : 0u));
    reinterpret_cast<uvec4*>(w)[7] = uvec4(std::uint32_t(p), in.cluster_count, 0u, 0u);
    for (std::uint32_t c = 0; c < in.cluster_count; ++c) {
      const std::optional<Obb>* obb = obbs.empty() ? nullptr : &obbs[in.first_cluster + c];
      // The OBB placed on the host, in double (placing an OBB takes square roots and divisions,
      // which GPUs do not round as the CPU does): what clusters::classify is given.
      if (obb && *obb) ow[placed++] = pack(instance_volume(**obb, in.transform));
      pw[p++] = uvec4(std::uint32_t(i), in.first_cluster + c, obb && *obb ? placed : 0u, 0u);
    }
  }
  clusters_ = std::move(clusters);
  instances_ = std::move(inst);
  pairs_ = std::move(pair_buffer);
  pair_obbs_ = std::move(pair_obbs);
  templates_ = std::move(templates);
  classes_ = std::move(classes);
  visible_ = std::move(visible);
  draws_ = std::move(draws);
  group_counts_ = std::move(group_counts);
  expand_counts_ = std::move(expand_counts);
  active_ = std::move(active);
  pair_count_ = std::size_t(pairs);
  instance_count_ = instances.size();
  std::memset(templates_.data(), 0, templates_.size());
  bound_classes_ = VK_NULL_HANDLE;  // descriptors rewritten by the next pass
}

void ClusterCuller::upload_draws(std::span<const DrawCommand> draws, bool merge) {
  if (draws.size() != pair_count_)
    throw std::invalid_argument("ClusterCuller::upload_draws: " + std::to_string(draws.size()) + " draws for " +
                                std::to_string(pair_count_) + " pairs");
  if (!draws.empty()) std::memcpy(templates_.data(), draws.data(), draws.size_bytes());
  // Which pairs continue the draw of the pair before (cull_types.h, CLUSTER_BINDING_PAIRS).
  auto* pairs = static_cast<uvec4*>(pairs_.data());
  for (std::size_t p = 0; p < draws.size(); ++p) {
    const DrawCommand* a = p > 0 ? &draws[p - 1] : nullptr;
    const DrawCommand& b = draws[p];
    pairs[p].w = merge && a && pairs[p - 1].x == pairs[p].x && a->instance_count == b.instance_count &&
                         a->vertex_offset == b.vertex_offset && a->first_instance == b.first_instance &&
                         std::uint64_t(a->first_index) + a->index_count == b.first_index
                     ? 1u
                     : 0u;
  }
}

void ClusterCuller::prepare(const ClusterFrame& frame) {
  for (std::size_t k = 0; k < frame.frustum.plane_count; ++k)
    if (!std::isfinite(frame.frustum.planes[k].normal.x) || !std::isfinite(frame.frustum.planes[k].normal.y) ||
        !std::isfinite(frame.frustum.planes[k].normal.z) || !std::isfinite(frame.frustum.planes[k].d))
      throw std::invalid_argument("ClusterCuller: frustum plane " + std::to_string(k) + " is not finite");
  if (frame.backface && !(std::isfinite(frame.eye.x) && std::isfinite(frame.eye.y) && std::isfinite(frame.eye.z)))
    throw std::invalid_argument("ClusterCuller: the eye is not finite");
  CullOptions occlusion;
  if (frame.pyramid) {
    occlusion.pyramid = frame.pyramid;
    occlusion.occlusion_views = {frame.occlusion_view};
    occlusion.occlusion_options = frame.occlusion_options;
    detail::check_occlusion(ctx_, occlusion, 1);
  }
  if (frame.object_classes &&
      frame.object_classes_offset % ctx_.properties().limits.minStorageBufferOffsetAlignment != 0)
    throw std::invalid_argument("ClusterCuller: object_classes_offset " + std::to_string(frame.object_classes_offset) +
                                " is not a multiple of the device's minStorageBufferOffsetAlignment (" +
                                std::to_string(ctx_.properties().limits.minStorageBufferOffsetAlignment) + ")");
  if (frame.object_classes && frame.object_classes->size() < frame.object_classes_offset + 4 * instance_count())
    throw std::invalid_argument("ClusterCuller: the object class buffer holds fewer than the " +
                                std::to_string(instance_count()) + " instances' classes");
  occlusion_ = frame.pyramid != nullptr;
  object_classes_ = frame.object_classes != nullptr;
  texels_ = occlusion_ ? frame.occlusion_options.texels_per_axis : 4u;
  refine_ = occlusion_ && frame.occlusion_options.refine_texels_per_axis > texels_
                ? frame.occlusion_options.refine_texels_per_axis
                : 0u;
  // Every pipeline now, not while recording.
  pipeline(Expand, false, object_classes_);
  pipeline(ExpandWrite, false, object_classes_);
  pipeline(Cull, occlusion_, false, texels_, refine_);
  pipeline(Scan);
  pipeline(Scatter);

  views_.as<GpuFrustum>()[0] = pack(frame.frustum);
  if (occlusion_) detail::write_occlusion_views(occlusion, occlusion_views_.as<GpuOcclusionView>());
  params_ = {};
  params_.pair_count = std::uint32_t(pair_count_);
  params_.view_count = 1;
  params_.visible_capacity = std::uint32_t(pair_count_);
  params_.backface = frame.backface ? 1u : 0u;
  params_.eye = vec4(frame.eye, 0.0f);

  // The descriptors, when what they name changed (the previous pass has completed: the
  // renderer and cull() wait for every frame).
  const vulkan::Buffer* classes = frame.object_classes ? frame.object_classes : &no_classes_;
  const vulkan::Buffer* pyramid = frame.pyramid ? &frame.pyramid->texels() : &no_pyramid_;
  const VkDeviceSize classes_offset = frame.object_classes ? frame.object_classes_offset : 0;
  // (The handles, not the Buffer objects: an owner that grows a buffer moves a new one into the
  // same object.)
  const VkDeviceSize classes_size = frame.object_classes ? std::max<VkDeviceSize>(4 * instance_count_, 4) : 16;
  if (bound_classes_ != classes->handle() || bound_classes_offset_ != classes_offset ||
      bound_pyramid_ != pyramid->handle() || bound_pyramid_size_ != pyramid->size()) {
    using Range = detail::PassResources::Range;
    const Range ranges[kBindingCount] = {Range{&clusters_},
                                         Range{&classes_},
                                         Range{&visible_},
                                         Range{&counters_},
                                         Range{&views_},
                                         Range{&templates_},
                                         Range{&draws_},
                                         Range{&group_counts_},
                                         Range{&instances_},
                                         Range{pyramid},
                                         Range{&occlusion_views_},
                                         Range{&pairs_},
                                         Range{classes, classes_offset, classes_size},
                                         Range{&active_},
                                         Range{&pair_obbs_}};
    resources_->write(0, ranges);
    // The listing's set: its group counts, and the list's header as its counters.
    Range listing[kBindingCount];
    std::copy(std::begin(ranges), std::end(ranges), listing);
    listing[BINDING_COUNTERS] = Range{&active_, 0, sizeof(ViewCounters)};
    listing[BINDING_GROUP_COUNTS] = Range{&expand_counts_};
    resources_->write(1, listing);
    bound_classes_ = classes->handle();
    bound_classes_offset_ = classes_offset;
    bound_pyramid_ = pyramid->handle();
    bound_pyramid_size_ = pyramid->size();
  }
}

void ClusterCuller::record_passes(VkCommandBuffer cmd) {
  detail::record_entry_barrier(ctx_, cmd);
  // The object classes and the pyramid an earlier compute or transfer pass of the same command
  // buffer wrote are visible to the passes below whoever wrote them.
  const VkMemoryBarrier inputs{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr,
                               VK_ACCESS_SHADER_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT, VK_ACCESS_SHADER_READ_BIT};
  vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT | VK_PIPELINE_STAGE_TRANSFER_BIT,
                       VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, 0, 1, &inputs, 0, nullptr, 0, nullptr);
  vkCmdFillBuffer(cmd, counters_.handle(), 0, sizeof(ViewCounters), 0);
  vkCmdFillBuffer(cmd, group_counts_.handle(), 0, VK_WHOLE_SIZE, 0);
  vkCmdFillBuffer(cmd, expand_counts_.handle(), 0, VK_WHOLE_SIZE, 0);
  // Pairs of the instances the object pass culled are never visited: their class is this.
  vkCmdFillBuffer(cmd, classes_.handle(), 0, VK_WHOLE_SIZE, CLUSTER_OBJECT_CULLED);
  detail::record_transfer_to_compute(cmd);
  if (pair_count_ > 0) {
    const std::uint64_t per_dispatch = std::uint64_t(max_groups_) * group_size_;
    // One pass over `items` (instances or pairs) with descriptor set `set_index`.
    auto pass = [&](const vulkan::ComputePipeline& pipe, std::size_t set_index, std::uint64_t items) {
      const VkDescriptorSet set = resources_->set(set_index);
      vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
      vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &set, 0, nullptr);
      for (std::uint64_t first = 0; first < items; first += per_dispatch) {
        if (first > 0) detail::record_compute_to_compute(cmd);
        ClusterCullParams params = params_;
        params.pair_count = std::uint32_t(items);
        params.first_pair = std::uint32_t(first);
        vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
        vkCmdDispatch(cmd, vulkan::group_count(std::min<std::uint64_t>(per_dispatch, items - first), group_size_), 1,
                      1);
      }
    };
    auto scan = [&](std::size_t set_index, std::uint64_t items) {
      const vulkan::ComputePipeline& pipe = pipeline(Scan);
      const VkDescriptorSet set = resources_->set(set_index);
      ClusterCullParams params = params_;
      params.pair_count = std::uint32_t(items);
      vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
      vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &set, 0, nullptr);
      vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
      vkCmdDispatch(cmd, 1, 1, 1);
    };
    // List the kept instances' pairs (set 1: the list's header is its counter)...
    pass(pipeline(Expand, false, object_classes_), 1, instance_count_);
    detail::record_compute_to_compute(cmd);
    scan(1, instance_count_);
    detail::record_compute_to_compute(cmd);
    pass(pipeline(ExpandWrite, false, object_classes_), 1, instance_count_);
    detail::record_compute_to_compute(cmd);
    // ...then cull them, count the draws per workgroup, and write the draws, in as many
    // workgroups as the list needs (the listing wrote the count).
    detail::record_compute_to_compute(cmd, true);
    auto listed_pass = [&](const vulkan::ComputePipeline& pipe) {
      const VkDescriptorSet set = resources_->set(0);
      ClusterCullParams params = params_;
      params.first_pair = 0;
      vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.pipeline());
      vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe.layout(), 0, 1, &set, 0, nullptr);
      vkCmdPushConstants(cmd, pipe.layout(), VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(params), &params);
      vkCmdDispatchIndirect(cmd, active_.handle(), CLUSTER_ACTIVE_DISPATCH * sizeof(std::uint32_t));
    };
    listed_pass(pipeline(Cull, occlusion_, false, texels_, refine_));
    detail::record_compute_to_compute(cmd);
    scan(0, pair_count_);
    detail::record_compute_to_compute(cmd);
    listed_pass(pipeline(Scatter));
  }
  detail::record_exit_barrier(ctx_, cmd);
}

void ClusterCuller::record(VkCommandBuffer cmd, const ClusterFrame& frame) {
  prepare(frame);
  record_passes(cmd);
}

ClusterResult ClusterCuller::read_results() const {
  ClusterResult r;
  r.classes.resize(pair_count_);
  const auto* c = static_cast<const std::uint32_t*>(classes_.data());
  for (std::size_t p = 0; p < pair_count_; ++p) {
    const std::uint32_t v = c[p];
    r.classes[p] = static_cast<clusters::ClusterClass>(v);
    if (v < r.counts.size()) ++r.counts[v];
  }
  r.drawn = r.counts[std::size_t(clusters::ClusterClass::Drawn)];
  r.draws = counters_.as<const ViewCounters>()[0].visible_count;
  return r;
}

ClusterResult ClusterCuller::cull(const ClusterFrame& frame) {
  const auto start = std::chrono::steady_clock::now();
  prepare(frame);
  const double gpu_ns = resources_->run([&](VkCommandBuffer cmd, VkQueryPool timestamps) {
    if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, timestamps, 0);
    record_passes(cmd);
    if (timestamps) vkCmdWriteTimestamp(cmd, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps, 1);
  });
  ClusterResult r = read_results();
  r.gpu_ns = gpu_ns;
  r.wall_ns =
      double(std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now() - start).count());
  return r;
}

}  // namespace cullpipe::gpu
