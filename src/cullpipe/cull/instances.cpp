#include "cullpipe/cull/instances.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "cullpipe/core/thread_pool.hpp"
#include "cullpipe/geom/plane_bounds.hpp"
#include "cullpipe/geom/validate.hpp"

namespace cullpipe {

namespace {

// Placed volumes stay within this of the origin, so that a plane distance (|n| = 1, |d| up to
// 2^120 as the settling margin allows) can neither overflow nor lose the volume's extent.
constexpr double kReachLimit = 0x1p100;

double reach(const Aabb& b) {
  double r = 0.0;
  for (int i = 0; i < 3; ++i) r = std::max({r, std::abs(double(b.min[i])), std::abs(double(b.max[i]))});
  return r;
}
double reach(const Obb& b) {  // the centre's largest coordinate plus the box's diagonal
  double r = 0.0, diagonal = 0.0;
  for (int i = 0; i < 3; ++i) {
    r = std::max(r, std::abs(double(b.center[i])));
    diagonal += std::abs(double(b.half_extents[i])) * glm::length(glm::dvec3(b.basis[i]));
  }
  return r + diagonal;
}
double reach(const Sphere& s) {
  double r = 0.0;
  for (int i = 0; i < 3; ++i) r = std::max(r, std::abs(double(s.center[i])));
  return r + s.radius;
}

// Room for one more element, growing geometrically (reserve(size + 1) would reallocate on every
// call): allocations happen here, before a method changes anything.
template <class T>
void room_for_one(std::vector<T>& v) {
  if (v.size() == v.capacity()) v.reserve(std::max<std::size_t>(16, v.capacity() * 2));
}

std::string object_name(std::size_t object) { return "instance " + std::to_string(object); }

}  // namespace

template <class Volume>
InstanceSet<Volume>::InstanceSet(std::vector<Volume> meshes) : meshes_(std::move(meshes)) {
  mesh_reach_.reserve(meshes_.size());
  for (std::size_t m = 0; m < meshes_.size(); ++m) {
    if (const std::string why = invalid_reason(meshes_[m]); !why.empty())
      throw std::invalid_argument("mesh " + std::to_string(m) + ": " + why);
    const double r = reach(meshes_[m]);
    if (!(r <= kReachLimit))
      throw std::invalid_argument("mesh " + std::to_string(m) + ": reaches " + std::to_string(r) +
                                  " from the origin, past 2^100");
    mesh_reach_.push_back(r);
  }
}

template <class Volume>
void InstanceSet<Volume>::check_placement(std::size_t object, std::uint32_t mesh, const Transform3x4& t) const {
  if (mesh >= meshes_.size())
    throw std::invalid_argument(object_name(object) + ": mesh index " + std::to_string(mesh) + " is out of range (" +
                                std::to_string(meshes_.size()) + " meshes)");
  if (const std::string why = invalid_reason(t); !why.empty())
    throw std::invalid_argument(object_name(object) + ": transform " + why);
  // Every placed point p' has |p'_i| <= sum_j |m_ij| reach + |t_i|.
  for (int i = 0; i < 3; ++i) {
    const glm::vec4& row = t.rows[static_cast<std::size_t>(i)];
    const double bound =
        (std::abs(double(row.x)) + std::abs(double(row.y)) + std::abs(double(row.z))) * mesh_reach_[mesh] +
        std::abs(double(row.w));
    if (!(bound <= kReachLimit))
      throw std::invalid_argument(object_name(object) + ": placed by this transform, mesh " + std::to_string(mesh) +
                                  " could reach " + std::to_string(bound) + " along axis " + std::to_string(i) +
                                  ", past 2^100");
  }
}

template <class Volume>
void InstanceSet<Volume>::mark(std::uint32_t slot) {
  if (!is_changed_[slot]) {
    is_changed_[slot] = 1;
    changed_.push_back(slot);
  }
}

template <class Volume>
InstanceId InstanceSet<Volume>::add(std::uint32_t mesh, const Transform3x4& transform) {
  if (ids_.size() >= kNoSlot) throw std::length_error("InstanceSet: more than 2^32 - 2 objects");
  const InstanceId id = free_ids_.empty() ? static_cast<InstanceId>(slot_of_.size()) : free_ids_.back();
  check_placement(id, mesh, transform);
  const float scale = max_scale(transform);
  // Every allocation first, so a failure leaves the set as it was.
  room_for_one(ids_);
  room_for_one(meshes_of_);
  room_for_one(transforms_);
  room_for_one(scales_);
  room_for_one(changed_);
  room_for_one(slot_of_);
  if (is_changed_.size() <= ids_.size()) {
    room_for_one(is_changed_);
    is_changed_.push_back(0);
  }

  const auto slot = static_cast<std::uint32_t>(ids_.size());
  ids_.push_back(id);
  meshes_of_.push_back(mesh);
  transforms_.push_back(transform);
  scales_.push_back(scale);
  if (id == slot_of_.size())
    slot_of_.push_back(slot);
  else {
    slot_of_[id] = slot;
    free_ids_.pop_back();
  }
  mark(slot);
  return id;
}

template <class Volume>
std::uint32_t InstanceSet<Volume>::slot(InstanceId id) const {
  if (!contains(id)) throw std::invalid_argument("no instance has id " + std::to_string(id));
  return slot_of_[id];
}

template <class Volume>
void InstanceSet<Volume>::set_transform(InstanceId id, const Transform3x4& transform) {
  set_transforms({&id, 1}, {&transform, 1});
}

template <class Volume>
void InstanceSet<Volume>::set_transforms(std::span<const InstanceId> ids, std::span<const Transform3x4> transforms) {
  if (ids.size() != transforms.size())
    throw std::invalid_argument("set_transforms: " + std::to_string(ids.size()) + " ids but " +
                                std::to_string(transforms.size()) + " transforms");
  for (std::size_t k = 0; k < ids.size(); ++k) check_placement(ids[k], meshes_of_[slot(ids[k])], transforms[k]);
  if (changed_.capacity() < changed_.size() + ids.size())
    changed_.reserve(std::max(changed_.size() + ids.size(), changed_.capacity() * 2));
  for (std::size_t k = 0; k < ids.size(); ++k) {
    const std::uint32_t s = slot_of_[ids[k]];
    transforms_[s] = transforms[k];
    scales_[s] = max_scale(transforms[k]);
    mark(s);
  }
}

template <class Volume>
void InstanceSet<Volume>::remove(InstanceId id) {
  const std::uint32_t s = slot(id);
  room_for_one(free_ids_);
  room_for_one(changed_);
  const auto last = static_cast<std::uint32_t>(ids_.size() - 1);
  if (s != last) {
    ids_[s] = ids_[last];
    meshes_of_[s] = meshes_of_[last];
    transforms_[s] = transforms_[last];
    scales_[s] = scales_[last];
    slot_of_[ids_[s]] = s;
    mark(s);
  }
  ids_.pop_back();
  meshes_of_.pop_back();
  transforms_.pop_back();
  scales_.pop_back();
  slot_of_[id] = kNoSlot;
  free_ids_.push_back(id);
}

template <class Volume>
Volume InstanceSet<Volume>::world_volume(std::size_t s) const {
  if constexpr (std::is_same_v<Volume, Sphere>)
    return instance_volume(meshes_[meshes_of_[s]], transforms_[s], scales_[s]);
  else
    return instance_volume(meshes_[meshes_of_[s]], transforms_[s]);
}

template <class Volume>
void InstanceSet<Volume>::world_volumes(std::span<Volume> out, ThreadPool* pool) const {
  if (out.size() != size())
    throw std::invalid_argument("world_volumes: room for " + std::to_string(out.size()) + " volumes, " +
                                std::to_string(size()) + " objects");
  constexpr std::size_t kChunk = 16384;
  const std::size_t chunks = (size() + kChunk - 1) / kChunk;
  auto run = [&](std::size_t c) {
    // The GPU's rounding: to nearest, subnormals kept (the caller's thread may flush them).
    const plane_bounds::NearestNoFlush mode;
    const std::size_t end = std::min(size(), (c + 1) * kChunk);
    for (std::size_t s = c * kChunk; s < end; ++s) out[s] = world_volume(s);
  };
  if (pool && chunks > 1)
    pool->parallel_for(chunks, run);
  else
    for (std::size_t c = 0; c < chunks; ++c) run(c);
}

template <class Volume>
std::vector<std::uint32_t> InstanceSet<Volume>::changed_slots() const {
  std::vector<std::uint32_t> slots;
  slots.reserve(changed_.size());
  for (const std::uint32_t s : changed_)
    if (s < size()) slots.push_back(s);
  std::sort(slots.begin(), slots.end());
  return slots;
}

template <class Volume>
void InstanceSet<Volume>::check_slots(std::span<const std::uint32_t> slots, const char* who) const {
  for (std::size_t k = 0; k < slots.size(); ++k) {
    if (slots[k] >= size())
      throw std::invalid_argument(std::string(who) + ": slot " + std::to_string(slots[k]) + " is out of range (" +
                                  std::to_string(size()) + " objects)");
    if (k > 0 && slots[k] <= slots[k - 1])
      throw std::invalid_argument(std::string(who) + ": slots are not ascending (slot " + std::to_string(slots[k]) +
                                  " after " + std::to_string(slots[k - 1]) + ")");
  }
}

template <class Volume>
void InstanceSet<Volume>::clear_changes() {
  for (const std::uint32_t s : changed_) is_changed_[s] = 0;
  changed_.clear();
}

template class InstanceSet<Aabb>;
template class InstanceSet<Obb>;
template class InstanceSet<Sphere>;

}  // namespace cullpipe
