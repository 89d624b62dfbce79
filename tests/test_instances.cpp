// Instances: world volumes placed in float enclose the local volumes as transformed exactly, and
// the instance set keeps ids, slots and changes straight, refusing bad input without a trace.
#include <gtest/gtest.h>

#include <cmath>
#include <glm/ext/matrix_clip_space.hpp>
#include <glm/ext/matrix_transform.hpp>
#include <glm/gtc/quaternion.hpp>
#include <random>
#include <stdexcept>

#include "cullpipe/cull/cpu_culler.hpp"
#include "cullpipe/cull/instances.hpp"
#include "cullpipe/cull/reference.hpp"
#include "cullpipe/geom/instance.hpp"
#include "cullpipe/geom/validate.hpp"

namespace cullpipe {
namespace {

float uniform(std::mt19937& rng, float lo, float hi) { return std::uniform_real_distribution<float>(lo, hi)(rng); }

// Rotations, scales of many sizes (non-uniform, mirrored, zero), shears and translations that
// cancel the mesh's offset (where a float sum loses the most).
Transform3x4 random_transform(std::mt19937& rng, const glm::vec3& cancel) {
  const glm::quat q =
      glm::normalize(glm::quat(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
  glm::mat4 m = glm::mat4_cast(q);
  const int kind = static_cast<int>(rng() % 4);
  glm::vec3 scale(std::exp2(uniform(rng, -20, 20)));
  if (kind >= 1) scale *= glm::vec3(uniform(rng, -3, 3), uniform(rng, -3, 3), uniform(rng, -3, 3));
  if (kind == 3) scale.y = 0.0f;  // flattened
  m = m * glm::scale(glm::mat4(1.0f), scale);
  if (kind == 2) m[1][0] += uniform(rng, -2, 2) * scale.x;  // shear
  glm::vec3 t(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1));
  t *= std::exp2(uniform(rng, -30, 30));
  if (rng() % 2) t -= glm::vec3(m * glm::vec4(cancel, 0.0f));  // brings the mesh back near the origin
  m[3] = glm::vec4(t, 1.0f);
  return Transform3x4::from_mat4(m);
}

Aabb random_box(std::mt19937& rng) {
  const glm::vec3 centre =
      glm::vec3(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)) * std::exp2(uniform(rng, -10, 20));
  const glm::vec3 half =
      glm::vec3(uniform(rng, 0, 1), uniform(rng, 0, 1), uniform(rng, 0, 1)) * std::exp2(uniform(rng, -20, 5));
  return {centre - half, centre + half};
}

TEST(InstanceVolume, BoxEnclosesTheBoxTransformedInDouble) {
  std::mt19937 rng(5);
  double worst_room = 0.0;  // how much of the widening the rounding used, at most
  for (int i = 0; i < 200000; ++i) {
    const Aabb local = random_box(rng);
    const Transform3x4 t = random_transform(rng, local.center());
    const Aabb world = instance_volume(local, t);
    ASSERT_TRUE(is_valid(world)) << invalid_reason(world);
    // Arvo in double: each product of two floats is exact, and the sums round by about 2^-52
    // of the magnitudes, far inside the 2^-20 the float box is widened by.
    for (int a = 0; a < 3; ++a) {
      const glm::vec4& row = t.rows[static_cast<std::size_t>(a)];
      double lo = row.w, hi = row.w, magnitude = std::abs(double(row.w));
      for (int j = 0; j < 3; ++j) {
        const double p = double(row[j]) * local.min[j], q = double(row[j]) * local.max[j];
        lo += std::min(p, q);
        hi += std::max(p, q);
        magnitude += std::max(std::abs(p), std::abs(q));
      }
      const double slack = magnitude * 0x1p-45;
      ASSERT_LE(world.min[a], lo - slack) << "instance " << i << " axis " << a;
      ASSERT_GE(world.max[a], hi + slack) << "instance " << i << " axis " << a;
      // Tight: no wider than the widening and its rounding.
      ASSERT_LE(lo - world.min[a], magnitude * 0x1p-19 + 0x1p-119) << "instance " << i << " axis " << a;
      ASSERT_LE(world.max[a] - hi, magnitude * 0x1p-19 + 0x1p-119) << "instance " << i << " axis " << a;
      if (magnitude > 0)
        worst_room = std::max(worst_room, std::max(double(lo) - world.min[a], world.max[a] - hi) / magnitude);
    }
  }
  EXPECT_GT(worst_room, 0x1p-21);  // the widening is not just a formality
}

// The largest singular value of M, by power iteration on M^T M in double (from below).
double largest_singular_value(const Transform3x4& t) {
  glm::dmat3 m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m[c][r] = t.rows[static_cast<std::size_t>(r)][c];
  const glm::dmat3 g = glm::transpose(m) * m;
  glm::dvec3 v(0.6, 0.7, 0.8);
  double lambda = 0.0;
  for (int k = 0; k < 200; ++k) {
    const glm::dvec3 w = g * v;
    const double len = glm::length(w);
    if (len == 0.0) return 0.0;
    lambda = glm::dot(v, w) / glm::dot(v, v);
    v = w / len;
  }
  return std::sqrt(std::max(lambda, 0.0));
}

TEST(InstanceVolume, MaxScaleBoundsTheLargestStretchAndIsTightForRotationThenScale) {
  std::mt19937 rng(9);
  for (int i = 0; i < 20000; ++i) {
    const Transform3x4 t = random_transform(rng, glm::vec3(0.0f));
    const double sigma = largest_singular_value(t);
    ASSERT_GE(double(max_scale(t)), sigma * (1 - 1e-12)) << "transform " << i;
  }
  for (int i = 0; i < 2000; ++i) {
    const glm::quat q =
        glm::normalize(glm::quat(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
    const glm::vec3 s(uniform(rng, 0.1f, 4), uniform(rng, 0.1f, 4), uniform(rng, 0.1f, 4));
    const Transform3x4 t = Transform3x4::from_mat4(glm::mat4_cast(q) * glm::scale(glm::mat4(1.0f), s));
    EXPECT_NEAR(max_scale(t), std::max({s.x, s.y, s.z}), 1e-5 * std::max({s.x, s.y, s.z})) << "transform " << i;
  }
}

TEST(InstanceVolume, SphereEnclosesTheBallTransformedInDouble) {
  std::mt19937 rng(3);
  for (int i = 0; i < 100000; ++i) {
    const Aabb b = random_box(rng);
    const Sphere local{b.center(), glm::length(b.half_extent())};
    const Transform3x4 t = random_transform(rng, local.center);
    const Sphere world = instance_volume(local, t, max_scale(t));
    ASSERT_TRUE(is_valid(world)) << invalid_reason(world);
    // The transformed ball lies within |c' - world.center| + r sigma of world.center.
    glm::dvec3 centre;
    for (int a = 0; a < 3; ++a) {
      const glm::vec4& row = t.rows[static_cast<std::size_t>(a)];
      centre[a] =
          double(row.x) * local.center.x + double(row.y) * local.center.y + double(row.z) * local.center.z + row.w;
    }
    const double needed = glm::length(centre - glm::dvec3(world.center)) + local.radius * largest_singular_value(t);
    ASSERT_GE(double(world.radius), needed * (1 + 0x1p-40)) << "instance " << i;
  }
}

TEST(InstanceVolume, TransformFromMat4RefusesProjectiveAndNonFiniteMatrices) {
  glm::mat4 m(1.0f);
  m[2][3] = -1.0f;
  EXPECT_THROW(Transform3x4::from_mat4(m), std::invalid_argument);
  m = glm::mat4(1.0f);
  m[1][2] = NAN;
  try {
    (void)Transform3x4::from_mat4(m);
    FAIL() << "a NaN transform was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("row 2 column 1"), std::string::npos) << e.what();
  }
  const glm::mat4 affine = glm::translate(glm::rotate(glm::mat4(1.0f), 0.3f, glm::vec3(0, 1, 0)), glm::vec3(1, 2, 3));
  EXPECT_EQ(Transform3x4::from_mat4(affine).to_mat4(), affine);
}

Transform3x4 translation(float x) {
  return Transform3x4::from_mat4(glm::translate(glm::mat4(1.0f), glm::vec3(x, 0, 0)));
}

TEST(InstanceSet, IdsStayWhileSlotsMove) {
  InstanceSet<Aabb> set({Aabb{glm::vec3(-1), glm::vec3(1)}, Aabb{glm::vec3(0), glm::vec3(2)}});
  std::vector<InstanceId> ids;
  for (int i = 0; i < 5; ++i) ids.push_back(set.add(static_cast<std::uint32_t>(i % 2), translation(float(i))));
  EXPECT_EQ(set.changed_slots(), (std::vector<std::uint32_t>{0, 1, 2, 3, 4}));
  set.clear_changes();
  set.remove(ids[1]);  // slot 1 gets the last object (id 4)
  EXPECT_FALSE(set.contains(ids[1]));
  EXPECT_EQ(set.size(), 4u);
  EXPECT_EQ(set.slot(ids[4]), 1u);
  EXPECT_EQ(set.ids()[1], ids[4]);
  EXPECT_EQ(set.transforms()[1], translation(4.0f));
  EXPECT_EQ(set.changed_slots(), (std::vector<std::uint32_t>{1}));
  set.clear_changes();
  set.remove(ids[4]);  // now the last slot? no: slot 1; the object in slot 3 (id 3) moves there
  EXPECT_EQ(set.slot(ids[3]), 1u);
  const InstanceId again = set.add(1, translation(9.0f));  // reuses a freed id
  EXPECT_TRUE(again == ids[1] || again == ids[4]);
  EXPECT_EQ(set.slot(again), 3u);
  EXPECT_EQ(set.changed_slots(), (std::vector<std::uint32_t>{1, 3}));
  set.set_transform(ids[0], translation(-5.0f));
  EXPECT_EQ(set.world_volume(set.slot(ids[0])), instance_volume(set.meshes()[0], translation(-5.0f)));
  std::vector<Aabb> world(set.size());
  set.world_volumes(world);
  for (std::size_t s = 0; s < set.size(); ++s)
    EXPECT_EQ(world[s], instance_volume(set.meshes()[set.mesh_indices()[s]], set.transforms()[s]));
}

TEST(InstanceSet, BadInputIsRefusedAndChangesNothing) {
  EXPECT_THROW(InstanceSet<Aabb>({Aabb{glm::vec3(1), glm::vec3(0)}}), std::invalid_argument);
  EXPECT_THROW(InstanceSet<Sphere>({Sphere{glm::vec3(0), -1.0f}}), std::invalid_argument);
  InstanceSet<Sphere> set({Sphere{glm::vec3(0), 1.0f}});
  const InstanceId a = set.add(0, translation(1.0f));
  const InstanceId b = set.add(0, translation(2.0f));
  set.clear_changes();
  const auto expect_unchanged = [&] {
    EXPECT_EQ(set.size(), 2u);
    EXPECT_EQ(set.transforms()[0], translation(1.0f));
    EXPECT_EQ(set.transforms()[1], translation(2.0f));
    EXPECT_EQ(set.changed_count(), 0u);
  };
  const auto expect_error = [](auto&& call, const std::string& words) {
    try {
      call();
      ADD_FAILURE() << "accepted; expected an error with \"" << words << "\"";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  expect_error([&] { set.add(1, translation(0.0f)); }, "mesh index 1 is out of range");
  Transform3x4 nan = translation(0.0f);
  nan.rows[1].w = NAN;
  expect_error([&] { set.add(0, nan); }, "row 1 column 3 is NaN");
  Transform3x4 huge = translation(0.0f);
  huge.rows[0].x = 0x1p110f;
  expect_error([&] { set.add(0, huge); }, "past 2^100");
  expect_error([&] { set.set_transform(77, translation(0.0f)); }, "no instance has id 77");
  const InstanceId ids[2] = {a, b};
  const Transform3x4 moves[2] = {translation(5.0f), nan};
  expect_error([&] { set.set_transforms(ids, moves); }, "instance 1: transform row 1 column 3 is NaN");
  expect_error([&] { set.remove(5); }, "no instance has id 5");
  expect_unchanged();
}

// The fast CPU path on instances, every instruction set: its classes equal the reference's on the
// set's placed volumes after each frame's moves, adds and removes.
template <class Volume>
void cpu_frames(const std::vector<Volume>& meshes, std::uint32_t seed) {
  for (const fast::Isa isa : fast::supported_isas()) {
    SCOPED_TRACE(std::string(fast::to_string(isa)));
    std::mt19937 rng(seed);
    fast::CpuCuller culler({.threads = 2, .isa = isa, .chunk_objects = 1024});
    InstanceSet<Volume> set(meshes);
    std::vector<InstanceId> live;
    auto place = [&] {
      Transform3x4 t = random_transform(rng, glm::vec3(0.0f));
      for (auto& row : t.rows) row.w = std::fmod(row.w, 20.0f);  // within the views
      return t;
    };
    for (int i = 0; i < 5000; ++i) live.push_back(set.add(static_cast<std::uint32_t>(rng() % meshes.size()), place()));
    culler.upload(set);
    set.clear_changes();
    for (int frame = 0; frame < 6; ++frame) {
      glm::mat4 proj = glm::perspectiveRH_ZO(glm::radians(uniform(rng, 40, 90)), 1.5f, 0.5f, 40.0f);
      const glm::vec3 eye(uniform(rng, -10, 10), uniform(rng, -10, 10), uniform(rng, 10, 30));
      const Frustum view = Frustum::from_view_proj(proj * glm::lookAtRH(eye, glm::vec3(0.0f), glm::vec3(0, 1, 0)));
      const std::vector<fast::CpuViewResult> results = culler.cull(std::span<const Frustum>(&view, 1));
      std::vector<Volume> world(set.size());
      set.world_volumes(world);
      std::vector<Classification> cpu(world.size());
      reference::classify_all(std::span<const Volume>(world), view, cpu);
      for (std::size_t s = 0; s < world.size(); ++s)
        ASSERT_EQ(results[0].classes[s], cpu[s]) << "frame " << frame << ", slot " << s << " (id " << set.ids()[s]
                                                 << ", mesh " << set.mesh_indices()[s] << ")";
      for (int k = 0; k < 500; ++k) set.set_transform(live[rng() % live.size()], place());
      if (frame == 3) {
        for (int k = 0; k < 300; ++k) {
          const std::size_t r = rng() % live.size();
          set.remove(live[r]);
          live[r] = live.back();
          live.pop_back();
        }
        for (int k = 0; k < 100; ++k) live.push_back(set.add(0, place()));
      }
      culler.update(set, set.changed_slots());
      set.clear_changes();
    }
  }
}

TEST(InstanceSet, FastCpuPathAgreesWithTheReferenceOnEveryFrame) {
  cpu_frames<Aabb>(
      {Aabb{glm::vec3(-1, -2, -0.5f), glm::vec3(1, 0.5f, 0.5f)}, Aabb{glm::vec3(0), glm::vec3(0.1f, 3, 0)}}, 1);
  if (HasFatalFailure()) return;
  cpu_frames<Sphere>({Sphere{glm::vec3(0.5f, 0, 0), 1.0f}, Sphere{glm::vec3(0), 0.0f}}, 2);
  if (HasFatalFailure()) return;
  const glm::mat3 turned = glm::mat3_cast(glm::angleAxis(0.7f, glm::normalize(glm::vec3(1, 2, 3))));
  cpu_frames<Obb>({Obb{glm::vec3(0.5f, 0, 0), turned, glm::vec3(1, 0.25f, 2)},
                   Obb{glm::vec3(0), glm::mat3(1.0f), glm::vec3(0.5f, 0, 0.5f)}},
                  3);
}

// A placed OBB (on the host, in double) encloses the local box's corners as transformed in
// double, for rotations, mirrors, non-uniform scale and shear; and with rotation, uniform scale
// and translation it is the exact box: its extents the local ones scaled, to float rounding.
TEST(InstanceVolume, ObbEnclosesTheBoxTransformedInDouble) {
  std::mt19937 rng(9);
  for (int i = 0; i < 20000; ++i) {
    const glm::quat q =
        glm::normalize(glm::quat(uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1), uniform(rng, -1, 1)));
    const Obb local{glm::vec3(uniform(rng, -5, 5), uniform(rng, -5, 5), uniform(rng, -5, 5)), glm::mat3_cast(q),
                    glm::vec3(uniform(rng, 0, 3), uniform(rng, 0, 3), uniform(rng, 0, 3))};
    const Transform3x4 t = random_transform(rng, glm::vec3(0.0f));
    const Obb world = instance_volume(local, t);
    ASSERT_TRUE(is_valid(world)) << invalid_reason(world);
    for (int c = 0; c < 8; ++c) {
      // The local box's corner and its placement, in double (rounding far below a float step).
      glm::dvec3 corner(local.center);
      for (int k = 0; k < 3; ++k)
        corner += glm::dvec3(local.basis[k]) * (double(local.half_extents[k]) * ((c >> k) & 1 ? 1.0 : -1.0));
      glm::dvec3 p;
      double magnitude = 0.0;
      for (int a = 0; a < 3; ++a) {
        const glm::vec4& row = t.rows[static_cast<std::size_t>(a)];
        p[a] = double(row.x) * corner.x + double(row.y) * corner.y + double(row.z) * corner.z + double(row.w);
        magnitude += std::abs(p[a]) + std::abs(double(world.center[a]));
      }
      // In the placed box's frame: within its extents (up to double rounding of the magnitudes).
      const glm::dvec3 d = p - glm::dvec3(world.center);
      for (int k = 0; k < 3; ++k)
        ASSERT_LE(std::abs(glm::dot(d, glm::dvec3(world.basis[k]))),
                  double(world.half_extents[k]) + magnitude * 0x1p-44)
            << "instance " << i << ", corner " << c << ", axis " << k;
    }
  }
  // Rotation, uniform scale, translation: the local extents times the scale.
  const Obb local{glm::vec3(1, 2, 3), glm::mat3(1.0f), glm::vec3(1, 2, 0.5f)};
  const glm::mat4 m = glm::translate(glm::mat4(1.0f), glm::vec3(10, -4, 2)) *
                      glm::mat4_cast(glm::angleAxis(1.1f, glm::normalize(glm::vec3(0, 1, 1)))) *
                      glm::scale(glm::mat4(1.0f), glm::vec3(2.0f));
  const Obb world = instance_volume(local, Transform3x4::from_mat4(m));
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(world.half_extents[k], 2.0f * local.half_extents[k], 1e-5f) << k;
}

TEST(InstanceSet, FastCpuPathRefusesBadUpdates) {
  fast::CpuCuller culler({.threads = 1});
  InstanceSet<Aabb> set({Aabb{glm::vec3(-1), glm::vec3(1)}});
  for (int i = 0; i < 10; ++i) set.add(0, translation(float(i)));
  const std::uint32_t slots[2] = {4, 2};
  EXPECT_THROW(culler.update(set, std::span<const std::uint32_t>(slots, 1)),
               std::invalid_argument);  // nothing uploaded
  culler.upload(set);
  EXPECT_THROW(culler.update(set, slots), std::invalid_argument);  // descending
  const std::uint32_t past[1] = {10};
  EXPECT_THROW(culler.update(set, past), std::invalid_argument);
  EXPECT_EQ(culler.object_count(), 10u);
}

}  // namespace
}  // namespace cullpipe
