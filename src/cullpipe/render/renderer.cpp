#include "cullpipe/render/renderer.hpp"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <functional>
#include <glm/ext/matrix_double3x3.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <glm/matrix.hpp>
#include <limits>
#include <map>
#include <stdexcept>
#include <string>
#include <unordered_map>
#include <utility>

#include "cullpipe/bounds/cone_fit.hpp"
#include "cullpipe/bounds/sphere_fit.hpp"
#include "cullpipe/geom/instance.hpp"
#include "cullpipe/vulkan/check.hpp"

// SPIR-V compiled from shaders/render_mesh.{vert,frag} at build time.
#include "render_id.frag.spv.h"
#include "render_mesh.frag.spv.h"
#include "render_mesh.vert.spv.h"
#include "render_primitive.frag.spv.h"

namespace cullpipe::render {
namespace {

using gpu::DrawCommand;
using gpu::RenderObject;

// A fixed, well-spread colour per object id (golden-ratio hue steps, HSV to RGB).
glm::vec4 object_color(std::size_t id) {
  const float h = std::fmod(0.11f + 0.61803398875f * float(id % 100000), 1.0f) * 6.0f;
  const float s = 0.55f, v = 0.92f;
  const float c = v * s, x = c * (1.0f - std::abs(std::fmod(h, 2.0f) - 1.0f)), m = v - c;
  glm::vec3 rgb = h < 1   ? glm::vec3(c, x, 0)
                  : h < 2 ? glm::vec3(x, c, 0)
                  : h < 3 ? glm::vec3(0, c, x)
                  : h < 4 ? glm::vec3(0, x, c)
                  : h < 5 ? glm::vec3(x, 0, c)
                          : glm::vec3(c, 0, x);
  return glm::vec4(rgb + m, 1.0f);
}

// The unit cube [0,1]^3: 8 corners, 12 triangles.
const glm::vec3 kCubeVertices[8] = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {1, 1, 0},
                                    {0, 0, 1}, {1, 0, 1}, {0, 1, 1}, {1, 1, 1}};
const std::uint32_t kCubeIndices[36] = {0, 2, 1, 1, 2, 3, 4, 5, 6, 5, 7, 6, 0, 1, 4, 1, 5, 4,
                                        2, 6, 3, 3, 6, 7, 0, 4, 2, 2, 4, 6, 1, 3, 5, 3, 7, 5};

// Points binding 0 (the pipelines' object records) of `set` at the whole of `objects`.
void write_objects(VkDevice dev, VkDescriptorSet set, const vulkan::Buffer& objects) {
  VkDescriptorBufferInfo buffer_info{objects.handle(), 0, VK_WHOLE_SIZE};
  VkWriteDescriptorSet write{VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET};
  write.dstSet = set;
  write.dstBinding = 0;
  write.descriptorCount = 1;
  write.descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
  write.pBufferInfo = &buffer_info;
  vkUpdateDescriptorSets(dev, 1, &write, 0, nullptr);
}

VkShaderModule shader_module(VkDevice dev, const std::uint32_t* code, std::size_t bytes) {
  VkShaderModuleCreateInfo info{VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO};
  info.codeSize = bytes;
  info.pCode = code;
  VkShaderModule m = VK_NULL_HANDLE;
  CULLPIPE_VK_CHECK(vkCreateShaderModule(dev, &info, nullptr, &m));
  return m;
}

}  // namespace

