#pragma once
// Shared by the BVH test executables: the check that hierarchical culling over a tree gives
// every object exactly the flat reference's class.
#include <gtest/gtest.h>

#include <span>
#include <vector>

#include "bvh/bvh.hpp"
#include "cull/reference.hpp"

namespace cullpipe::test {

/// In every view, the scalar hierarchical cull over `flat` classifies every object as the flat
/// CPU reference does, with the same visible and inside counts and no more object tests than
/// objects. Volume: Aabb, Obb or Sphere (for the last two the tree is over their enclosing
/// boxes).
template <class Volume>
void expect_hierarchy_equals_flat(const bvh::FlatTree& flat, std::span<const Volume> volumes, const std::vector<Frustum>& frusta) {
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    std::vector<Classification> cpu(volumes.size());
    const reference::CullCounts counts = reference::classify_all(volumes, frusta[v], cpu);
    const bvh::HierarchicalResult h = bvh::cull_hierarchical(flat, volumes, frusta[v]);
    ASSERT_EQ(h.classes.size(), cpu.size()) << "view " << v;
    for (std::size_t i = 0; i < cpu.size(); ++i)
      ASSERT_EQ(h.classes[i], cpu[i]) << "view " << v << ", object " << i << ": hierarchical " << to_string(h.classes[i]) << ", flat "
                                      << to_string(cpu[i]);
    EXPECT_EQ(h.visible, counts.visible);
    EXPECT_EQ(h.inside, counts.inside);
    EXPECT_LE(h.object_tests, volumes.size());
  }
}
template <class Volume>
void expect_hierarchy_equals_flat(const bvh::FlatTree& flat, const std::vector<Volume>& volumes, const std::vector<Frustum>& frusta) {
  expect_hierarchy_equals_flat(flat, std::span<const Volume>(volumes), frusta);
}

}  // namespace cullpipe::test
