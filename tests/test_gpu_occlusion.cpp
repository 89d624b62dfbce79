// The depth pyramid on the GPU (lavapipe, validation on): bit for bit the CPU's pyramid of the
// same depth image for every size, and clear refusals of depth images it cannot reduce.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <limits>
#include <vector>

#include "cullpipe/bvh/builders.hpp"
#include "cullpipe/cull/compare.hpp"
#include "cullpipe/cull/depth_pyramid.hpp"
#include "cullpipe/cull/occlusion.hpp"
#include "cullpipe/gpu/bvh_culler.hpp"
#include "cullpipe/gpu/cluster_culler.hpp"
#include "cullpipe/gpu/depth_pyramid_pass.hpp"
#include "cullpipe/gpu/gpu_culler.hpp"
#include "cullpipe/scene/clusters.hpp"
#include "cullpipe/vulkan/buffer.hpp"
#include "cullpipe/vulkan/check.hpp"
#include "gpu_test_env.hpp"
#include "mesh_test_util.hpp"
#include "occlusion_test_util.hpp"
#include "test_util.hpp"

namespace cullpipe {
namespace {

using PyramidEnvironment = test::GpuTestEnvironment<gpu::DepthPyramidPass>;
const auto* const kEnvironment = ::testing::AddGlobalTestEnvironment(new PyramidEnvironment);
using GpuPyramid = test::GpuTest<gpu::DepthPyramidPass>;

/// A depth image in device memory holding given values, left in `layout` as a renderer leaves
/// its depth attachment.
class DepthImage {
 public:
  DepthImage(const vulkan::Context& ctx, std::uint32_t width, std::uint32_t height, const std::vector<float>& depth,
             VkFormat format = VK_FORMAT_D32_SFLOAT,
             VkImageLayout layout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL)
      : DepthImage(ctx, width, height, depth.data(), depth.size() * sizeof(float), format, layout) {}
  /// Depth as the format's buffer copies lay it out (D16: two bytes a value; 24-bit: a word each).
  DepthImage(const vulkan::Context& ctx, std::uint32_t width, std::uint32_t height, const void* data, std::size_t bytes,
             VkFormat format, VkImageLayout layout = VK_IMAGE_LAYOUT_DEPTH_STENCIL_ATTACHMENT_OPTIMAL)
      : ctx_(ctx) {
    VkImageCreateInfo info{VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO};
    info.imageType = VK_IMAGE_TYPE_2D;
    info.format = format;
    info.extent = {width, height, 1};
    info.mipLevels = 1;
    info.arrayLayers = 1;
    info.samples = VK_SAMPLE_COUNT_1_BIT;
    info.tiling = VK_IMAGE_TILING_OPTIMAL;
    info.usage =
        VK_IMAGE_USAGE_DEPTH_STENCIL_ATTACHMENT_BIT | VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT;
    CULLPIPE_VK_CHECK(vkCreateImage(ctx.device(), &info, nullptr, &image_));
    VkMemoryRequirements req;
    vkGetImageMemoryRequirements(ctx.device(), image_, &req);
    VkMemoryAllocateInfo alloc{VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO};
    alloc.allocationSize = req.size;
    alloc.memoryTypeIndex = ctx.find_memory_type(req.memoryTypeBits, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
    CULLPIPE_VK_CHECK(vkAllocateMemory(ctx.device(), &alloc, nullptr, &memory_));
    CULLPIPE_VK_CHECK(vkBindImageMemory(ctx.device(), image_, memory_, 0));
    const bool stencil = format == VK_FORMAT_D32_SFLOAT_S8_UINT || format == VK_FORMAT_D24_UNORM_S8_UINT ||
                         format == VK_FORMAT_D16_UNORM_S8_UINT;
    // Staging copy of the depth values into the image, then the layout a renderer leaves.
    vulkan::Buffer staging(ctx, bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, "depth staging");
    std::memcpy(staging.data(), data, bytes);
    VkCommandBufferAllocateInfo cmd_info{VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO};
    cmd_info.commandPool = ctx.command_pool();
    cmd_info.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
    cmd_info.commandBufferCount = 1;
    VkCommandBuffer cmd;
    CULLPIPE_VK_CHECK(vkAllocateCommandBuffers(ctx.device(), &cmd_info, &cmd));
    VkCommandBufferBeginInfo begin{VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO};
    begin.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    CULLPIPE_VK_CHECK(vkBeginCommandBuffer(cmd, &begin));
    VkImageMemoryBarrier barrier{VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER};
    barrier.dstAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    barrier.oldLayout = VK_IMAGE_LAYOUT_UNDEFINED;
    barrier.newLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
    barrier.srcQueueFamilyIndex = barrier.dstQueueFamilyIndex = VK_QUEUE_FAMILY_IGNORED;
    barrier.image = image_;
    barrier.subresourceRange = {
        VkImageAspectFlags(VK_IMAGE_ASPECT_DEPTH_BIT | (stencil ? VK_IMAGE_ASPECT_STENCIL_BIT : 0)), 0, 1, 0, 1};
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, 0, 0, nullptr, 0,
                         nullptr, 1, &barrier);
    VkBufferImageCopy copy{};
    copy.imageSubresource = {VK_IMAGE_ASPECT_DEPTH_BIT, 0, 0, 1};
    copy.imageExtent = {width, height, 1};
    vkCmdCopyBufferToImage(cmd, staging.handle(), image_, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, 1, &copy);
    barrier.srcAccessMask = VK_ACCESS_TRANSFER_WRITE_BIT;
    barrier.dstAccessMask = VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_READ_BIT | VK_ACCESS_DEPTH_STENCIL_ATTACHMENT_WRITE_BIT |
                            VK_ACCESS_TRANSFER_READ_BIT;
    barrier.oldLayout = VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL;
    barrier.newLayout = layout;
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_TRANSFER_BIT,
                         VK_PIPELINE_STAGE_EARLY_FRAGMENT_TESTS_BIT | VK_PIPELINE_STAGE_LATE_FRAGMENT_TESTS_BIT |
                             VK_PIPELINE_STAGE_TRANSFER_BIT,
                         0, 0, nullptr, 0, nullptr, 1, &barrier);
    CULLPIPE_VK_CHECK(vkEndCommandBuffer(cmd));
    ctx.submit_and_wait(cmd);
    vkFreeCommandBuffers(ctx.device(), ctx.command_pool(), 1, &cmd);
    source_ = {image_, layout, format, width, height};
  }
  ~DepthImage() {
    vkDestroyImage(ctx_.device(), image_, nullptr);
    vkFreeMemory(ctx_.device(), memory_, nullptr);
  }
  DepthImage(const DepthImage&) = delete;
  DepthImage& operator=(const DepthImage&) = delete;
  const gpu::DepthSource& source() const { return source_; }