Renderer::Renderer(const vulkan::Context& ctx, const Scene& scene, const RendererConfig& config)
    : ctx_(ctx), config_(config) {
  if (!ctx.draw_indirect_count())
    throw vulkan::Error(
        "the renderer needs drawIndirectCount, multiDrawIndirect and drawIndirectFirstInstance, which " +
        ctx.info().name + " does not offer (or which the borrowed device did not enable)");
  if (!(ctx.queue_flags() & VK_QUEUE_GRAPHICS_BIT))
    throw vulkan::Error("the renderer needs a queue with graphics and compute; " + ctx.info().name +
                        "'s chosen queue has no graphics");
  if (config_.width == 0 || config_.height == 0 || config_.width > ctx.properties().limits.maxFramebufferWidth ||
      config_.height > ctx.properties().limits.maxFramebufferHeight)
    throw std::invalid_argument("image size " + std::to_string(config_.width) + "x" + std::to_string(config_.height) +
                                " is empty or larger than the device's framebuffer limit");
  try {
    // ---- geometry: each distinct triangle mesh's vertices once (box objects share the unit
    //      cube), its triangles once per winding it is drawn with, cluster by cluster ----
    TriangleMesh cube;
    cube.positions.assign(std::begin(kCubeVertices), std::end(kCubeVertices));
    cube.indices.assign(std::begin(kCubeIndices), std::end(kCubeIndices));
    std::vector<glm::vec3> vertices;
    std::vector<std::uint32_t> indices;
    std::vector<Aabb> cluster_boxes;
    std::vector<BackfaceCone> cluster_cones;
    std::vector<std::optional<Obb>> cluster_obbs;
    // A mesh's vertices in the vertex buffer, and its triangles' order: ranges of its own index
    // list (its clusters' with RendererConfig::clusters, else one range of every triangle).
    struct Source {
      std::int32_t vertex_offset = 0;
      std::vector<std::uint32_t> order;  // the mesh's indices, cluster by cluster
      std::vector<std::pair<std::uint32_t, std::uint32_t>> ranges;
      std::uint32_t first_cluster = 0;  // into cluster_boxes / cluster_cones
    };
    std::unordered_map<const TriangleMesh*, Source> sources;
    auto source_of = [&](const TriangleMesh& mesh, std::size_t object) -> const Source& {
      auto found = sources.find(&mesh);
      if (found != sources.end()) return found->second;
      if (vertices.size() + mesh.positions.size() > std::size_t(std::numeric_limits<std::int32_t>::max()))
        throw std::length_error("the scene's distinct meshes have more vertices than one draw can address");
      Source src;
      src.vertex_offset = std::int32_t(vertices.size());
      vertices.insert(vertices.end(), mesh.positions.begin(), mesh.positions.end());
      src.first_cluster = std::uint32_t(cluster_boxes.size());
      bool split = false;
      if (config_.clusters) {
        const std::string name = "object " + std::to_string(object) + "'s mesh";
        try {
          const MeshClusters c = build_clusters(mesh, config_.cluster_options, name);
          src.order = c.indices;
          const bool both = config_.cull_back_faces && mesh.double_sided;
          std::vector<std::uint32_t> reversed;
          for (const Cluster& cl : c.clusters) {
            src.ranges.emplace_back(cl.first_index, cl.index_count);
            cluster_boxes.push_back(cl.box);
            cluster_cones.push_back(config_.cull_back_faces ? cl.cone : BackfaceCone{});
            cluster_obbs.push_back(cl.obb);
            if (!both) continue;
            // A double-sided mesh's cluster is drawn twice, its triangles reversed the second
            // time (layout_of): that copy is a cluster of its own, whose cone is the reversed
            // triangles' (it faces away where the first copy faces the eye).
            reversed.assign(c.indices.begin() + cl.first_index, c.indices.begin() + cl.first_index + cl.index_count);
            for (std::size_t k = 0; k < reversed.size(); k += 3) std::swap(reversed[k + 1], reversed[k + 2]);
            cluster_boxes.push_back(cl.box);
            cluster_cones.push_back(bounds::backface_cone(mesh.positions, reversed, -cl.cone.axis));
            cluster_obbs.push_back(cl.obb);
          }
          split = true;
        } catch (const std::invalid_argument& e) {
          // Drawn whole: one cluster, no cone; nothing this mesh added is kept.
          cluster_fallbacks_.push_back(e.what());
          src.order.clear();
          src.ranges.clear();
          cluster_boxes.resize(src.first_cluster);
          cluster_cones.resize(src.first_cluster);
          cluster_obbs.resize(src.first_cluster);
        }
      }
      if (!split) {
        src.order = mesh.indices;
        src.ranges.emplace_back(0u, std::uint32_t(mesh.indices.size()));
        if (config_.clusters)
          for (int side = 0; side < (config_.cull_back_faces && mesh.double_sided ? 2 : 1); ++side) {
            cluster_boxes.push_back(mesh.positions.empty() ? Aabb{} : bounds::aabb_of_points(mesh.positions));
            cluster_cones.push_back(BackfaceCone{});
            cluster_obbs.emplace_back();
          }
      }
      return sources.emplace(&mesh, std::move(src)).first->second;
    };
    // Where a mesh's triangles are in the index buffer for one winding: each range (cluster)
    // in order, its triangles flipped for a mirroring instance, and for a double-sided mesh
    // followed by the same triangles reversed (a range of its own), so that back-face culling
    // keeps one side of each. Either way the first copy is drawn where the eye is in front of
    // the mesh's own triangles, the second where it is behind them.
    struct Layout {
      std::uint32_t first = 0, count = 0;
      std::vector<std::pair<std::uint32_t, std::uint32_t>> ranges;  // per cluster (and side), in the index buffer
    };
    std::map<std::pair<const TriangleMesh*, bool>, Layout> layouts;
    auto layout_of = [&](const TriangleMesh& mesh, const Source& src, bool flipped) -> const Layout& {
      auto found = layouts.find({&mesh, flipped});
      if (found != layouts.end()) return found->second;
      const bool both = config_.cull_back_faces && mesh.double_sided;
      if (indices.size() + src.order.size() * (both ? 2 : 1) > std::numeric_limits<std::uint32_t>::max())
        throw std::length_error("the scene's distinct meshes have more indices than one draw can address");
      Layout l;
      l.first = std::uint32_t(indices.size());
      for (const auto& [first, count] : src.ranges)
        for (int side = 0; side < (both ? 2 : 1); ++side) {
          const std::uint32_t start = std::uint32_t(indices.size());
          for (std::uint32_t k = first; k < first + count; k += 3) {
            const bool reverse = flipped != (side == 1);
            indices.insert(indices.end(),
                           {src.order[k], src.order[k + (reverse ? 2 : 1)], src.order[k + (reverse ? 1 : 2)]});
          }
          l.ranges.emplace_back(start, std::uint32_t(indices.size()) - start);
        }
      l.count = std::uint32_t(indices.size()) - l.first;
      return layouts.emplace(std::pair{&mesh, flipped}, std::move(l)).first->second;
    };
    const std::size_t n = scene.objects.size();
    templates_.resize(n);
    std::vector<RenderObject> objects(n);
    std::vector<gpu::ClusterInstance> cluster_instances;
    std::vector<DrawCommand> cluster_draws;
    for (std::size_t i = 0; i < n; ++i) {
      const SceneObject& o = scene.objects[i];
      const TriangleMesh& mesh = o.triangles ? *o.triangles : cube;
      if (o.triangles) {
        objects[i].model = o.world;
      } else {
        const glm::vec3 size = o.local_bounds.max - o.local_bounds.min;
        objects[i].model = glm::scale(glm::translate(o.world, o.local_bounds.min), size);
      }
      objects[i].color = object_color(i);
      // glTF: a transform with a negative determinant mirrors, and turns the winding around.
      const glm::dmat3 linear(objects[i].model);
      const bool flipped = config_.cull_back_faces && glm::determinant(linear) < 0.0;
      const Source& src = source_of(mesh, i);
      const Layout& l = layout_of(mesh, src, flipped);
      templates_[i] = {l.count, 1, l.first, src.vertex_offset, std::uint32_t(i), 0};
      if (config_.clusters) {
        cluster_instances.push_back({Transform3x4::from_mat4(objects[i].model), src.first_cluster,
                                     std::uint32_t(l.ranges.size()), config_.cull_back_faces});
        for (const auto& [first, count] : l.ranges)
          cluster_draws.push_back({count, 1, first, src.vertex_offset, std::uint32_t(i), 0});
      }
    }
    const auto upload = [&](vulkan::Buffer& b, const void* data, std::size_t bytes, VkBufferUsageFlags usage,
                            const char* what) {
      b = vulkan::Buffer(ctx_, std::max<std::size_t>(bytes, 16), usage, what);
      if (bytes) std::memcpy(b.data(), data, bytes);
    };
    upload(vertices_, vertices.data(), vertices.size() * sizeof(glm::vec3), VK_BUFFER_USAGE_VERTEX_BUFFER_BIT,
           "vertex buffer");
    upload(indices_, indices.data(), indices.size() * sizeof(std::uint32_t), VK_BUFFER_USAGE_INDEX_BUFFER_BIT,
           "index buffer");
    upload(objects_, objects.data(), objects.size() * sizeof(RenderObject), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
           "render object buffer");
    // The id pass's objects: the same, coloured by id + 1 in 24 bits (render_id.frag).
    if (n >= (std::size_t(1) << 24) - 1)
      throw std::length_error(std::to_string(n) + " objects: the id pass tells at most 2^24 - 2 apart");
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t id = std::uint32_t(i + 1);
      objects[i].color =
          glm::vec4(float(id & 255u) / 255.0f, float(id >> 8 & 255u) / 255.0f, float(id >> 16) / 255.0f, 1.0f);
    }
    upload(id_objects_, objects.data(), objects.size() * sizeof(RenderObject), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
           "id pass object buffer");
    upload(all_draws_, templates_.data(), templates_.size() * sizeof(DrawCommand), VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT,
           "unculled draw buffer");
    if (n > ctx_.properties().limits.maxDrawIndirectCount)
      throw std::length_error(std::to_string(n) + " objects are more draws than one indirect draw call may issue on " +
                              ctx_.info().name + " (maxDrawIndirectCount " +
                              std::to_string(ctx_.properties().limits.maxDrawIndirectCount) + ")");
    readback_ = vulkan::Buffer(ctx_, VkDeviceSize(config_.width) * config_.height * 4, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                               "image readback buffer");

    // ---- the culling pass on the same device ----
    culler_ = std::make_unique<gpu::GpuCuller>(ctx_);
    switch (config_.bv) {
      case BvKind::Aabb: {
        const std::vector<Aabb> v = world_aabbs(scene, config_.aabb_update);
        culler_->upload(std::span<const Aabb>(v));
        break;
      }
      case BvKind::Obb: {
        const std::vector<Obb> v = world_obbs(scene);
        culler_->upload(std::span<const Obb>(v));
        break;
      }
      case BvKind::Sphere: {
        const std::vector<Sphere> v = world_spheres(scene);
        culler_->upload(std::span<const Sphere>(v));
        break;
      }
    }
    culler_->upload_draws(templates_);
    // The frames draw from the culler's draw and count buffers: made once, never replaced.
    gpu::CullOptions frame_options;
    frame_options.ordered = true;
    frame_options.draws = true;
    culler_->reserve_outputs(1, frame_options);
    if (config_.clusters) {
      if (cluster_draws.size() > ctx_.properties().limits.maxDrawIndirectCount)
        throw std::length_error(std::to_string(cluster_draws.size()) +
                                " clusters are more draws than one indirect draw call may issue on " +
                                ctx_.info().name);
      cluster_culler_ = std::make_unique<gpu::ClusterCuller>(ctx_);
      cluster_culler_->upload(cluster_boxes, cluster_cones, cluster_instances, cluster_obbs);
      // Unmerged: a culled frame issues a subset of the unculled frame's draws, each as it is.
      // (On lavapipe the pixels along a triangle's edge can come out differently when the same
      // triangles are issued in other draws: the generated meshes scene lost one pixel of 64,000
      // against per-object draws. So unculled frames draw cluster by cluster too.)
      cluster_culler_->upload_draws(cluster_draws, false);
      upload(all_cluster_draws_, cluster_draws.data(), cluster_draws.size() * sizeof(DrawCommand),
             VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "unculled cluster draw buffer");
      cluster_boxes_ = std::move(cluster_boxes);
      cluster_cones_ = std::move(cluster_cones);
      cluster_obbs_ = std::move(cluster_obbs);
      cluster_instances_ = std::move(cluster_instances);
    }

    create_targets();
    create_pipelines();

    VkCommandBufferAllocateInfo cmd_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    cmd_info.commandPool = ctx_.command_pool();
    cmd_info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    cmd_info.commandBufferCount = 1;
    CULLPIPE_VK_CHECK(vkAllocateCommandBuffers(ctx_.device(), &cmd_info, &cmd_));
    if (ctx_.pipeline_statistics()) {
      VkQueryPoolCreateInfo q{VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO};
      q.queryType = VK_QUERY_TYPE_PIPELINE_STATISTICS;
      q.queryCount = 1;
      q.pipelineStatistics = VK_QUERY_PIPELINE_STATISTIC_INPUT_ASSEMBLY_PRIMITIVES_BIT;
      CULLPIPE_VK_CHECK(vkCreateQueryPool(ctx_.device(), &q, nullptr, &stats_pool_));
    }
  } catch (...) {
    release();
    throw;
  }
}

