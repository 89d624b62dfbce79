// build_binned_sah and BinnedSahBuilder: the builder's two variants from one source (the
// baseline: SSE2 on x86-64, plain C++ elsewhere; and AVX2, chosen at run time), its working
// memory, and the choice between the variants.
#include "cullpipe/bvh/binned_sah.hpp"

#include <cmath>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <string_view>

#define CULLPIPE_BINNED_NS baseline
#define CULLPIPE_BINNED_AVX2 0
#include "cullpipe/bvh/binned_sah.inl"
#undef CULLPIPE_BINNED_NS
#undef CULLPIPE_BINNED_AVX2

// The AVX2 variant: only the functions defined in binned_sah.inl get AVX2 (a target pragma, not
// -mavx2 on a file, which would also compile shared inline functions such as std::vector's for
// AVX2, and the linker may keep those copies for every caller).
#if defined(__x86_64__) && defined(__SSE2__) && defined(__GNUC__) && !defined(__clang__)
#define CULLPIPE_HAVE_X86_BUILDERS 1
#pragma GCC push_options
#pragma GCC target("avx2")
#define CULLPIPE_BINNED_NS avx2
#define CULLPIPE_BINNED_AVX2 1
#include "cullpipe/bvh/binned_sah.inl"
#undef CULLPIPE_BINNED_NS
#undef CULLPIPE_BINNED_AVX2
#pragma GCC pop_options
#endif

namespace cullpipe::bvh {

namespace detail {

void BinnedScratch::reserve(std::size_t n) {
  if (capacity >= n) return;
  // Released first, so the old and new buffers are never held together (and, should an
  // allocation throw, the scratch holds nothing rather than null buffers it claims to have).
  capacity = 0;
  buffer[0].reset();
  buffer[1].reset();
  bin_of.reset();
  buffer[0].reset(new Box8[n]);
  buffer[1].reset(new Box8[n]);
  bin_of.reset(new std::uint32_t[n]);
  cullpipe::detail::advise_huge_pages(buffer[0].get(), n * sizeof(Box8));
  cullpipe::detail::advise_huge_pages(buffer[1].get(), n * sizeof(Box8));
  capacity = n;
}

void BinnedScratch::reserve_nodes(std::size_t n) {
  if (node_capacity >= n) return;
  node_capacity = 0;
  nodes.reset();
  // Raw memory: a Node is an implicit-lifetime aggregate, so the array begins to exist in it
  // without a constructor touching every page here, on one thread; each subtree's task
  // touches its own region's pages, and writes every slot before reading it.
  nodes.reset(static_cast<Node*>(::operator new[](2 * n * sizeof(Node))));
  cullpipe::detail::advise_huge_pages(nodes.get(), 2 * n * sizeof(Node));
  node_capacity = n;
}

bool binned_sah_avx2_available() {
#if defined(CULLPIPE_HAVE_X86_BUILDERS)
  // __builtin_cpu_init first: a build from a static initialiser may run before the runtime's.
  static const bool available = (__builtin_cpu_init(), __builtin_cpu_supports("avx2"));
  return available;
#else
  return false;
#endif
}

namespace {

// The variant build_binned_sah and BinnedSahBuilder use: AVX2 where the CPU has it, unless
// CULLPIPE_ISA=portable (which also keeps the fast CPU path on its portable kernels).
bool use_avx2() {
  static const bool use = binned_sah_avx2_available() &&
                          !(std::getenv("CULLPIPE_ISA") && std::string_view(std::getenv("CULLPIPE_ISA")) == "portable");
  return use;
}

}  // namespace

#if !defined(CULLPIPE_HAVE_X86_BUILDERS)
namespace avx2 {
void build(std::span<const Aabb> boxes, const TopDownOptions& options, BinnedScratch& scratch, Tree& tree,
           ThreadPool* pool) {
  baseline::build(boxes, options, scratch, tree, pool);
}
}  // namespace avx2
#endif

}  // namespace detail

BinnedSahBuilder::BinnedSahBuilder() : scratch_(std::make_unique<detail::BinnedScratch>()) {}
BinnedSahBuilder::~BinnedSahBuilder() = default;
BinnedSahBuilder::BinnedSahBuilder(BinnedSahBuilder&&) noexcept = default;
BinnedSahBuilder& BinnedSahBuilder::operator=(BinnedSahBuilder&&) noexcept = default;

void BinnedSahBuilder::build(std::span<const Aabb> boxes, const TopDownOptions& options, Tree& tree, ThreadPool* pool) {
  if (!scratch_) scratch_ = std::make_unique<detail::BinnedScratch>();  // a moved-from builder
  const auto variant = [&](const TopDownOptions& o, Tree& out) {
    if (detail::use_avx2()) {
      detail::avx2::build(boxes, o, *scratch_, out, pool);
    } else {
      detail::baseline::build(boxes, o, *scratch_, out, pool);
    }
  };
  if (options.sah_leaves && !(options.object_cost > 0.0f && std::isfinite(options.object_cost)))
    throw std::invalid_argument("build_binned_sah: object_cost " + std::to_string(options.object_cost) +
                                " (a positive finite number)");
  if (!options.sah_leaves || options.max_leaf_size <= 1) {
    variant(options, tree);
    return;
  }
  // Leaves of one object (the threaded build's fastest path), then collapsed by the SAH.
  TopDownOptions ones = options;
  ones.max_leaf_size = 1;
  ones.sah_leaves = false;
  variant(ones, scratch_->ones);
  detail::collapse_leaves(scratch_->ones, options.max_leaf_size, options.object_cost, tree, scratch_->collapse);
}

void BinnedSahBuilder::release() { scratch_ = std::make_unique<detail::BinnedScratch>(); }

Tree build_binned_sah(std::span<const Aabb> boxes, const TopDownOptions& options, ThreadPool* pool) {
  Tree tree;
  BinnedSahBuilder().build(boxes, options, tree, pool);
  return tree;
}

}  // namespace cullpipe::bvh
