#pragma once
// A scene of instances: each distinct mesh's local volume once, and per object a mesh index and
// a transform, with ids that stay the same while objects come and go. An engine changes a few
// transforms a frame; the set keeps which slots changed, so the GPU receives only those
// (gpu::GpuCuller::upload(InstanceSet), gpu::GpuCuller::update) and transforms only those.
#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "cullpipe/geom/aabb.hpp"
#include "cullpipe/geom/instance.hpp"
#include "cullpipe/geom/obb.hpp"
#include "cullpipe/geom/sphere.hpp"

namespace cullpipe {

class ThreadPool;

/// A stable name for an instance: given by add(), valid until remove(); a removed id may be
/// given again by a later add().
using InstanceId = std::uint32_t;

/// Instances of one volume kind (Aabb, Obb or Sphere). Objects are kept densely in slots 0..size()-1,
/// the order culling reports them in; removing one moves the last object into its slot, so a
/// slot's object can change while its id does not (ids() maps slots to ids, slot() back).
/// Every method that takes outside input checks all of it first and throws
/// std::invalid_argument naming the object and what is wrong, leaving the set as it was.
template <class Volume>
class InstanceSet {
 public:
  /// The meshes' local volumes, indexed by the mesh index of add(); each must be valid
  /// (invalid_reason) and within 2^100 of the origin.
  explicit InstanceSet(std::vector<Volume> meshes);

  /// Adds an object of mesh `mesh` placed by `transform`; its slot is size() - 1. Throws when
  /// the mesh index is out of range, a transform value is not finite, or the placed volume
  /// could reach past 2^100 (where plane distances could overflow).
  InstanceId add(std::uint32_t mesh, const Transform3x4& transform);
  /// Moves object `id`. Throws when no object has that id, or as add() does.
  void set_transform(InstanceId id, const Transform3x4& transform);
  /// Moves several objects at once: all of them, or (on a bad id or transform) none.
  void set_transforms(std::span<const InstanceId> ids, std::span<const Transform3x4> transforms);
  /// Removes object `id`: the last object moves into its slot. Throws when no object has it.
  void remove(InstanceId id);

  bool contains(InstanceId id) const { return id < slot_of_.size() && slot_of_[id] != kNoSlot; }
  /// The slot of object `id`; throws std::invalid_argument when no object has it.
  std::uint32_t slot(InstanceId id) const;
  std::size_t size() const { return ids_.size(); }
  std::span<const Volume> meshes() const { return meshes_; }
  std::span<const InstanceId> ids() const { return ids_; }                    ///< per slot
  std::span<const std::uint32_t> mesh_indices() const { return meshes_of_; }  ///< per slot
  std::span<const Transform3x4> transforms() const { return transforms_; }    ///< per slot
  /// Per slot, max_scale of its transform (what a sphere's radius is scaled by).
  std::span<const float> scales() const { return scales_; }

  /// Slot `slot`'s world volume: instance_volume of its mesh's local volume and transform.
  Volume world_volume(std::size_t slot) const;
  /// Every slot's world volume, into out (out.size() == size()), on `pool`'s threads if given.
  void world_volumes(std::span<Volume> out, ThreadPool* pool = nullptr) const;

  /// The slots written since the last clear_changes() (added, moved, or filled by a removal),
  /// ascending, each once; slots at or past size() are dropped.
  std::vector<std::uint32_t> changed_slots() const;
  /// Throws std::invalid_argument, naming `who` (the caller's method), unless `slots` are
  /// ascending slots of this set: what the cullers' update() takes.
  void check_slots(std::span<const std::uint32_t> slots, const char* who) const;
  std::size_t changed_count() const { return changed_.size(); }
  void clear_changes();

 private:
  static constexpr std::uint32_t kNoSlot = 0xffffffffu;
  void check_placement(std::size_t object, std::uint32_t mesh, const Transform3x4& transform) const;
  void mark(std::uint32_t slot);

  std::vector<Volume> meshes_;
  std::vector<double> mesh_reach_;  // per mesh: how far its volume reaches from the origin, per axis at most
  std::vector<InstanceId> ids_;
  std::vector<std::uint32_t> meshes_of_;
  std::vector<Transform3x4> transforms_;
  std::vector<float> scales_;
  std::vector<std::uint32_t> slot_of_;    // per id; kNoSlot when free
  std::vector<InstanceId> free_ids_;      // ids given back by remove(), reused last first
  std::vector<std::uint32_t> changed_;    // slots written since clear_changes(), unordered
  std::vector<std::uint8_t> is_changed_;  // per slot
};

extern template class InstanceSet<Aabb>;
extern template class InstanceSet<Obb>;
extern template class InstanceSet<Sphere>;

}  // namespace cullpipe