Renderer::~Renderer() { release(); }

void Renderer::create_targets() {
  VkDevice dev = ctx_.device();
  const auto make_image = [&](VkFormat format, VkImageUsageFlags usage, VkImageAspectFlags aspect, VkImage& image,
                              VkDeviceMemory& memory, VkImageView& view, const char* what) {
    VkImageCreateInfo info{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
    info.imageType = VK_IMAGE_TYPE_2D;
    info.format = format;
    info.extent = {config_.width, config_.height, 1};
    info.mipLevels = 1;
    info.arrayLayers = 1;
    info.samples = VK_SAMPLE_COUNT_1_BIT;
    info.tiling = VK_IMAGE_TILING_OPTIMAL;
    info.usage = usage;
    info.initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    CULLPIPE_VK_CHECK(vkCreateImage(dev, &info, nullptr, &image));
    VkMemoryRequirements req{};
    vkGetImageMemoryRequirements(dev, image, &req);
    VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    alloc.allocationSize = req.size;
    alloc.memoryTypeIndex = ctx_.find_memory_type(req.memoryTypeBits, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
    const VkResult r = vkAllocateMemory(dev, &alloc, nullptr, &memory);
    if (r != VK_SUCCESS)
      throw vulkan::Error(std::string("allocating the ") + what + " failed: " + vulkan::result_name(r), r);
    CULLPIPE_VK_CHECK(vkBindImageMemory(dev, image, memory, 0));
    VkImageViewCreateInfo view_info{VK_STRUCTURE_TYPE_IMAGE_VIEW_CREATE_INFO};
    view_info.image = image;
    view_info.viewType = VK_IMAGE_VIEW_TYPE_2D;
    view_info.format = format;
    view_info.subresourceRange = {aspect, 0, 1, 0, 1};
    CULLPIPE_VK_CHECK(vkCreateImageView(dev, &view_info, nullptr, &view));
  };
  make_image(VK_FORMAT_R8G8B8A8_UNORM, VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
             VK_IMAGE_ASPECT_COLOR_BIT, color_, color_memory_, color_view_, "colour image");
  // (Transfer source: occlusion frames copy the first phase's depth into the pyramid.)
  make_image(VK_FORMAT_D32_SFLOAT, VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT,
             VK_IMAGE_ASPECT_DEPTH_BIT, depth_, depth_memory_, depth_view_, "depth image");

  VkAttachmentDescription attachments[2]{};
  attachments[0].format = VK_FORMAT_R8G8B8A8_UNORM;
  attachments[0].samples = VK_SAMPLE_COUNT_1_BIT;
  attachments[0].loadOp = VK_ATTACHMENT_LOAD_OP_CLEAR;
  attachments[0].storeOp = VK_ATTACHMENT_STORE_OP_STORE;
  attachments[0].stencilLoadOp = VK_ATTACHMENT_LOAD_OP_DONT_CARE;
  attachments[0].stencilStoreOp = VK_ATTACHMENT_STORE_OP_DONT_CARE;
  attachments[0].initialLayout = VK_IMAGE_LAYOUT_UNDEFINED;
  attachments[0].finalLayout = VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL;
  attachments[1] = attachments[0];
  attachments[1].format = VK_FORMAT_D32_SFLOAT;
  attachments[1].storeOp = VK_ATTACHMENT_STORE_OP_STORE;  // (the pyramid reads it)
  attachments[1].finalLayout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL;
  VkAttachmentReference color_ref{0, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL};
  VkAttachmentReference depth_ref{1, VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL};
  VkSubpassDescription subpass{};
  subpass.pipelineBindPoint = VK_PIPELINE_BIND_POINT_GRAPHICS;
  subpass.colorAttachmentCount = 1;
  subpass.pColorAttachments = &color_ref;
  subpass.pDepthStencilAttachment = &depth_ref;
  // In: the previous frame's copy (transfer read of the colour image) and depth writes finish
  // before this frame clears and writes. Out: colour writes finish before the copy.
  VkSubpassDependency deps[2]{};
  deps[0].srcSubpass = VK_SUBPASS_EXTERNAL;
  deps[0].dstSubpass = 0;
  // (Occlusion frames run the render pass twice: the first phase's colour writes finish too.)
  deps[0].srcStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT | VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT |
                         VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
  deps[0].srcAccessMask = VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
  deps[0].dstStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT | VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT |
                         VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT;
  deps[0].dstAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT |
                          VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT;
  deps[1].srcSubpass = 0;
  deps[1].dstSubpass = VK_SUBPASS_EXTERNAL;
  deps[1].srcStageMask = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
  deps[1].srcAccessMask = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
  deps[1].dstStageMask = VK_PIPELINE_STAGE_TRANSFER_BIT;
  deps[1].dstAccessMask = VK_ACCESS_TRANSFER_READ_BIT;
  VkRenderPassCreateInfo rp{VK_STRUCTURE_TYPE_RENDER_PASS_CREATE_INFO};
  rp.attachmentCount = 2;
  rp.pAttachments = attachments;
  rp.subpassCount = 1;
  rp.pSubpasses = &subpass;
  rp.dependencyCount = 2;
  rp.pDependencies = deps;
  CULLPIPE_VK_CHECK(vkCreateRenderPass(dev, &rp, nullptr, &render_pass_));
  VkImageView views[2] = {color_view_, depth_view_};
  VkFramebufferCreateInfo fb{VK_STRUCTURE_TYPE_FRAMEBUFFER_CREATE_INFO};
  fb.renderPass = render_pass_;
  fb.attachmentCount = 2;
  fb.pAttachments = views;
  fb.width = config_.width;
  fb.height = config_.height;
  fb.layers = 1;
  CULLPIPE_VK_CHECK(vkCreateFramebuffer(dev, &fb, nullptr, &framebuffer_));
}

void Renderer::create_pipelines() {
  VkDevice dev = ctx_.device();
  VkDescriptorSetLayoutBinding binding{0, VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 1, VK_SHADER_STAGE_VERTEX_BIT, nullptr};
  VkDescriptorSetLayoutCreateInfo set_info{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO};
  set_info.bindingCount = 1;
  set_info.pBindings = &binding;
  CULLPIPE_VK_CHECK(vkCreateDescriptorSetLayout(dev, &set_info, nullptr, &set_layout_));
  VkPushConstantRange push{VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(gpu::RenderParams)};
  VkPipelineLayoutCreateInfo layout_info{VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO};
  layout_info.setLayoutCount = 1;
  layout_info.pSetLayouts = &set_layout_;
  layout_info.pushConstantRangeCount = 1;
  layout_info.pPushConstantRanges = &push;
  CULLPIPE_VK_CHECK(vkCreatePipelineLayout(dev, &layout_info, nullptr, &pipeline_layout_));

  VkDescriptorPoolSize pool_size{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, 3};
  VkDescriptorPoolCreateInfo pool_info{VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO};
  pool_info.maxSets = 3;
  pool_info.poolSizeCount = 1;
  pool_info.pPoolSizes = &pool_size;
  CULLPIPE_VK_CHECK(vkCreateDescriptorPool(dev, &pool_info, nullptr, &descriptor_pool_));
  VkDescriptorSetAllocateInfo alloc{VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO};
  alloc.descriptorPool = descriptor_pool_;
  alloc.descriptorSetCount = 1;
  alloc.pSetLayouts = &set_layout_;
  CULLPIPE_VK_CHECK(vkAllocateDescriptorSets(dev, &alloc, &descriptor_set_));
  write_objects(dev, descriptor_set_, objects_);
  CULLPIPE_VK_CHECK(vkAllocateDescriptorSets(dev, &alloc, &id_descriptor_set_));
  write_objects(dev, id_descriptor_set_, id_objects_);
  CULLPIPE_VK_CHECK(vkAllocateDescriptorSets(dev, &alloc, &class_descriptor_set_));  // written by class_image

  VkShaderModule vert = shader_module(dev, cullpipe_render_mesh_vert_spv, sizeof(cullpipe_render_mesh_vert_spv));
  VkShaderModule frag = VK_NULL_HANDLE, id_frag = VK_NULL_HANDLE, primitive_frag = VK_NULL_HANDLE;
  try {
    frag = shader_module(dev, cullpipe_render_mesh_frag_spv, sizeof(cullpipe_render_mesh_frag_spv));
    id_frag = shader_module(dev, cullpipe_render_id_frag_spv, sizeof(cullpipe_render_id_frag_spv));
    if (ctx_.primitive_ids())
      primitive_frag =
          shader_module(dev, cullpipe_render_primitive_frag_spv, sizeof(cullpipe_render_primitive_frag_spv));
    VkPipelineShaderStageCreateInfo stages[2]{};
    stages[0] = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                 nullptr,
                 0,
                 VK_SHADER_STAGE_VERTEX_BIT,
                 vert,
                 "main",
                 nullptr};
    stages[1] = {VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO,
                 nullptr,
                 0,
                 VK_SHADER_STAGE_FRAGMENT_BIT,
                 frag,
                 "main",
                 nullptr};
    VkVertexInputBindingDescription vb{0, sizeof(glm::vec3), VK_VERTEX_INPUT_RATE_VERTEX};
    VkVertexInputAttributeDescription va{0, 0, VK_FORMAT_R32G32B32_SFLOAT, 0};
    VkPipelineVertexInputStateCreateInfo vertex_input{VK_STRUCTURE_TYPE_PIPELINE_VERTEX_INPUT_STATE_CREATE_INFO};
    vertex_input.vertexBindingDescriptionCount = 1;
    vertex_input.pVertexBindingDescriptions = &vb;
    vertex_input.vertexAttributeDescriptionCount = 1;
    vertex_input.pVertexAttributeDescriptions = &va;
    VkPipelineInputAssemblyStateCreateInfo assembly{VK_STRUCTURE_TYPE_PIPELINE_INPUT_ASSEMBLY_STATE_CREATE_INFO};
    assembly.topology = VK_PRIMITIVE_TOPOLOGY_TRIANGLE_LIST;
    VkViewport viewport{0.0f, 0.0f, float(config_.width), float(config_.height), 0.0f, 1.0f};
    VkRect2D scissor{{0, 0}, {config_.width, config_.height}};
    VkPipelineViewportStateCreateInfo viewport_state{VK_STRUCTURE_TYPE_PIPELINE_VIEWPORT_STATE_CREATE_INFO};
    viewport_state.viewportCount = 1;
    viewport_state.pViewports = &viewport;
    viewport_state.scissorCount = 1;
    viewport_state.pScissors = &scissor;
    VkPipelineRasterizationStateCreateInfo raster{VK_STRUCTURE_TYPE_PIPELINE_RASTERIZATION_STATE_CREATE_INFO};
    raster.polygonMode = VK_POLYGON_MODE_FILL;
    // glTF's front faces are counter-clockwise; the index buffer holds mirroring instances'
    // triangles flipped and double-sided meshes' twice, so one state serves every draw.
    raster.cullMode = config_.cull_back_faces ? VK_CULL_MODE_BACK_BIT : VK_CULL_MODE_NONE;
    raster.frontFace = VK_FRONT_FACE_COUNTER_CLOCKWISE;
    raster.lineWidth = 1.0f;
    VkPipelineMultisampleStateCreateInfo multisample{VK_STRUCTURE_TYPE_PIPELINE_MULTISAMPLE_STATE_CREATE_INFO};
    multisample.rasterizationSamples = VK_SAMPLE_COUNT_1_BIT;
    VkPipelineDepthStencilStateCreateInfo depth{VK_STRUCTURE_TYPE_PIPELINE_DEPTH_STENCIL_STATE_CREATE_INFO};
    depth.depthTestEnable = VK_TRUE;
    depth.depthWriteEnable = VK_TRUE;
    VkPipelineColorBlendAttachmentState blend_attachment{};
    blend_attachment.colorWriteMask =
        VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT | VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
    VkPipelineColorBlendStateCreateInfo blend{VK_STRUCTURE_TYPE_PIPELINE_COLOR_BLEND_STATE_CREATE_INFO};
    blend.attachmentCount = 1;
    blend.pAttachments = &blend_attachment;
    VkGraphicsPipelineCreateInfo info{VK_STRUCTURE_TYPE_GRAPHICS_PIPELINE_CREATE_INFO};
    info.stageCount = 2;
    info.pStages = stages;
    info.pVertexInputState = &vertex_input;
    info.pInputAssemblyState = &assembly;
    info.pViewportState = &viewport_state;
    info.pRasterizationState = &raster;
    info.pMultisampleState = &multisample;
    info.pDepthStencilState = &depth;
    info.pColorBlendState = &blend;
    info.layout = pipeline_layout_;
    info.renderPass = render_pass_;
    info.subpass = 0;
    for (int reversed = 0; reversed < 2; ++reversed) {
      depth.depthCompareOp = reversed ? VK_COMPARE_OP_GREATER : VK_COMPARE_OP_LESS;
      stages[1].module = frag;
      CULLPIPE_VK_CHECK(vkCreateGraphicsPipelines(dev, VK_NULL_HANDLE, 1, &info, nullptr, &pipeline_[reversed]));
      stages[1].module = id_frag;
      CULLPIPE_VK_CHECK(vkCreateGraphicsPipelines(dev, VK_NULL_HANDLE, 1, &info, nullptr, &id_pipeline_[reversed]));
      if (primitive_frag) {
        stages[1].module = primitive_frag;
        CULLPIPE_VK_CHECK(
            vkCreateGraphicsPipelines(dev, VK_NULL_HANDLE, 1, &info, nullptr, &primitive_pipeline_[reversed]));
      }
      // Depth only (the first phase of an occlusion frame): no fragment shader, no colour.
      info.stageCount = 1;
      blend_attachment.colorWriteMask = 0;
      CULLPIPE_VK_CHECK(vkCreateGraphicsPipelines(dev, VK_NULL_HANDLE, 1, &info, nullptr, &depth_pipeline_[reversed]));
      info.stageCount = 2;
      blend_attachment.colorWriteMask =
          VK_COLOR_COMPONENT_R_BIT | VK_COLOR_COMPONENT_G_BIT | VK_COLOR_COMPONENT_B_BIT | VK_COLOR_COMPONENT_A_BIT;
    }
  } catch (...) {
    vkDestroyShaderModule(dev, vert, nullptr);
    if (frag) vkDestroyShaderModule(dev, frag, nullptr);
    if (id_frag) vkDestroyShaderModule(dev, id_frag, nullptr);
    if (primitive_frag) vkDestroyShaderModule(dev, primitive_frag, nullptr);
    throw;
  }
  vkDestroyShaderModule(dev, vert, nullptr);
  vkDestroyShaderModule(dev, frag, nullptr);
  vkDestroyShaderModule(dev, id_frag, nullptr);
  if (primitive_frag) vkDestroyShaderModule(dev, primitive_frag, nullptr);
}

void Renderer::release() {
  VkDevice dev = ctx_.device();
  if (ctx_.owns_device()) vkDeviceWaitIdle(dev);
  cluster_culler_.reset();
  culler_.reset();
  if (stats_pool_) vkDestroyQueryPool(dev, stats_pool_, nullptr);
  if (cmd_) vkFreeCommandBuffers(dev, ctx_.command_pool(), 1, &cmd_);
  for (VkPipeline& p : pipeline_)
    if (p) vkDestroyPipeline(dev, p, nullptr), p = VK_NULL_HANDLE;
  for (VkPipeline& p : depth_pipeline_)
    if (p) vkDestroyPipeline(dev, p, nullptr), p = VK_NULL_HANDLE;
  for (VkPipeline& p : id_pipeline_)
    if (p) vkDestroyPipeline(dev, p, nullptr), p = VK_NULL_HANDLE;
  for (VkPipeline& p : primitive_pipeline_)
    if (p) vkDestroyPipeline(dev, p, nullptr), p = VK_NULL_HANDLE;
  if (descriptor_pool_) vkDestroyDescriptorPool(dev, descriptor_pool_, nullptr);
  if (pipeline_layout_) vkDestroyPipelineLayout(dev, pipeline_layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(dev, set_layout_, nullptr);
  if (framebuffer_) vkDestroyFramebuffer(dev, framebuffer_, nullptr);
  if (render_pass_) vkDestroyRenderPass(dev, render_pass_, nullptr);
  if (color_view_) vkDestroyImageView(dev, color_view_, nullptr);
  if (depth_view_) vkDestroyImageView(dev, depth_view_, nullptr);
  if (color_) vkDestroyImage(dev, color_, nullptr);
  if (depth_) vkDestroyImage(dev, depth_, nullptr);
  if (color_memory_) vkFreeMemory(dev, color_memory_, nullptr);
  if (depth_memory_) vkFreeMemory(dev, depth_memory_, nullptr);
  stats_pool_ = VK_NULL_HANDLE;
  cmd_ = VK_NULL_HANDLE;
  descriptor_pool_ = VK_NULL_HANDLE;
  pipeline_layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
  framebuffer_ = VK_NULL_HANDLE;
  render_pass_ = VK_NULL_HANDLE;
  color_view_ = depth_view_ = VK_NULL_HANDLE;
  color_ = depth_ = VK_NULL_HANDLE;
  color_memory_ = depth_memory_ = VK_NULL_HANDLE;
}

void Renderer::begin_frame() {
  CULLPIPE_VK_CHECK(vkResetCommandBuffer(cmd_, 0));
  VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
  begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  CULLPIPE_VK_CHECK(vkBeginCommandBuffer(cmd_, &begin));
}

void Renderer::record_scene_pass(const Camera& camera, ScenePass pass, const std::function<void()>& draw) {
  const bool ids = pass == ScenePass::Ids, primitives = pass == ScenePass::Primitives;
  VkClearValue clears[2];
  clears[0].color =
      ids || primitives ? VkClearColorValue{{0.0f, 0.0f, 0.0f, 0.0f}} : VkClearColorValue{{0.085f, 0.09f, 0.11f, 1.0f}};
  clears[1].depthStencil = {camera.reversed_z ? 0.0f : 1.0f, 0};
  VkRenderPassBeginInfo rp{VK_STRUCTURE_TYPE_RENDER_PASS_BEGIN_INFO};
  rp.renderPass = render_pass_;
  rp.framebuffer = framebuffer_;
  rp.renderArea = {{0, 0}, {config_.width, config_.height}};
  rp.clearValueCount = 2;
  rp.pClearValues = clears;
  vkCmdBeginRenderPass(cmd_, &rp, VK_SUBPASS_CONTENTS_INLINE);
  const int reversed = camera.reversed_z ? 1 : 0;
  const VkPipeline pipeline = ids                        ? id_pipeline_[reversed]
                              : primitives               ? primitive_pipeline_[reversed]
                              : pass == ScenePass::Depth ? depth_pipeline_[reversed]
                                                         : pipeline_[reversed];
  vkCmdBindPipeline(cmd_, VK_PIPELINE_BIND_POINT_GRAPHICS, pipeline);
  const VkDescriptorSet set = ids                          ? id_descriptor_set_
                              : pass == ScenePass::Classes ? class_descriptor_set_
                                                           : descriptor_set_;
  vkCmdBindDescriptorSets(cmd_, VK_PIPELINE_BIND_POINT_GRAPHICS, pipeline_layout_, 0, 1, &set, 0, nullptr);
  const VkDeviceSize zero = 0;
  VkBuffer vb = vertices_.handle();
  vkCmdBindVertexBuffers(cmd_, 0, 1, &vb, &zero);
  vkCmdBindIndexBuffer(cmd_, indices_.handle(), 0, VK_INDEX_TYPE_UINT32);
  const gpu::RenderParams params{camera.view_proj()};
  vkCmdPushConstants(cmd_, pipeline_layout_, VK_SHADER_STAGE_VERTEX_BIT, 0, sizeof(params), &params);
  draw();
  vkCmdEndRenderPass(cmd_);
}

Image Renderer::submit_and_read() {
  VkBufferImageCopy copy{};
  copy.imageSubresource = {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1};
  copy.imageExtent = {config_.width, config_.height, 1};
  vkCmdCopyImageToBuffer(cmd_, color_, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, readback_.handle(), 1, &copy);
  VkMemoryBarrier to_host{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, VK_ACCESS_TRANSFER_WRITE_BIT,
                          VK_ACCESS_HOST_READ_BIT};
  vkCmdPipelineBarrier(cmd_, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_PIPELINE_STAGE_HOST_BIT, 0, 1, &to_host, 0, nullptr, 0,
                       nullptr);
  CULLPIPE_VK_CHECK(vkEndCommandBuffer(cmd_));
  ctx_.submit_and_wait(cmd_);
  Image image;
  image.width = config_.width;
  image.height = config_.height;
  image.rgba.resize(std::size_t(config_.width) * config_.height * 4);
  std::memcpy(image.rgba.data(), readback_.data(), image.rgba.size());
  return image;
}

Image Renderer::draw_everything(const Camera& camera, ScenePass pass) {
  const std::size_t n = templates_.size();
  begin_frame();
  record_scene_pass(camera, pass, [&] {
    if (n > 0) vkCmdDrawIndexedIndirect(cmd_, all_draws_.handle(), 0, std::uint32_t(n), sizeof(DrawCommand));
  });
  return submit_and_read();
}

std::optional<std::uint64_t> Renderer::visible_triangles(const Camera& camera) {
  if (!primitive_pipeline_[0]) return std::nullopt;
  const Image objects = draw_everything(camera, ScenePass::Ids);
  const Image primitives = draw_everything(camera, ScenePass::Primitives);
  std::vector<std::uint64_t> owners;
  for (std::size_t p = 0; p < objects.rgba.size(); p += 4) {
    const std::uint64_t object = std::uint64_t(objects.rgba[p]) | std::uint64_t(objects.rgba[p + 1]) << 8 |
                                 std::uint64_t(objects.rgba[p + 2]) << 16;
    const std::uint64_t primitive = std::uint64_t(primitives.rgba[p]) | std::uint64_t(primitives.rgba[p + 1]) << 8 |
                                    std::uint64_t(primitives.rgba[p + 2]) << 16 |
                                    std::uint64_t(primitives.rgba[p + 3]) << 24;
    if (object != 0 && primitive != 0) owners.push_back(object << 32 | primitive);
  }
  std::sort(owners.begin(), owners.end());
  return std::uint64_t(std::unique(owners.begin(), owners.end()) - owners.begin());
}

std::vector<bool> Renderer::pixel_owners(const Camera& camera) {
  const std::size_t n = templates_.size();
  const Image image = draw_everything(camera, ScenePass::Ids);
  std::vector<bool> owners(n, false);
  for (std::size_t p = 0; p < image.rgba.size(); p += 4) {
    const std::uint32_t id =
        std::uint32_t(image.rgba[p]) | std::uint32_t(image.rgba[p + 1]) << 8 | std::uint32_t(image.rgba[p + 2]) << 16;
    if (id != 0 && id <= n) owners[id - 1] = true;
  }
  return owners;
}

Image Renderer::class_image(const Camera& observer, const FrameStats& stats) {
  const std::size_t n = templates_.size();
  const bool by_cluster = cluster_culler_ != nullptr;
  const std::size_t records = by_cluster ? cluster_culler_->pair_count() : n;
  const std::size_t have = by_cluster ? stats.cluster_pair_classes.size() : stats.classes.size();
  if (have != records)
    throw std::invalid_argument("class_image: the frame stats hold " + std::to_string(have) + " classes, the " +
                                (by_cluster ? "renderer's cluster pairs are " : "renderer's objects are ") +
                                std::to_string(records) + " (give the stats of a culled frame of this renderer)");
  const auto rgba = [](std::uint32_t c) {
    return glm::vec4(float(c >> 24) / 255.0f, float(c >> 16 & 255u) / 255.0f, float(c >> 8 & 255u) / 255.0f, 1.0f);
  };
  // A record per object or pair (its object's model matrix, the class's colour) and a draw per
  // record whose firstInstance is that record: the same triangles as the unculled frame's draws.
  const std::span<const RenderObject> models = objects_.as<const RenderObject>();
  std::vector<RenderObject> painted(records);
  std::vector<DrawCommand> draws(records);
  if (by_cluster) {
    using clusters::ClusterClass;
    const std::span<const DrawCommand> pair_draws = all_cluster_draws_.as<const DrawCommand>();
    for (std::size_t p = 0; p < records; ++p) {
      const ClusterClass c = stats.cluster_pair_classes[p];
      const std::uint32_t color = c == ClusterClass::Drawn        ? kColorInside
                                  : c == ClusterClass::Occluded   ? kColorOccluded
                                  : c == ClusterClass::BackFacing ? kColorBackFacing
                                  : c == ClusterClass::Outside    ? kColorOutside
                                                                  : kColorObjectCulled;
      draws[p] = pair_draws[p];
      painted[p] = {models[draws[p].first_instance].model, rgba(color)};
      draws[p].first_instance = std::uint32_t(p);
    }
  } else {
    for (std::size_t i = 0; i < n; ++i) {
      const Classification c = stats.classes[i];
      const std::uint32_t color = c == Classification::Inside         ? kColorInside
                                  : c == Classification::Intersecting ? kColorIntersecting
                                  : c == Classification::Occluded     ? kColorOccluded
                                                                      : kColorOutside;
      painted[i] = {models[i].model, rgba(color)};
      draws[i] = templates_[i];
    }
  }
  // Every pass before has completed (each waits), so the last call's buffers can be replaced.
  class_objects_ = vulkan::Buffer(ctx_, std::max<std::size_t>(records * sizeof(RenderObject), 16),
                                  VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "class image object buffer");
  class_draws_ = vulkan::Buffer(ctx_, std::max<std::size_t>(records * sizeof(DrawCommand), 16),
                                VK_BUFFER_USAGE_INDIRECT_BUFFER_BIT, "class image draw buffer");
  if (records) {
    std::memcpy(class_objects_.data(), painted.data(), records * sizeof(RenderObject));
    std::memcpy(class_draws_.data(), draws.data(), records * sizeof(DrawCommand));
  }
  write_objects(ctx_.device(), class_descriptor_set_, class_objects_);
  begin_frame();
  record_scene_pass(observer, ScenePass::Classes, [&] {
    if (records > 0)
      vkCmdDrawIndexedIndirect(cmd_, class_draws_.handle(), 0, std::uint32_t(records), sizeof(DrawCommand));
  });
  return submit_and_read();
}

Image Renderer::render(const Camera& camera, CullMode mode, FrameStats* stats) {
  const glm::mat4 view_proj = camera.view_proj();
  const Frustum frustum = Frustum::from_view_proj(view_proj);
  const std::size_t n = templates_.size();
  const bool cull = mode != CullMode::None, occlusion = mode == CullMode::Occlusion;
  gpu::CullOptions options;
  options.classes = stats != nullptr;
  options.visible_ids = false;
  options.ordered = true;  // the draws in object order, as the unculled frame issues them
  options.draws = true;
  if (occlusion) {
    if (!pyramid_) pyramid_ = std::make_unique<gpu::DepthPyramidPass>(ctx_);
    options.pyramid = pyramid_.get();
    options.occlusion_views = {occlusion::OcclusionView{view_proj, config_.width, config_.height, camera.reversed_z}};
    options.occlusion_options = config_.occlusion;
  }
  const bool first_phase = occlusion && has_visibility_;

  begin_frame();
  if (stats_pool_) vkCmdResetQueryPool(cmd_, stats_pool_, 0, 1);

  const auto scene_pass = [&](const std::function<void()>& draw) { record_scene_pass(camera, ScenePass::Image, draw); };
  // n <= maxDrawIndirectCount (checked at construction): one call either way. The culled count
  // (view 0's visible_count) cannot exceed the capacity n: maxDrawCount = n. Cluster frames draw
  // the cluster pass's draws, as many as there are pairs at most.
  const auto culled_draws = [&] {
    if (cluster_culler_) {
      if (cluster_culler_->pair_count() > 0)
        vkCmdDrawIndexedIndirectCount(cmd_, cluster_culler_->draw_buffer().handle(), 0,
                                      cluster_culler_->counter_buffer().handle(), 0,
                                      std::uint32_t(cluster_culler_->pair_count()), sizeof(DrawCommand));
    } else if (n > 0) {
      vkCmdDrawIndexedIndirectCount(cmd_, culler_->draw_buffer().handle(), 0, culler_->counter_buffer().handle(), 0,
                                    std::uint32_t(n), sizeof(DrawCommand));
    }
  };

  std::size_t first_phase_draws = 0;
  if (occlusion) {
    // First phase: what the last culled frame kept (its draws, still in the culler's buffers),
    // for depth; then that depth as a pyramid.
    if (first_phase) {
      first_phase_draws =
          cluster_culler_
              ? std::min<std::size_t>(cluster_culler_->counter_buffer().as<const gpu::ViewCounters>()[0].visible_count,
                                      cluster_culler_->pair_count())
              : std::min<std::size_t>(culler_->counter_buffer().as<const gpu::ViewCounters>()[0].visible_count, n);
      record_scene_pass(camera, ScenePass::Depth, culled_draws);  // (its colour is cleared below)
    } else {
      record_scene_pass(camera, ScenePass::Depth, [] {});  // nothing drawn: a cleared depth occludes nothing
    }
    pyramid_->record(cmd_, depth_source(), camera.reversed_z);
  }
  if (cull) culler_->record(cmd_, std::span(&frustum, 1), options);
  if (cull && cluster_culler_) {
    // Each kept object's clusters: by the frustum, their cones (perspective views: the eye is
    // the projection's centre) and the same pyramid.
    gpu::ClusterFrame frame;
    frame.frustum = frustum;
    frame.backface = config_.cull_back_faces && !camera.orthographic;
    frame.eye = camera.eye;
    frame.object_classes = &culler_->class_buffer();
    if (occlusion) {
      frame.pyramid = pyramid_.get();
      frame.occlusion_view = options.occlusion_views[0];
      frame.occlusion_options = options.occlusion_options;
    }
    cluster_culler_->record(cmd_, frame);
  }
  // The image: every object, or what the culling pass kept, in object order.
  scene_pass([&] {
    if (stats_pool_) vkCmdBeginQuery(cmd_, stats_pool_, 0, 0);
    if (cull) {
      culled_draws();
    } else if (cluster_culler_) {
      // Cluster by cluster, as the cluster frames draw them.
      if (cluster_culler_->pair_count() > 0)
        vkCmdDrawIndexedIndirect(cmd_, all_cluster_draws_.handle(), 0, std::uint32_t(cluster_culler_->pair_count()),
                                 sizeof(DrawCommand));
    } else if (n > 0) {
      vkCmdDrawIndexedIndirect(cmd_, all_draws_.handle(), 0, std::uint32_t(n), sizeof(DrawCommand));
    }
    if (stats_pool_) vkCmdEndQuery(cmd_, stats_pool_, 0);
  });

  const Image image = submit_and_read();
  // The culler's draws are what this frame kept: the next occlusion frame's first phase (any
  // set of objects would keep its image exact; last frame's visible ones make the pyramid tight).
  if (cull) has_visibility_ = true;
  if (stats) {
    stats->objects = n;
    stats->first_phase_draws = first_phase_draws;
    stats->occluded = 0;
    stats->clusters = cluster_culler_ ? cluster_culler_->pair_count() : 0;
    stats->cluster_classes = {};
    stats->cluster_pair_classes.clear();
    stats->clusters_drawn = 0;
    if (cull) {
      const gpu::CullResult r = culler_->read_results();
      stats->draws = std::min<std::size_t>(r.views[0].counts.visible, n);
      stats->occluded = r.views[0].counts.occluded;
      stats->classes = r.views[0].classes;
      if (cluster_culler_) {
        const gpu::ClusterResult c = cluster_culler_->read_results();
        stats->cluster_classes = c.counts;
        stats->cluster_pair_classes = c.classes;
        stats->clusters_drawn = c.drawn;
        stats->draws = std::min(c.draws, cluster_culler_->pair_count());
      }
    } else {
      stats->draws = cluster_culler_ ? cluster_culler_->pair_count() : n;  // a draw per cluster, or per object
      stats->classes.clear();
    }
    stats->primitives = 0;
    stats->primitives_counted = false;
    if (stats_pool_) {
      std::uint64_t prims = 0;
      CULLPIPE_VK_CHECK(vkGetQueryPoolResults(ctx_.device(), stats_pool_, 0, 1, sizeof(prims), &prims, sizeof(prims),
                                              VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT));
      stats->primitives = prims;
      stats->primitives_counted = true;
    }
  }
  return image;
}

Image cluster_top_down_image(const Renderer& renderer, const FrameStats& stats, const Camera& camera,
                             std::uint32_t size) {
  using clusters::ClusterClass;
  const ClusterClass order[5] = {ClusterClass::ObjectCulled, ClusterClass::Outside, ClusterClass::BackFacing,
                                 ClusterClass::Occluded, ClusterClass::Drawn};
  const std::uint32_t colors[5] = {kColorObjectCulled, kColorOutside, kColorBackFacing, kColorOccluded, kColorInside};
  std::vector<Aabb> boxes;
  std::vector<std::uint32_t> box_colors;
  for (int layer = 0; layer < 5; ++layer) {
    std::size_t p = 0;
    for (const gpu::ClusterInstance& in : renderer.cluster_instances())
      for (std::uint32_t k = 0; k < in.cluster_count; ++k, ++p)
        if (p < stats.cluster_pair_classes.size() && stats.cluster_pair_classes[p] == order[layer]) {
          boxes.push_back(instance_volume(renderer.cluster_boxes()[in.first_cluster + k], in.transform));
          box_colors.push_back(colors[layer]);
        }
  }
  return top_down_image(boxes, box_colors, camera, size);
}

std::vector<occlusion::OccluderBox> box_occluders(const Scene& scene) {
  std::vector<occlusion::OccluderBox> occluders;
  for (const SceneObject& object : scene.objects)
    if (!object.triangles) occluders.push_back(occlusion::occluder_box(object.local_bounds, object.world));
  return occluders;
}

}  // namespace cullpipe::render
