#include "common/sim/surface_tracker.h"

#include <algorithm>

#include "common/core/error.h"
#include "common/mesh/surface.h"
#include "common/sim/scene_fem.h"

namespace cutsim::sim {

template <typename T>
void SurfaceTracker::Rebuild(const fem::Model<T>& model, const T* x, cutting::CutMesh* cut, bool with_tool) {
  node_capacity_ = model.node_capacity();
  if (cut != nullptr) {
    cut->set_track_slot_changes(with_tool);
    RebuildFromCut(*cut);
  } else {
    mesh::Surface surf = mesh::ExtractSurface(TetsMatrix(model));
    surface_ = std::move(surf.tris);
    surface_tet_ = std::move(surf.tet);
    num_slots_ = static_cast<int32_t>(surface_.rows());
    opened_.assign(static_cast<size_t>(surface_.rows()), 0);
  }
  CUTSIM_CHECK(surface_tet_.size() == static_cast<size_t>(surface_.rows()), "surface/tet map size");
  if (!with_tool) return;  // contact structures only serve the tool
  FlagDebris(model, cut);
  CopyWorld(model, x);
  bvh_ = mesh::TriangleBvh(world_, surface_);
}

void SurfaceTracker::RebuildFromCut(cutting::CutMesh& cut) {
  const auto& slots = cut.surface_slots();
  num_slots_ = static_cast<int32_t>(slots.size());
  // Room for as many slots again: cuts add slots, and growing inside a cut
  // step copies and clears every per-slot array here and in the BVH (built
  // over these rows, dead ones included), a cost the first cut steps on a
  // large mesh would pay. Beyond that the arrays double.
  surface_.resize(std::max<int32_t>(2 * num_slots_, 16), 3);
  surface_.setConstant(-1);
  opened_.assign(static_cast<size_t>(surface_.rows()), 0);
  surface_tet_.assign(static_cast<size_t>(surface_.rows()), -1);
  wall_node_.assign(static_cast<size_t>(node_capacity_), 0);
  for (int32_t f = 0; f < num_slots_; ++f) {
    const cutting::SurfaceFace& face = slots[static_cast<size_t>(f)];
    if (!face.alive) continue;
    const std::array<int32_t, 3> tri = cut.SurfaceTriangle(f);
    surface_.row(f) << tri[0], tri[1], tri[2];
    opened_[static_cast<size_t>(f)] = face.opened ? 1 : 0;
    surface_tet_[static_cast<size_t>(f)] = face.tet;
    if (face.opened) FlagWallNodes(tri);
  }
  std::vector<int32_t> drained;
  cut.TakeChangedSlots(drained);  // all covered above
}

template <typename T>
void SurfaceTracker::RefreshWorld(const fem::Model<T>& model, const T* x) {
  CopyWorld(model, x);
  bvh_.Refit(world_, model.num_nodes());
}

/// world_ holds node_capacity rows (allocated once), the first num_nodes()
/// of them current.
template <typename T>
void SurfaceTracker::CopyWorld(const fem::Model<T>& model, const T* x) {
  const int32_t N = model.num_nodes();
  if (world_.rows() < model.node_capacity()) world_.resize(model.node_capacity(), 3);
  for (int32_t i = 0; i < N; ++i) {
    for (int k = 0; k < 3; ++k) {
      world_(i, k) = static_cast<double>(x[3 * static_cast<size_t>(i) + static_cast<size_t>(k)]);
    }
  }
}

/// Marks the nodes of a face a cut opened (tool_contact.h: walls and lips
/// of a cut). A node stays on a cut once it is: cuts never close.
void SurfaceTracker::FlagWallNodes(const std::array<int32_t, 3>& tri) {
  if (wall_node_.size() < static_cast<size_t>(node_capacity_)) {
    wall_node_.resize(static_cast<size_t>(node_capacity_), 0);
  }
  for (const int32_t v : tri) wall_node_[static_cast<size_t>(v)] = 1;
}

/// Facets the blade does not touch: those of debris (debris.h), over the
/// whole mesh (set-up, restore); UpdateAfterCut and FlagDebrisFacets keep
/// them after each cut.
template <typename T>
void SurfaceTracker::FlagDebris(const fem::Model<T>& model, const cutting::CutMesh* cut) {
  debris_facet_.clear();
  debris_.reset();
  if (cut == nullptr) return;
  const int32_t num_tets = model.num_tets();
  std::vector<double> element_mass(static_cast<size_t>(num_tets));
  for (int32_t t = 0; t < num_tets; ++t) element_mass[static_cast<size_t>(t)] = static_cast<double>(model.element_mass(t));
  debris_.emplace(std::move(element_mass), model.TotalMass(),
                  DebrisTracker::Limits{.mass_fraction = kDebrisMassFraction, .max_tets = kDebrisMaxTets});
  debris_->Reset(*cut);
  debris_facet_.assign(static_cast<size_t>(surface_.rows()), 0);
  for (int32_t f = 0; f < num_slots_; ++f) {
    const int32_t t = surface_tet_[static_cast<size_t>(f)];
    if (t >= 0) debris_facet_[static_cast<size_t>(f)] = debris_->is_debris(t) ? 1 : 0;
  }
}

void SurfaceTracker::UpdateAfterCut(cutting::CutMesh& cut, std::span<const cutting::Split> splits) {
  // The copies this cut made are the last splits.size() nodes, in order.
  const int32_t first_copy = cut.num_nodes() - static_cast<int32_t>(splits.size());
  for (size_t i = 0; i < splits.size(); ++i) {
    CUTSIM_CHECK(splits[i].new_node == first_copy + static_cast<int32_t>(i), "split copies out of order");
    world_.row(splits[i].new_node) = world_.row(splits[i].node);
  }
  cut.TakeChangedSlots(changed_slots_);
  std::sort(changed_slots_.begin(), changed_slots_.end());
  changed_slots_.erase(std::unique(changed_slots_.begin(), changed_slots_.end()), changed_slots_.end());
  num_slots_ = static_cast<int32_t>(cut.surface_slots().size());
  if (num_slots_ > surface_.rows()) GrowSlots();
  for (const int32_t f : changed_slots_) UpdateSlot(cut, f);
  flagged_.clear();
  if (debris_) debris_->Update(cut, splits, &flagged_);
}

/// Room for num_slots_ slots, by doubling: amortised O(1) per slot.
void SurfaceTracker::GrowSlots() {
  const auto old_rows = static_cast<int32_t>(surface_.rows());
  const int32_t rows = std::max(num_slots_, 2 * old_rows);
  surface_.conservativeResize(rows, 3);
  surface_.bottomRows(rows - old_rows).setConstant(-1);
  opened_.resize(static_cast<size_t>(rows), 0);
  surface_tet_.resize(static_cast<size_t>(rows), -1);
  if (debris_) debris_facet_.resize(static_cast<size_t>(rows), 0);
}

/// Slot `f` as the cut complex has it now: freed (out of the BVH) or
/// created (into it: a local insert, amortised O(log F); the tree is
/// rebuilt only after as many inserts as half its faces, bvh.h).
void SurfaceTracker::UpdateSlot(const cutting::CutMesh& cut, int32_t f) {
  const cutting::SurfaceFace& face = cut.surface_slots()[static_cast<size_t>(f)];
  const auto i = static_cast<size_t>(f);
  if (!face.alive) {
    surface_.row(f).setConstant(-1);
    opened_[i] = 0;
    surface_tet_[i] = -1;
    if (!debris_facet_.empty()) debris_facet_[i] = 0;
    bvh_.Remove(f);
    return;
  }
  const std::array<int32_t, 3> tri = cut.SurfaceTriangle(f);
  surface_.row(f) << tri[0], tri[1], tri[2];
  opened_[i] = face.opened ? 1 : 0;
  surface_tet_[i] = face.tet;
  if (face.opened) FlagWallNodes(tri);
  bvh_.Insert(f, tri, world_);
}

void SurfaceTracker::FlagDebrisFacets(const cutting::CutMesh& cut) {
  if (!debris_) return;
  const auto& slots = cut.surface_slots();
  for (const int32_t f : changed_slots_) {
    const cutting::SurfaceFace& face = slots[static_cast<size_t>(f)];
    debris_facet_[static_cast<size_t>(f)] = face.alive && debris_->is_debris(face.tet) ? 1 : 0;
  }
  for (const int32_t t : flagged_) {
    for (int f = 0; f < 4; ++f) {
      const int32_t slot = cut.SurfaceSlot(t, f);
      if (slot >= 0) debris_facet_[static_cast<size_t>(slot)] = 1;
    }
  }
}

int32_t SurfaceTracker::SlotTet(int32_t tri) const {
  if (tri < 0 || static_cast<size_t>(tri) >= surface_tet_.size()) return -1;
  return surface_tet_[static_cast<size_t>(tri)];
}

int SurfaceTracker::OpenedFaces() const {
  return static_cast<int>(std::count(opened_.begin(), opened_.begin() + num_slots_, uint8_t{1}));
}

void SurfaceTracker::FillView(MeshView& view) const {
  // Dead slots (rows of −1) are left out: viewers get the live triangles.
  int32_t live = 0;
  for (int32_t f = 0; f < num_slots_; ++f) live += surface_(f, 0) >= 0 ? 1 : 0;
  view.surface.resize(live, 3);
  view.opened.resize(static_cast<size_t>(live));
  view.debris.resize(debris_facet_.empty() ? 0 : static_cast<size_t>(live));
  int32_t row = 0;
  for (int32_t f = 0; f < num_slots_; ++f) {
    if (surface_(f, 0) < 0) continue;
    view.surface.row(row) = surface_.row(f);
    if (!view.debris.empty()) view.debris[static_cast<size_t>(row)] = debris_facet_[static_cast<size_t>(f)];
    view.opened[static_cast<size_t>(row++)] = opened_[static_cast<size_t>(f)];
  }
}

#define CUTSIM_SIM_SURFACE_INSTANTIATE(T)                                                                \
  template void SurfaceTracker::Rebuild<T>(const fem::Model<T>&, const T*, cutting::CutMesh*, bool);     \
  template void SurfaceTracker::RefreshWorld<T>(const fem::Model<T>&, const T*);

CUTSIM_SIM_SURFACE_INSTANTIATE(float)
CUTSIM_SIM_SURFACE_INSTANTIATE(double)

}  // namespace cutsim::sim