 private:
  const vulkan::Context& ctx_;
  VkImage image_ = VK_NULL_HANDLE;
  VkDeviceMemory memory_ = VK_NULL_HANDLE;
  gpu::DepthSource source_;
};

const vulkan::Context& context() { return *PyramidEnvironment::context; }

void expect_same_pyramid(const occlusion::DepthPyramid& gpu, const occlusion::DepthPyramid& cpu,
                         const std::string& what) {
  ASSERT_EQ(gpu.levels, cpu.levels) << what;
  ASSERT_EQ(gpu.texels.size(), cpu.texels.size()) << what;
  for (unsigned k = 0; k < cpu.levels.size(); ++k) {
    const auto& level = cpu.levels[k];
    for (std::uint32_t y = 0; y < level.height; ++y)
      for (std::uint32_t x = 0; x < level.width; ++x) {
        const float g = gpu.at(k, x, y), c = cpu.at(k, x, y);
        ASSERT_EQ(std::memcmp(&g, &c, sizeof g), 0)
            << what << ": level " << k << " texel " << x << "," << y << ": gpu " << g << ", cpu " << c;
      }
  }
}

TEST_F(GpuPyramid, EqualsTheCpuPyramidForEverySize) {
  test::Rng rng(5);
  std::vector<std::pair<std::uint32_t, std::uint32_t>> sizes = {
      {1, 1}, {1, 2}, {2, 1}, {3, 3}, {7, 1}, {1, 9}, {5, 7}, {16, 16}, {17, 9}, {33, 64}, {960, 540}, {1023, 3}};
  for (int i = 0; i < 8; ++i)
    sizes.push_back({1 + std::uint32_t(rng.next() % 300), 1 + std::uint32_t(rng.next() % 300)});
  for (const bool reversed : {false, true})
    for (const auto& [w, h] : sizes) {
      std::vector<float> depth(std::size_t(w) * h);
      for (float& d : depth) {
        const std::uint64_t pick = rng.next() % 16;
        // Ties, the ends, a subnormal, -0, and rarely a NaN (which wins every level above it).
        d = pick == 0                           ? 0.0f
            : pick == 1                         ? 1.0f
            : pick == 2                         ? 1e-40f
            : pick == 3                         ? -0.0f
            : pick == 4 && rng.next() % 64 == 0 ? std::numeric_limits<float>::quiet_NaN()
                                                : rng.uniform();
      }
      const DepthImage image(context(), w, h, depth);
      const occlusion::DepthPyramid gpu = culler().build(image.source(), reversed);
      const occlusion::DepthPyramid cpu = occlusion::build_depth_pyramid(depth, w, h, reversed);
      expect_same_pyramid(gpu, cpu, std::to_string(w) + "x" + std::to_string(h) + (reversed ? " reversed" : ""));
    }
}

TEST_F(GpuPyramid, ReducesTheDepthOfACombinedDepthStencilImage) {
  std::vector<float> depth(37 * 21);
  test::Rng rng(9);
  for (float& d : depth) d = rng.uniform();
  const DepthImage image(context(), 37, 21, depth, VK_FORMAT_D32_SFLOAT_S8_UINT);
  expect_same_pyramid(culler().build(image.source(), false), occlusion::build_depth_pyramid(depth, 37, 21, false),
                      "D32S8");
}

// Unorm depth (D16, and the 24-bit formats, their undefined high byte set at random): the GPU's
// pyramid equals occlusion::build_unorm_depth_pyramid of the same integers, bit for bit, for
// both depth directions; formats the device cannot hold as a depth image are skipped by name.
TEST_F(GpuPyramid, UnormDepthEqualsTheCpuPyramid) {
  test::Rng rng(17);
  std::size_t formats = 0;
  for (const VkFormat format :
       {VK_FORMAT_D16_UNORM, VK_FORMAT_X8_D24_UNORM_PACK32, VK_FORMAT_D24_UNORM_S8_UINT, VK_FORMAT_D16_UNORM_S8_UINT}) {
    VkFormatProperties props;
    vkGetPhysicalDeviceFormatProperties(context().physical_device(), format, &props);
    const VkFormatFeatureFlags needed = VK_FORMAT_FEATURE_DEPTH_STENCIL_ATTACHMENT_BIT |
                                        VK_FORMAT_FEATURE_TRANSFER_SRC_BIT | VK_FORMAT_FEATURE_TRANSFER_DST_BIT;
    if ((props.optimalTilingFeatures & needed) != needed) {
      std::printf("format %d: not a depth image with copies on this device, skipped\n", int(format));
      continue;
    }
    ++formats;
    const unsigned bits = format == VK_FORMAT_D16_UNORM || format == VK_FORMAT_D16_UNORM_S8_UINT ? 16 : 24;
    const std::uint32_t n = (1u << bits) - 1u;
    for (const bool reversed : {false, true})
      for (const auto& [w, h] :
           std::vector<std::pair<std::uint32_t, std::uint32_t>>{{1, 1}, {3, 5}, {37, 21}, {64, 33}}) {
        std::vector<std::uint32_t> q(std::size_t(w) * h);
        for (std::uint32_t& v : q) {
          const std::uint64_t pick = rng.next() % 8;
          v = pick == 0 ? 0u : pick == 1 ? 1u : pick == 2 ? n : pick == 3 ? n - 1 : std::uint32_t(rng.next() % (n + 1));
        }
        std::vector<std::uint16_t> packed16;
        std::vector<std::uint32_t> words;
        const void* data = nullptr;
        std::size_t bytes = 0;
        if (bits == 16) {
          packed16.assign(q.begin(), q.end());
          data = packed16.data(), bytes = packed16.size() * 2;
        } else {
          for (const std::uint32_t v : q) words.push_back(v | std::uint32_t(rng.next() % 256) << 24);
          data = words.data(), bytes = words.size() * 4;
        }
        const DepthImage image(context(), w, h, data, bytes, format);
        expect_same_pyramid(culler().build(image.source(), reversed),
                            occlusion::build_unorm_depth_pyramid(q, bits, w, h, reversed),
                            "format " + std::to_string(int(format)) + ", " + std::to_string(w) + "x" +
                                std::to_string(h) + (reversed ? " reversed" : ""));
        if (HasFatalFailure()) return;
      }
  }
  EXPECT_GT(formats, 0u);  // D16_UNORM is mandatory for depth attachments
}

TEST_F(GpuPyramid, RefusesWhatItCannotReduceByName) {
  auto message = [&](const gpu::DepthSource& s) -> std::string {
    try {
      culler().build(s, false);
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "";
  };
  std::vector<float> depth(12, 0.5f);
  const DepthImage image(context(), 4, 3, depth);
  gpu::DepthSource s = image.source();
  const std::uint32_t width_before = culler().width();
  s.format = VK_FORMAT_S8_UINT;
  EXPECT_NE(message(s).find("VK_FORMAT_S8_UINT is not supported"), std::string::npos);
  s = image.source();
  s.width = 0;
  EXPECT_NE(message(s).find("0x3 depth image"), std::string::npos);
  s = image.source();
  s.layout = VK_IMAGE_LAYOUT_UNDEFINED;
  EXPECT_NE(message(s).find("undefined"), std::string::npos);
  EXPECT_EQ(culler().width(), width_before);  // nothing changed
  EXPECT_EQ(message(image.source()), "");
}

// The flat pass with occlusion against occlusion::classify_all on the same pyramid: every
// object's class, the counts and the visible list, over random scenes of every volume kind and
// every kind of camera, in arrival and object order.
template <class Volume>
void expect_occlusion_agreement(gpu::DepthPyramidPass& pass, std::uint64_t seed) {
  gpu::GpuCuller culler(context());
  test::Rng rng(seed);
  std::size_t occluded = 0;
  for (int s = 0; s < 16; ++s) {
    const Camera cam = test::random_camera(rng, s % 8);
    const std::uint32_t w = 16 + std::uint32_t(rng.next() % 200), h = 16 + std::uint32_t(rng.next() % 120);
    const glm::mat4 vp = cam.view_proj();
    const test::Caster k(vp, w, h, cam.reversed_z);
    std::vector<Volume> occluders;
    for (int i = 0; i < 6; ++i) occluders.push_back(test::random_volume<Volume>(rng, 8.0f, 6.0f));
    const std::vector<float> depth = test::render_depth(k, occluders);
    const DepthImage image(context(), w, h, depth);
    const occlusion::DepthPyramid pyramid = pass.build(image.source(), cam.reversed_z);
    std::vector<Volume> volumes;
    for (int i = 0; i < 3000; ++i) volumes.push_back(test::random_volume<Volume>(rng, 14.0f, 1.5f));
    const Frustum frustum = Frustum::from_view_proj(vp);
    const occlusion::OcclusionView view{vp, w, h, cam.reversed_z};
    const std::uint32_t texels = 2u << (s % 4);
    // Half the scenes test the volumes the first test keeps again, at 16 texels per axis.
    const occlusion::OcclusionOptions occlusion_options{texels, texels < 16 && (s / 4) % 2 == 1 ? 16u : 0u};
    std::vector<Classification> cpu(volumes.size());
    const reference::CullCounts cpu_counts =
        occlusion::classify_all(std::span<const Volume>(volumes), frustum, view, pyramid, occlusion_options, cpu);
    occluded += cpu_counts.occluded;
    culler.upload(std::span<const Volume>(volumes));
    for (const bool ordered : {false, true}) {
      gpu::CullOptions options;
      options.ordered = ordered;
      options.pyramid = &pass;
      options.occlusion_views = {view};
      options.occlusion_options = occlusion_options;
      const gpu::CullResult result = culler.cull(std::span(&frustum, 1), options);
      const Agreement a = check_agreement<Volume>(volumes, frustum, cpu, cpu_counts, result.views[0].classes,
                                                  result.views[0].counts, result.views[0].visible_ids, volumes.size());
      ASSERT_EQ(a.mismatches, 0u) << "scene " << s << " (camera variant " << s % 8 << ", " << w << "x" << h << ", "
                                  << texels << " texels per axis, refined at "
                                  << occlusion_options.refine_texels_per_axis << (ordered ? ", ordered" : "")
                                  << "): " << (a.reports.empty() ? std::string() : a.reports.front());
    }
  }
  EXPECT_GT(occluded, 1000u) << "too few occluded objects to test the agreement";
}

TEST_F(GpuPyramid, FlatPassWithOcclusionEqualsTheReferenceForBoxes) { expect_occlusion_agreement<Aabb>(culler(), 21); }
TEST_F(GpuPyramid, FlatPassWithOcclusionEqualsTheReferenceForObbs) { expect_occlusion_agreement<Obb>(culler(), 22); }
TEST_F(GpuPyramid, FlatPassWithOcclusionEqualsTheReferenceForSpheres) {
  expect_occlusion_agreement<Sphere>(culler(), 23);
}

// The hierarchical pass with occlusion against occlusion::cull_hierarchical on the same pyramid
// and tree: every object's class, the counts and the node and object tests, with the walk's
// stacks in shared memory and in the records, with small cut subtrees (many walks from the root)
// and the default ones; and its visible list against the classes.
template <class Volume>
void expect_hierarchical_occlusion_agreement(gpu::DepthPyramidPass& pass, std::uint64_t seed) {
  gpu::BvhCuller culler(context());
  test::Rng rng(seed);
  std::size_t occluded = 0;
  for (int s = 0; s < 12; ++s) {
    const Camera cam = test::random_camera(rng, s % 8);
    const std::uint32_t w = 16 + std::uint32_t(rng.next() % 200), h = 16 + std::uint32_t(rng.next() % 120);
    const glm::mat4 vp = cam.view_proj();
    const test::Caster k(vp, w, h, cam.reversed_z);
    std::vector<Volume> volumes;
    for (int i = 0; i < 6; ++i) volumes.push_back(test::random_volume<Volume>(rng, 8.0f, 6.0f));
    const DepthImage image(context(), w, h, test::render_depth(k, volumes));
    const occlusion::DepthPyramid pyramid = pass.build(image.source(), cam.reversed_z);
    for (int i = 0; i < 3000; ++i) volumes.push_back(test::random_volume<Volume>(rng, 14.0f, 1.5f));
    const std::vector<Aabb> boxes = bvh::enclosing_boxes(std::span<const Volume>(volumes));
    const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(boxes, {s % 2 ? 1u : 4u, 16}));
    const Frustum frustum = Frustum::from_view_proj(vp);
    const occlusion::OcclusionView view{vp, w, h, cam.reversed_z};
    const std::uint32_t texels = 2u << (s % 4);
    const occlusion::OcclusionOptions occlusion_options{texels, texels < 16 && (s / 4) % 2 == 1 ? 16u : 0u};
    const bvh::HierarchicalResult cpu =
        occlusion::cull_hierarchical(tree, std::span<const Volume>(volumes), frustum, view, pyramid, occlusion_options);
    occluded += cpu.occluded;
    for (const bool in_records : {false, true})
      for (const std::uint32_t subtree : {64u, gpu::BvhCuller::kCpuSubtreeObjects}) {
        culler.set_walk_stack_in_records(in_records);
        culler.set_subtree_objects(subtree);
        culler.upload(tree, std::span<const Volume>(volumes));
        gpu::CullOptions options;
        options.pyramid = &pass;
        options.occlusion_views = {view};
        options.occlusion_options = occlusion_options;
        const gpu::CullResult result = culler.cull(std::span(&frustum, 1), options);
        const gpu::ViewResult& g = result.views[0];
        const std::string where = "scene " + std::to_string(s) + " (camera variant " + std::to_string(s % 8) + ", " +
                                  std::to_string(w) + "x" + std::to_string(h) + ", " + std::to_string(texels) +
                                  " texels per axis, refined at " +
                                  std::to_string(occlusion_options.refine_texels_per_axis) + ", subtrees of " +
                                  std::to_string(subtree) + (in_records ? ", stacks in records" : "") + ")";
        for (std::size_t i = 0; i < volumes.size(); ++i)
          ASSERT_EQ(g.classes[i], cpu.classes[i])
              << where << ": " << describe_mismatch(i, volumes[i], frustum, cpu.classes[i], g.classes[i]);
        EXPECT_EQ(g.counts.visible, cpu.visible) << where;
        EXPECT_EQ(g.counts.inside, cpu.inside) << where;
        EXPECT_EQ(g.counts.occluded, cpu.occluded) << where;
        EXPECT_EQ(g.node_tests, cpu.node_tests) << where;
        EXPECT_EQ(g.object_tests, cpu.object_tests) << where;
        std::vector<std::uint32_t> ids = g.visible_ids, expected;
        std::sort(ids.begin(), ids.end());
        for (std::size_t i = 0; i < volumes.size(); ++i)
          if (is_visible(cpu.classes[i])) expected.push_back(std::uint32_t(i));
        EXPECT_EQ(ids, expected) << where;
      }
  }
  EXPECT_GT(occluded, 1000u) << "too few occluded objects to test the agreement";
}

TEST_F(GpuPyramid, HierarchicalPassWithOcclusionEqualsTheReferenceForBoxes) {
  expect_hierarchical_occlusion_agreement<Aabb>(culler(), 31);
}
TEST_F(GpuPyramid, HierarchicalPassWithOcclusionEqualsTheReferenceForObbs) {
  expect_hierarchical_occlusion_agreement<Obb>(culler(), 32);
}
TEST_F(GpuPyramid, HierarchicalPassWithOcclusionEqualsTheReferenceForSpheres) {
  expect_hierarchical_occlusion_agreement<Sphere>(culler(), 33);
}

// Large cut subtrees of small boxes, all INSIDE: with occlusion every node and object of a
// workgroup is tested, and on lavapipe all loops of an invocation together may run at most 65535
// iterations; the occlusion passes' own cut of small subtrees keeps a workgroup's walk below
// that whatever subtree_objects() the frustum passes use. Classes and counts against the
// reference, on a far depth (nothing hidden) and on a near one with a far pixel in every 8 x 8
// block (nodes kept, objects mostly hidden).
TEST_F(GpuPyramid, HierarchicalOcclusionOfLargeSubtreesEqualsTheReference) {
  gpu::DepthPyramidPass& pass = culler();
  std::vector<Aabb> boxes;
  for (int i = 0; i < 64; ++i)
    for (int j = 0; j < 64; ++j)
      for (int k = 0; k < 8; ++k) {
        const glm::vec3 c(-12.0f + 24.0f * (float(i) + 0.5f) / 64.0f, -7.0f + 14.0f * (float(j) + 0.5f) / 64.0f,
                          -5.0f + 10.0f * (float(k) + 0.5f) / 8.0f);
        boxes.push_back(Aabb{c - glm::vec3(0.06f), c + glm::vec3(0.06f)});
      }
  Camera cam;
  cam.eye = {0, 0, 30};
  cam.target = {0, 0, 0};
  cam.far_plane = 200.0f;
  const std::uint32_t w = 512, h = 288;
  const glm::mat4 vp = cam.view_proj();
  const Frustum frustum = Frustum::from_view_proj(vp);
  const occlusion::OcclusionView view{vp, w, h, false};
  gpu::BvhCuller culler(context());
  culler.set_subtree_objects(16384);
  for (const bool pattern : {false, true}) {
    std::vector<float> depth(std::size_t(w) * h, pattern ? 0.0f : 1.0f);
    if (pattern)
      for (std::uint32_t y = 0; y < h; y += 8)
        for (std::uint32_t x = 0; x < w; x += 8) depth[y * w + x] = 1.0f;
    const DepthImage image(context(), w, h, depth);
    const occlusion::DepthPyramid pyramid = pass.build(image.source(), false);
    for (const std::uint32_t leaf : {1u, 2u}) {
      const bvh::FlatTree tree = bvh::flatten(bvh::build_binned_sah(boxes, {leaf, 16}));
      culler.upload(tree, std::span<const Aabb>(boxes));
      for (const occlusion::OcclusionOptions occlusion_options :
           {occlusion::OcclusionOptions{4}, occlusion::OcclusionOptions{16}, occlusion::OcclusionOptions{8, 16}}) {
        const std::uint32_t texels = occlusion_options.texels_per_axis;
        const bvh::HierarchicalResult cpu =
            occlusion::cull_hierarchical(tree, std::span<const Aabb>(boxes), frustum, view, pyramid, occlusion_options);
        gpu::CullOptions options;
        options.pyramid = &pass;
        options.occlusion_views = {view};
        options.occlusion_options = occlusion_options;
        const gpu::ViewResult g = culler.cull(std::span(&frustum, 1), options).views[0];
        const std::string where = std::string(pattern ? "near depth with far pixels" : "far depth") + ", leaves of " +
                                  std::to_string(leaf) + ", " + std::to_string(texels) +
                                  " texels per axis, refined at " +
                                  std::to_string(occlusion_options.refine_texels_per_axis);
        std::size_t mismatches = 0;
        for (std::size_t i = 0; i < boxes.size(); ++i) mismatches += g.classes[i] != cpu.classes[i];
        EXPECT_EQ(mismatches, 0u) << where;
        EXPECT_EQ(g.counts.visible, cpu.visible) << where;
        EXPECT_EQ(g.counts.occluded, cpu.occluded) << where;
        EXPECT_EQ(g.node_tests, cpu.node_tests) << where;
        EXPECT_EQ(g.object_tests, cpu.object_tests) << where;
      }
    }
  }
}

// The cluster pass against clusters::classify, pair by pair: instances of two meshes under
// rotated, non-uniformly scaled and mirrored transforms, with and without the object pass's
// classes, the back-face test and the pyramid, from every kind of camera, the clusters with
// OBBs (where they are tighter) and some without; and its draws, the drawn pairs' in pair order.
TEST_F(GpuPyramid, ClusterPassEqualsTheReferencePairByPair) {
  gpu::ClusterCuller pass(context());
  const TriangleMesh meshes[2] = {test::uv_sphere(24, 32, 2.0f), test::uv_sphere(6, 10, 1.0f)};
  std::vector<Aabb> boxes;
  std::vector<BackfaceCone> cones;
  std::vector<std::optional<Obb>> obbs;
  std::uint32_t first[2], count[2];
  for (int m = 0; m < 2; ++m) {
    const MeshClusters c = build_clusters(meshes[m]);
    first[m] = std::uint32_t(boxes.size());
    count[m] = std::uint32_t(c.clusters.size());
    for (const Cluster& cl : c.clusters) {
      boxes.push_back(cl.box);
      cones.push_back(cl.cone);
      obbs.push_back(boxes.size() % 5 == 0 ? std::nullopt : cl.obb);
    }
  }
  ASSERT_GT(std::count_if(obbs.begin(), obbs.end(), [](const auto& o) { return o.has_value(); }), 8);
  test::Rng rng(31);
  std::vector<gpu::ClusterInstance> instances(300);
  std::vector<std::uint32_t> instance_of, cluster_of;  // per pair
  for (std::size_t i = 0; i < instances.size(); ++i) {
    const int m = int(i % 2);
    instances[i] = {test::random_transform(rng, 30.0f), first[m], count[m], i % 7 != 0};
    for (std::uint32_t c = 0; c < count[m]; ++c) {
      instance_of.push_back(std::uint32_t(i));
      cluster_of.push_back(first[m] + c);
    }
  }
  pass.upload(boxes, cones, instances, obbs);
  ASSERT_EQ(pass.pair_count(), instance_of.size());
  std::vector<std::optional<Obb>> placed(instance_of.size());  // each pair's OBB, placed
  for (std::size_t p = 0; p < placed.size(); ++p)
    if (obbs[cluster_of[p]]) placed[p] = instance_volume(*obbs[cluster_of[p]], instances[instance_of[p]].transform);
  // Even instances' clusters follow on from each other in the index buffer (a run of drawn ones
  // is one draw); odd instances' leave gaps (a draw each).
  std::vector<gpu::DrawCommand> templates(pass.pair_count());
  std::uint32_t next = 0;
  for (std::size_t p = 0; p < templates.size(); ++p) {
    const std::uint32_t indices = std::uint32_t(3 * (p % 40 + 1));
    templates[p] = {indices, 1, next, std::int32_t(instance_of[p] % 3), instance_of[p], 0};
    next += indices + (instance_of[p] % 2 ? 3 : 0);
  }
  pass.upload_draws(templates);
  // The indices a list of draws draws, in order: (instance, vertex offset, index) each.
  const auto stream = [](std::span<const gpu::DrawCommand> draws) {
    std::vector<std::array<std::uint32_t, 3>> out;
    for (const gpu::DrawCommand& d : draws)
      for (std::uint32_t k = d.first_index; k < d.first_index + d.index_count; ++k)
        out.push_back({d.first_instance, std::uint32_t(d.vertex_offset), k});
    return out;
  };
  std::size_t all_drawn = 0, all_draws = 0;
  vulkan::Buffer object_classes(context(), instances.size() * 4, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "object classes");

  std::array<std::size_t, clusters::kClusterClassCount> seen{};
  std::size_t obb_culled = 0;  // pairs only their OBB culls
  for (int s = 0; s < 16; ++s) {
    const Camera cam = test::random_camera(rng, s % 8);
    const std::uint32_t w = 32 + std::uint32_t(rng.next() % 200), h = 32 + std::uint32_t(rng.next() % 120);
    const glm::mat4 vp = cam.view_proj();
    const test::Caster k(vp, w, h, cam.reversed_z);
    std::vector<Aabb> occluders;
    for (int i = 0; i < 8; ++i) occluders.push_back(test::random_volume<Aabb>(rng, 12.0f, 8.0f));
    const DepthImage image(context(), w, h, test::render_depth(k, occluders));
    const occlusion::DepthPyramid pyramid = culler().build(image.source(), cam.reversed_z);
    auto* classes = static_cast<std::uint32_t*>(object_classes.data());
    for (std::size_t i = 0; i < instances.size(); ++i) classes[i] = std::uint32_t(rng.next() % 4);

    gpu::ClusterFrame frame;
    frame.frustum = Frustum::from_view_proj(vp);
    frame.eye = cam.eye;
    frame.backface = !cam.orthographic && s % 4 != 3;
    frame.object_classes = s % 2 ? &object_classes : nullptr;
    const bool occlusion = s % 3 != 2;
    if (occlusion) {
      frame.pyramid = &culler();
      frame.occlusion_view = {vp, w, h, cam.reversed_z};
      frame.occlusion_options.texels_per_axis = 2u << (s % 4);
      frame.occlusion_options.refine_texels_per_axis = s % 4 != 3 && s % 5 == 1 ? 16u : 0u;
    }
    const gpu::ClusterResult r = pass.cull(frame);
    clusters::ClusterView view{frame.frustum,
                               frame.eye,
                               frame.backface,
                               occlusion ? &frame.occlusion_view : nullptr,
                               occlusion ? &pyramid : nullptr,
                               frame.occlusion_options};
    std::size_t mismatches = 0;
    std::vector<gpu::DrawCommand> expected;
    for (std::size_t p = 0; p < pass.pair_count(); ++p) {
      const std::uint32_t i = instance_of[p], c = cluster_of[p];
      const gpu::ClusterInstance& in = instances[i];
      const bool kept =
          !frame.object_classes || classes[i] == gpu::CLASS_INSIDE || classes[i] == gpu::CLASS_INTERSECTING;
      clusters::ClusterView v = view;
      v.backface = view.backface && in.backface;
      const clusters::ClusterClass want = clusters::classify(
          boxes[c], cones[c], in.transform, inverse_frame(in.transform), kept, v, placed[p] ? &*placed[p] : nullptr);
      ++seen[std::size_t(want)];
      obb_culled += placed[p] && want != clusters::ClusterClass::Drawn &&
                    clusters::classify(boxes[c], cones[c], in.transform, inverse_frame(in.transform), kept, v) ==
                        clusters::ClusterClass::Drawn;
      if (want == clusters::ClusterClass::Drawn) expected.push_back(templates[p]);
      if (r.classes[p] != want && ++mismatches <= 3)
        ADD_FAILURE() << "frame " << s << " (camera variant " << s % 8 << ", " << w << "x" << h << "): pair " << p
                      << " (instance " << i << ", cluster " << c << ", box " << describe(boxes[c]) << ", cone apex "
                      << cones[c].apex.x << " " << cones[c].apex.y << " " << cones[c].apex.z << " cutoff "
                      << cones[c].cutoff << "): GPU " << to_string(r.classes[p]) << ", reference " << to_string(want);
    }
    ASSERT_EQ(mismatches, 0u);
    ASSERT_EQ(r.drawn, expected.size());
    ASSERT_LE(r.draws, r.drawn);
    const auto draws = pass.draw_buffer().as<const gpu::DrawCommand>().first(r.draws);
    ASSERT_TRUE(stream(draws) == stream(expected)) << "frame " << s << ": the draws do not draw the drawn clusters";
    for (const gpu::DrawCommand& d : draws) ASSERT_EQ(d.instance_count, 1u);
    all_drawn += r.drawn;
    all_draws += r.draws;
  }
  EXPECT_LT(all_draws, all_drawn * 3 / 4) << "runs of drawn clusters are not merged";
  for (std::size_t c : {0, 1, 3, 4, 5}) EXPECT_GT(seen[c], 100u) << "too few pairs of class " << c;
  EXPECT_GT(obb_culled, 20u) << "too few pairs culled by their OBB alone";

  // Every object culled: nothing listed, no workgroups, no draws.
  auto* classes = static_cast<std::uint32_t*>(object_classes.data());
  for (std::size_t i = 0; i < instances.size(); ++i) classes[i] = gpu::CLASS_OUTSIDE;
  gpu::ClusterFrame frame;
  frame.frustum = Frustum::from_view_proj(test::test_view_proj());
  frame.eye = glm::vec3(0.0f, 0.0f, 10.0f);
  frame.object_classes = &object_classes;
  const gpu::ClusterResult none = pass.cull(frame);
  EXPECT_EQ(none.drawn, 0u);
  EXPECT_EQ(none.draws, 0u);
  EXPECT_EQ(none.counts[std::size_t(clusters::ClusterClass::ObjectCulled)], pass.pair_count());

  // Instances with no clusters among others, and a culler with no pairs at all.
  std::vector<gpu::ClusterInstance> sparse = {
      instances[0], {Transform3x4{}, 0, 0, true}, instances[1], {Transform3x4{}, 3, 0, false}};
  pass.upload(boxes, cones, sparse);
  ASSERT_EQ(pass.pair_count(), std::size_t(count[0] + count[1]));
  frame.object_classes = nullptr;
  const gpu::ClusterResult sparse_result = pass.cull(frame);
  clusters::ClusterView view{frame.frustum, frame.eye, true, nullptr, nullptr, {}};
  std::size_t p = 0;
  for (const gpu::ClusterInstance& in : sparse)
    for (std::uint32_t k = 0; k < in.cluster_count; ++k, ++p)
      EXPECT_EQ(sparse_result.classes[p], clusters::classify(boxes[in.first_cluster + k], cones[in.first_cluster + k],
                                                             in.transform, inverse_frame(in.transform), true, view))
          << "pair " << p;
  pass.upload(boxes, cones, {});
  EXPECT_EQ(pass.pair_count(), 0u);
  const gpu::ClusterResult empty = pass.cull(frame);
  EXPECT_EQ(empty.drawn, 0u);
  EXPECT_EQ(empty.draws, 0u);
}

// Bad uploads and frames are refused by name before anything changes: the pass after them is
// the pass before.
TEST_F(GpuPyramid, ClusterPassRefusesBadInputAndKeepsItsState) {
  gpu::ClusterCuller pass(context());
  const MeshClusters c = build_clusters(test::uv_sphere(8, 12, 1.0f));
  std::vector<Aabb> boxes;
  std::vector<BackfaceCone> cones;
  for (const Cluster& cl : c.clusters) boxes.push_back(cl.box), cones.push_back(cl.cone);
  const std::uint32_t n = std::uint32_t(boxes.size());
  std::vector<gpu::ClusterInstance> instances = {{Transform3x4{}, 0, n, true}};
  pass.upload(boxes, cones, instances);
  pass.upload_draws(std::vector<gpu::DrawCommand>(n, gpu::DrawCommand{3, 1, 0, 0, 0, 0}));
  gpu::ClusterFrame frame;
  frame.frustum = Frustum::from_view_proj(test::test_view_proj());
  frame.eye = glm::vec3(0.0f, 0.0f, 10.0f);
  const gpu::ClusterResult before = pass.cull(frame);
  ASSERT_GT(before.drawn, 0u);

  auto message = [&](auto&& call) {
    try {
      call();
    } catch (const std::exception& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  std::vector<gpu::ClusterInstance> past = instances;
  past[0].cluster_count = n + 1;
  EXPECT_NE(message([&] { pass.upload(boxes, cones, past); }).find("instance 0: clusters 0+" + std::to_string(n + 1)),
            std::string::npos);
  std::vector<gpu::ClusterInstance> nan = instances;
  nan[0].transform.rows[1].y = std::numeric_limits<float>::quiet_NaN();
  EXPECT_NE(message([&] { pass.upload(boxes, cones, nan); }).find("instance 0: transform row 1 column 1 is NaN"),
            std::string::npos);
  EXPECT_NE(message([&] { pass.upload(boxes, std::span(cones).first(1), instances); }).find("boxes and 1 cones"),
            std::string::npos);
  const std::vector<std::optional<Obb>> one_obb(1);
  EXPECT_NE(message([&] { pass.upload(boxes, cones, instances, one_obb); }).find("boxes and 1 OBBs"),
            std::string::npos);
  EXPECT_NE(message([&] { pass.upload_draws(std::vector<gpu::DrawCommand>(1)); }).find("1 draws for"),
            std::string::npos);
  gpu::ClusterFrame bad = frame;
  bad.eye.x = std::numeric_limits<float>::infinity();
  EXPECT_NE(message([&] { pass.cull(bad); }).find("the eye is not finite"), std::string::npos);
  bad = frame;
  bad.pyramid = &culler();
  bad.occlusion_view = {test::test_view_proj(), 7, 5, false};  // not the pyramid's size
  EXPECT_NE(message([&] { pass.cull(bad); }), "no error");
  const VkDeviceSize align = context().properties().limits.minStorageBufferOffsetAlignment;
  vulkan::Buffer small(context(), align + 2, VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, "small");
  bad = frame;
  bad.object_classes = &small;
  bad.object_classes_offset = align;
  EXPECT_NE(message([&] { pass.cull(bad); }).find("object class buffer"), std::string::npos);
  if (align > 1) {
    bad.object_classes_offset = 1;
    EXPECT_NE(message([&] { pass.cull(bad); }).find("minStorageBufferOffsetAlignment"), std::string::npos);
  }

  const gpu::ClusterResult after = pass.cull(frame);
  EXPECT_EQ(after.classes, before.classes);
  EXPECT_EQ(after.drawn, before.drawn);
}

}  // namespace
}  // namespace cullpipe
