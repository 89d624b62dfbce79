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
/// objects.
inline void expect_hierarchy_equals_flat(const bvh::FlatTree& flat, std::span<const Aabb> boxes, const std::vector<Frustum>& frusta) {
  for (std::size_t v = 0; v < frusta.size(); ++v) {
    std::vector<Classification> cpu(boxes.size());
    const reference::CullCounts counts = reference::classify_all(boxes, frusta[v], cpu);
    const bvh::HierarchicalResult h = bvh::cull_hierarchical(flat, boxes, frusta[v]);
    ASSERT_EQ(h.classes, cpu) << "view " << v;
    EXPECT_EQ(h.visible, counts.visible);
    EXPECT_EQ(h.inside, counts.inside);
    EXPECT_LE(h.object_tests, boxes.size());
  }
}

}  // namespace cullpipe::test
