#include "common/cutting/cut_mesh.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <unordered_map>

#include "common/core/disjoint_sets.h"
#include "common/core/error.h"
#include "common/mesh/face_key.h"
#include "common/mesh/surface.h"

namespace cutsim::cutting {

int32_t CutMesh::FindFaceMate(int32_t t, int f) const {
  const auto& n = recs_[Idx(t)].nodes;
  const auto& lf = mesh::internal::kTetFaces[Idx(f)];
  int32_t a = n[Idx(lf[0])], b = n[Idx(lf[1])], c = n[Idx(lf[2])];
  // Search the smallest of the three stars (a just-made copy's, often): a
  // face has at most two tets, so every star finds the same mate.
  if (star_block_[Idx(b)].size < star_block_[Idx(a)].size) std::swap(a, b);
  if (star_block_[Idx(c)].size < star_block_[Idx(a)].size) std::swap(a, c);
  for (const int32_t u : node_tets(a)) {
    if (u == t) continue;
    const auto& m = recs_[Idx(u)].nodes;
    const bool has_b = m[0] == b || m[1] == b || m[2] == b || m[3] == b;
    const bool has_c = m[0] == c || m[1] == c || m[2] == c || m[3] == c;
    if (has_b && has_c) return u;
  }
  return -1;
}

int CutMesh::MatchingFace(int32_t u, int32_t t, int f) const {
  // The corner of u that is not on the face (the face's nodes are t's other corners).
  const auto& n = recs_[Idx(t)].nodes;
  const auto& m = recs_[Idx(u)].nodes;
  for (int k = 0; k < 4; ++k) {
    bool on_face = false;
    for (int c = 0; c < 4; ++c)
      if (c != f && n[Idx(c)] == m[Idx(k)]) on_face = true;
    if (!on_face) return k;
  }
  CUTSIM_CHECK(false, "face is not a face of the tet");
}

CutMesh::CutMesh(const mesh::TetMesh& mesh, int32_t node_capacity) {
  const int32_t n = mesh.num_nodes();
  const int32_t cap = std::max(n, node_capacity > 0 ? node_capacity : 2 * n);
  rest_.reserve(Idx(cap));
  star_block_.reserve(Idx(cap));
  origin_.reserve(Idx(cap));
  for (int32_t i = 0; i < n; ++i) {
    rest_.emplace_back(mesh.nodes.row(i).transpose());
    origin_.push_back(i);
  }
  star_block_.resize(Idx(n));
  recs_.resize(Idx(mesh.num_tets()));
  for (int32_t t = 0; t < mesh.num_tets(); ++t) {
    for (int c = 0; c < 4; ++c) {
      const int32_t v = mesh.tets(t, c);
      CUTSIM_CHECK(v >= 0 && v < n, "tet node out of range (validate the mesh first)");
      recs_[Idx(t)].nodes[Idx(c)] = v;
      ++star_block_[Idx(v)].capacity;
    }
  }
  // Blocks in node order, each as large as the node's uncut star (a node
  // only loses tets to its copies; a rollback gives them back).
  int32_t offset = 0;
  for (StarBlock& b : star_block_) {
    b.begin = offset;
    offset += b.capacity;
  }
  star_pool_.reserve(Idx(offset) + Idx(offset) / 4);
  star_pool_.resize(Idx(offset));
  for (int32_t t = 0; t < num_tets(); ++t) {
    for (const int32_t v : recs_[Idx(t)].nodes) {
      StarBlock& b = star_block_[Idx(v)];
      star_pool_[Idx(b.begin + b.size++)] = t;  // ascending since t ascends
    }
  }
  copies_.resize(Idx(n));
  BuildFaces();
  tet_marks_.rows.resize(recs_.size());
  star_connected0_.resize(Idx(n));
  for (int32_t v = 0; v < n; ++v) star_connected0_[Idx(v)] = StarIsOneGroup(v) ? 1 : 0;
}

void CutMesh::BuildFaces() {
  // Pair tets through a hash of sorted face keys (construction only), then
  // assign surface slots in tet order (deterministic, like
  // mesh::ExtractSurface).
  for (TetRecord& r : recs_) r.neighbour = {-1, -1, -1, -1};
  slot_.assign(recs_.size(), {-1, -1, -1, -1});
  {
    std::unordered_map<mesh::internal::FaceKey, std::pair<int32_t, int>, mesh::internal::FaceKeyHash> first;  // key → (tet, face)
    first.reserve(recs_.size() * 3);
    for (int32_t t = 0; t < num_tets(); ++t) {
      for (int f = 0; f < 4; ++f) {
        const auto lf = mesh::LocalTetFace(f);
        const auto& tn = recs_[Idx(t)].nodes;
        std::array<int32_t, 3> k{tn[Idx(lf[0])], tn[Idx(lf[1])], tn[Idx(lf[2])]};
        std::sort(k.begin(), k.end());
        const auto [it, inserted] = first.try_emplace(k, t, f);
        if (inserted) continue;
        const auto [u, fu] = it->second;
        CUTSIM_CHECK(u >= 0, "face shared by more than two tets");
        recs_[Idx(t)].neighbour[Idx(f)] = u;
        recs_[Idx(u)].neighbour[Idx(fu)] = t;
        it->second.first = -1;
      }
    }
  }
  for (int32_t t = 0; t < num_tets(); ++t) {
    for (int f = 0; f < 4; ++f) {
      if (recs_[Idx(t)].neighbour[Idx(f)] < 0) slot_[Idx(t)][Idx(f)] = NewSlot(t, f, false);
    }
  }
}

std::array<int32_t, 2> CutMesh::FaceTets(int32_t a, int32_t b, int32_t c) const {
  std::array<int32_t, 2> out{-1, -1};
  if (a < 0 || a >= num_nodes()) return out;
  int k = 0;
  for (const int32_t u : node_tets(a)) {
    const auto& m = recs_[Idx(u)].nodes;
    const bool has_b = m[0] == b || m[1] == b || m[2] == b || m[3] == b;
    const bool has_c = m[0] == c || m[1] == c || m[2] == c || m[3] == c;
    if (has_b && has_c && k < 2) out[Idx(k++)] = u;
  }
  return out;
}

mesh::Tets CutMesh::TetsMatrix() const {
  mesh::Tets T(num_tets(), 4);
  for (int32_t t = 0; t < num_tets(); ++t)
    for (int c = 0; c < 4; ++c) T(t, c) = recs_[Idx(t)].nodes[Idx(c)];
  return T;
}

mesh::TetMesh CutMesh::RestMesh() const {
  mesh::TetMesh m;
  m.nodes.resize(num_nodes(), 3);
  for (int32_t i = 0; i < num_nodes(); ++i) m.nodes.row(i) = rest_[Idx(i)].transpose();
  m.tets = TetsMatrix();
  return m;
}

mesh::Triangles CutMesh::SurfaceTriangles(std::vector<uint8_t>* opened) const {
  mesh::Triangles tris(num_surface_, 3);
  if (opened) opened->clear();
  int32_t row = 0;
  for (const SurfaceFace& s : surface_) {
    if (!s.alive) continue;
    const auto lf = mesh::LocalTetFace(s.local_face);
    const auto& n = recs_[Idx(s.tet)].nodes;
    tris.row(row++) << n[Idx(lf[0])], n[Idx(lf[1])], n[Idx(lf[2])];
    if (opened) opened->push_back(s.opened ? 1 : 0);
  }
  return tris;
}

std::array<int32_t, 3> CutMesh::SurfaceTriangle(int32_t slot) const {
  const SurfaceFace& s = surface_[Idx(slot)];
  const auto lf = mesh::LocalTetFace(s.local_face);
  const auto& n = recs_[Idx(s.tet)].nodes;
  return {n[Idx(lf[0])], n[Idx(lf[1])], n[Idx(lf[2])]};
}

std::vector<int32_t> CutMesh::ContactElements(int32_t node, int32_t facet_tet) const {
  std::vector<int32_t> out;
  if (node >= 0 && node < num_nodes()) out.assign(node_tets(node).begin(), node_tets(node).end());
  if (facet_tet >= 0 && facet_tet < num_tets() && !std::binary_search(out.begin(), out.end(), facet_tet)) {
    out.insert(std::lower_bound(out.begin(), out.end(), facet_tet), facet_tet);
  }
  return out;
}

std::vector<int32_t> CutMesh::Twins(int32_t node, const WorldAccess& world) const {
  std::vector<int32_t> out;
  TwinsInto(node, world, out);
  return out;
}

void CutMesh::TwinsInto(int32_t node, const WorldAccess& world, std::vector<int32_t>& out) const {
  // Copies of one original vertex that still coincide (split but not moved
  // apart) move together, so a crack stays closed where the tool passed.
  out.clear();
  const int32_t o = origin_[Idx(node)];
  const Eigen::Vector3d x = world.Get(node);
  auto consider = [&](int32_t k) {
    if (rest_[Idx(k)] == rest_[Idx(node)] && world.Get(k) == x) out.push_back(k);
  };
  consider(o);
  for (const int32_t k : copies_[Idx(o)]) consider(k);
  // Ascending: the original first, copies in creation order.
}

int32_t CutMesh::SelectV2(int32_t v0, int32_t v1, const Eigen::Vector3d& cp, const Eigen::Vector3d& normal,
                          const WorldAccess& world) const {
  const Eigen::Vector3d n = normal.normalized();
  auto tangential = [&](const Eigen::Vector3d& a) { return Eigen::Vector3d(a - n.dot(a) * n); };
  const Eigen::Vector3d s1 = tangential(world.Get(v1) - world.Get(v0));
  if (!(s1.norm() > 0.0)) return -1;
  int32_t best = -1;
  double best_cos = -2.0;
  for (const int32_t t : node_tets(v1)) {
    const auto& tn = recs_[Idx(t)].nodes;
    for (int f = 0; f < 4; ++f) {
      if (tn[Idx(f)] == v1 || recs_[Idx(t)].neighbour[Idx(f)] >= 0) continue;  // surface faces through v1
      for (int c = 0; c < 4; ++c) {
        const int32_t vi = tn[Idx(c)];
        if (c == f || vi == v1 || origin_[Idx(vi)] == origin_[Idx(v0)] || origin_[Idx(vi)] == origin_[Idx(v1)])
          continue;
        const Eigen::Vector3d si = tangential(world.Get(vi) - cp);  // eq. (12): s_i from C_p(t)
        if (!(si.norm() > 0.0)) continue;
        const double c_angle = s1.dot(si) / (s1.norm() * si.norm());
        if (c_angle > best_cos || (c_angle == best_cos && vi < best)) {
          best_cos = c_angle;
          best = vi;
        }
      }
    }
  }
  return best;
}

int32_t CutMesh::NewSlot(int32_t t, int f, bool opened) {
  int32_t slot;
  if (!free_slots_.empty()) {
    slot = free_slots_.back();
    free_slots_.pop_back();
  } else {
    slot = static_cast<int32_t>(surface_.size());
    surface_.emplace_back();
  }
  surface_[Idx(slot)] = SurfaceFace{t, static_cast<int8_t>(f), opened, true};
  ++num_surface_;
  if (track_slots_) changed_slots_.push_back(slot);
  return slot;
}

void CutMesh::FreeSlot(int32_t slot) {
  surface_[Idx(slot)].alive = false;
  free_slots_.push_back(slot);
  --num_surface_;
  if (track_slots_) changed_slots_.push_back(slot);
}

bool CutMesh::RemoveFaceTet(int32_t t, int f) {
  const int32_t u = recs_[Idx(t)].neighbour[Idx(f)];
  if (u < 0) {  // a surface face: it travels with its tet
    const int32_t slot = slot_[Idx(t)][Idx(f)];
    CUTSIM_CHECK(slot >= 0, "surface face without a slot");
    const bool opened = surface_[Idx(slot)].opened;
    FreeSlot(slot);
    slot_[Idx(t)][Idx(f)] = -1;
    return opened;
  }
  // Interior face: the other tet is exposed, as a face opened by the cut.
  const int fu = MatchingFace(u, t, f);
  CUTSIM_CHECK(recs_[Idx(u)].neighbour[Idx(fu)] == t, "face owner mismatch");
  recs_[Idx(t)].neighbour[Idx(f)] = -1;
  recs_[Idx(u)].neighbour[Idx(fu)] = -1;
  slot_[Idx(u)][Idx(fu)] = NewSlot(u, fu, true);
  return true;
}

void CutMesh::AddFaceTet(int32_t t, int f, bool opened_if_boundary) {
  const int32_t u = FindFaceMate(t, f);
  if (u < 0) {
    slot_[Idx(t)][Idx(f)] = NewSlot(t, f, opened_if_boundary);
    return;
  }
  // Two tets sharing a face both hold copies only moved together (see the
  // proof sketch in SplitNode), so a third user is a bug.
  const int fu = MatchingFace(u, t, f);
  CUTSIM_CHECK(recs_[Idx(u)].neighbour[Idx(fu)] < 0, "face would be shared by more than two tets");
  recs_[Idx(t)].neighbour[Idx(f)] = u;
  recs_[Idx(u)].neighbour[Idx(fu)] = t;
  FreeSlot(slot_[Idx(u)][Idx(fu)]);
  slot_[Idx(u)][Idx(fu)] = -1;
}

int32_t CutMesh::AddNodeCopy(int32_t node, int32_t star_capacity) {
  const Eigen::Vector3d r = rest_[Idx(node)];
  const int32_t o = origin_[Idx(node)];
  rest_.push_back(r);
  origin_.push_back(o);
  const auto begin = static_cast<int32_t>(star_pool_.size());
  star_capacity = std::max(star_capacity, 1);
  star_pool_.resize(star_pool_.size() + Idx(star_capacity));
  star_block_.push_back(StarBlock{begin, 0, star_capacity});
  copies_[Idx(o)].push_back(num_nodes() - 1);
  return num_nodes() - 1;
}

void CutMesh::RemoveLastNode() {
  const StarBlock b = star_block_.back();
  CUTSIM_CHECK(b.size == 0, "removing a node still in use");
  copies_[Idx(origin_.back())].pop_back();
  rest_.pop_back();
  origin_.pop_back();
  star_block_.pop_back();
  // A rolled-back copy's block is usually the pool's last: give it back.
  if (Idx(b.begin + b.capacity) == star_pool_.size()) star_pool_.resize(Idx(b.begin));
}

void CutMesh::StarInsert(int32_t node, int32_t t) {
  StarBlock& b = star_block_[Idx(node)];
  if (b.size == b.capacity) [[unlikely]] {  // move the block to the pool's end, twice as large
    const auto begin = static_cast<int32_t>(star_pool_.size());
    const int32_t capacity = std::max(4, 2 * b.capacity);
    star_pool_.resize(star_pool_.size() + Idx(capacity));
    std::copy_n(star_pool_.begin() + b.begin, b.size, star_pool_.begin() + begin);
    b.begin = begin;
    b.capacity = capacity;
  }
  int32_t* first = star_pool_.data() + b.begin;
  int32_t* last = first + b.size;
  int32_t* at = std::upper_bound(first, last, t);
  std::copy_backward(at, last, last + 1);
  *at = t;
  ++b.size;
}

void CutMesh::StarErase(int32_t node, int32_t t) {
  StarBlock& b = star_block_[Idx(node)];
  int32_t* first = star_pool_.data() + b.begin;
  int32_t* last = first + b.size;
  int32_t* at = std::lower_bound(first, last, t);
  std::copy(at + 1, last, at);
  --b.size;
}

void CutMesh::RetargetTet(int32_t t, int32_t from, int32_t to) {
  auto& n = recs_[Idx(t)].nodes;
  int corner = -1;
  for (int c = 0; c < 4; ++c)
    if (n[Idx(c)] == from) corner = c;
  CUTSIM_CHECK(corner >= 0, "retargeted tet does not use the node");
  // The three faces through the corner change key; the opposite face does not.
  std::array<bool, 4> opened{};
  for (int f = 0; f < 4; ++f)
    if (f != corner) opened[Idx(f)] = RemoveFaceTet(t, f);
  StarErase(from, t);
  n[Idx(corner)] = to;
  StarInsert(to, t);
  for (int f = 0; f < 4; ++f)
    if (f != corner) AddFaceTet(t, f, opened[Idx(f)]);
  if (journaling_) journal_.push_back(Op{t, from, to});
}

size_t CutMesh::BeginJournal() {
  journaling_ = true;
  return journal_.size();
}

void CutMesh::EndJournal(size_t journal_mark) {
  journaling_ = false;
  journal_.resize(journal_mark);
}

void CutMesh::RollBack(size_t journal_mark, int32_t node_mark) {
  const bool was_journaling = journaling_;
  journaling_ = false;
  while (journal_.size() > journal_mark) {
    const Op op = journal_.back();
    journal_.pop_back();
    RetargetTet(op.tet, op.to, op.from);
  }
  while (num_nodes() > node_mark) RemoveLastNode();
  journaling_ = was_journaling;
}

int32_t CutMesh::SplitNode(int32_t node, std::span<const int32_t> moved, TopologyEvent* event) {
  // Why no face can get a third tet: the copy only ever receives tets that
  // used `node`, so two tets sharing a face with the copy shared the same
  // face with `node` before, and that face had at most two tets.
  const int32_t copy = AddNodeCopy(node, static_cast<int32_t>(moved.size()));
  MoveTetsToCopy(moved, node, copy);
  if (event) {
    Split split;
    split.node = node;
    split.new_node = copy;
    split.tets.assign(moved.begin(), moved.end());
    event->splits.push_back(std::move(split));
  }
  return copy;
}

void CutMesh::MoveTetsToCopy(std::span<const int32_t> moved, int32_t from, int32_t to) {
  CUTSIM_CHECK(node_tets(to).empty(), "tets move to a fresh copy only");
  // All at once rather than RetargetTet one by one: a face between two
  // moved tets stays interior (its neighbour entries are per local face,
  // and the corner is replaced in place), a surface face keeps its slot
  // (its triangle then names the copy), and only a face between a moved and
  // an unmoved tet opens, as two new surface faces. One tet at a time would
  // open and close each face between two moved tets again (two slots made
  // and freed, and a mate search in a star).
  tet_marks_.Clear(kMoving);
  for (const int32_t t : moved) tet_marks_.Insert(kMoving, t);
  for (const int32_t t : moved) {
    auto& n = recs_[Idx(t)].nodes;
    int corner = -1;
    for (int c = 0; c < 4; ++c)
      if (n[Idx(c)] == from) corner = c;
    CUTSIM_CHECK(corner >= 0, "retargeted tet does not use the node");
    for (int f = 0; f < 4; ++f) {
      if (f == corner) continue;  // the face opposite the corner keeps its nodes
      const int32_t u = recs_[Idx(t)].neighbour[Idx(f)];
      if (u < 0) {
        if (track_slots_) changed_slots_.push_back(slot_[Idx(t)][Idx(f)]);
        continue;
      }
      if (tet_marks_.Contains(kMoving, u)) continue;
      const int fu = MatchingFace(u, t, f);  // while t still holds `from`
      recs_[Idx(t)].neighbour[Idx(f)] = -1;
      recs_[Idx(u)].neighbour[Idx(fu)] = -1;
      slot_[Idx(u)][Idx(fu)] = NewSlot(u, fu, true);
      slot_[Idx(t)][Idx(f)] = NewSlot(t, f, true);
    }
    StarErase(from, t);
    n[Idx(corner)] = to;
    StarInsert(to, t);
    if (journaling_) journal_.push_back(Op{t, from, to});  // undone one tet at a time
  }
}

bool CutMesh::StarIsOneGroup(int32_t node) const {
  // Flood over the faces through `node` from the first tet of its star; a
  // tet across such a face holds the face, hence the node: it is in the star.
  const std::span<const int32_t> star = node_tets(node);
  if (star.size() <= 1) return true;
  tet_marks_.Clear(kInStar);
  tet_marks_.Insert(kInStar, star[0]);
  star_queue_.assign(1, star[0]);
  for (size_t i = 0; i < star_queue_.size(); ++i) {
    const int32_t t = star_queue_[i];
    const auto& n = recs_[Idx(t)].nodes;
    for (int f = 0; f < 4; ++f) {
      if (n[Idx(f)] == node) continue;
      const int32_t u = recs_[Idx(t)].neighbour[Idx(f)];
      if (u >= 0 && tet_marks_.Insert(kInStar, u)) star_queue_.push_back(u);
    }
  }
  return star_queue_.size() == star.size();
}

bool CutMesh::SurfaceManifoldAt(int32_t node) const {
  SurfaceLinkInto(node, link_);
  return link_.empty() || LinkIsOneCycle(link_, heads_);  // empty: an interior vertex
}

void CutMesh::SurfaceLinkInto(int32_t node, SurfaceLink& link) const {
  // Each surface triangle (node, p, q) contributes the directed link edge
  // p → q.
  link.clear();
  for (const int32_t t : node_tets(node)) {
    const auto& nb = recs_[Idx(t)].neighbour;
    if ((nb[0] | nb[1] | nb[2] | nb[3]) >= 0) continue;  // no surface face (the usual tet)
    const auto& n = recs_[Idx(t)].nodes;
    for (int f = 0; f < 4; ++f) {
      if (n[Idx(f)] == node || nb[Idx(f)] >= 0) continue;
      const auto& lf = mesh::internal::kTetFaces[Idx(f)];
      const int32_t a = n[Idx(lf[0])], b = n[Idx(lf[1])], c = n[Idx(lf[2])];
      // The triangle rotated to start at the node: (node, p, q).
      if (a == node) {
        link.emplace_back(b, c);
      } else if (b == node) {
        link.emplace_back(c, a);
      } else {
        link.emplace_back(a, b);
      }
    }
  }
}

bool CutMesh::LinkIsOneCycle(SurfaceLink& link, std::vector<int32_t>& heads) {
  // A closed, oriented manifold fan is exactly one cycle: every link vertex
  // has one out- and one in-edge, and the walk from one edge visits all.
  if (link.empty()) return false;
  const size_t k = link.size();
  if (k <= 32) {
    // A handful of edges (a vertex's surface fan, a few more on a cut):
    // scans beat sorting. Walk from link[0] along the one out-edge of each
    // vertex reached (its index; −1: none or two). If the walk is back at
    // its start after exactly k edges, they are k distinct edges (each the
    // only one from its tail, and a deterministic walk that first returns
    // after k steps meets k distinct tails): all of them, one cycle, every
    // vertex with one out- and one in-edge. Same answer as the sorted path.
    auto out_edge = [&](int32_t v) {
      int found = -1;
      for (size_t j = 0; j < k; ++j) {
        if (link[j].first != v) continue;
        if (found >= 0) return -1;
        found = static_cast<int>(j);
      }
      return found;
    };
    const int32_t start = link[0].first;
    if (out_edge(start) != 0) return false;
    size_t steps = 1;
    for (int32_t v = link[0].second; v != start; ++steps) {
      const int j = out_edge(v);
      if (j < 0 || steps == k) return false;
      v = link[static_cast<size_t>(j)].second;
    }
    return steps == k;
  }
  std::sort(link.begin(), link.end());
  for (size_t i = 1; i < link.size(); ++i)
    if (link[i].first == link[i - 1].first) return false;  // two out-edges
  heads.clear();
  for (const auto& e : link) heads.push_back(e.second);
  std::sort(heads.begin(), heads.end());
  if (std::adjacent_find(heads.begin(), heads.end()) != heads.end()) return false;  // two in-edges
  for (size_t i = 0; i < link.size(); ++i)
    if (heads[i] != link[i].first) return false;  // a link vertex without in- or out-edge
  // One cycle through all link edges.
  int32_t v = link[0].first;
  for (size_t steps = 1;; ++steps) {
    const auto it = std::lower_bound(link.begin(), link.end(), std::make_pair(v, INT32_MIN));
    v = it->second;
    if (v == link[0].first) return steps == link.size();
    if (steps > link.size()) return false;
  }
}

std::vector<int32_t> CutMesh::ConnectedComponents(int32_t* count) const {
  DisjointSets ds(recs_.size());
  for (int32_t t = 0; t < num_tets(); ++t)
    for (const int32_t u : recs_[Idx(t)].neighbour)
      if (u > t) ds.Union(t, u);
  std::vector<int32_t> labels;
  const int32_t k = ds.Label(&labels);
  if (count) *count = k;
  return labels;
}

std::vector<int32_t> ConnectedComponents(const mesh::Tets& tets, int32_t* count) {
  std::unordered_map<mesh::internal::FaceKey, int32_t, mesh::internal::FaceKeyHash> first;
  first.reserve(static_cast<size_t>(tets.rows()) * 3);
  DisjointSets ds(static_cast<size_t>(tets.rows()));
  for (int32_t t = 0; t < tets.rows(); ++t) {
    for (int f = 0; f < 4; ++f) {
      std::array<int32_t, 3> k{};
      int j = 0;
      for (int c = 0; c < 4; ++c)
        if (c != f) k[static_cast<size_t>(j++)] = tets(t, c);
      std::sort(k.begin(), k.end());
      const auto [it, inserted] = first.try_emplace(k, t);
      if (!inserted) ds.Union(it->second, t);
    }
  }
  std::vector<int32_t> labels;
  const int32_t k = ds.Label(&labels);
  if (count) *count = k;
  return labels;
}

void CutMesh::ApplyEvent(const TopologyEvent& event) {
  auto fail = [](const std::string& field, const std::string& why) {
    ThrowInputError(SourceRef{.field = field}, why);
  };
  if (event.version != version_ + 1) {
    fail("event.version", "expected version " + std::to_string(version_ + 1) + ", got " +
                              std::to_string(event.version));
  }
  for (size_t i = 0; i < event.moves.size(); ++i) {
    const Move& m = event.moves[i];
    if (!m.rest.allFinite() || !m.world.allFinite()) fail("event.moves[" + std::to_string(i) + "]", "non-finite position");
  }
  const size_t journal_mark = BeginJournal();
  const int32_t node_mark = num_nodes();
  std::string error_field, error_why;
  for (size_t i = 0; i < event.splits.size() && error_field.empty(); ++i) {
    const Split& s = event.splits[i];
    if (s.node < 0 || s.node >= num_nodes() || s.new_node != num_nodes()) {
      error_field = "event.splits[" + std::to_string(i) + "]";
      error_why = "node ids do not follow the mesh (node " + std::to_string(s.node) + ", new node " +
                  std::to_string(s.new_node) + ", expected new node " + std::to_string(num_nodes()) + ")";
      break;
    }
    tet_marks_.Clear(kMoving);
    for (const int32_t t : s.tets) {
      const bool uses = t >= 0 && t < num_tets() &&
                        std::find(recs_[Idx(t)].nodes.begin(), recs_[Idx(t)].nodes.end(), s.node) != recs_[Idx(t)].nodes.end();
      if (!uses || !tet_marks_.Insert(kMoving, t)) {
        error_field = "event.splits[" + std::to_string(i) + "].tets";
        error_why = "tet " + std::to_string(t) +
                    (uses ? " is listed twice" : " does not use node " + std::to_string(s.node));
        break;
      }
    }
    if (!error_field.empty()) break;
    AddNodeCopy(s.node, static_cast<int32_t>(s.tets.size()));
    MoveTetsToCopy(s.tets, s.node, s.new_node);
  }
  for (size_t i = 0; i < event.moves.size() && error_field.empty(); ++i) {
    if (event.moves[i].node < 0 || event.moves[i].node >= num_nodes()) {
      error_field = "event.moves[" + std::to_string(i) + "].node";
      error_why = "node out of range";
    }
  }
  if (!error_field.empty()) {
    RollBack(journal_mark, node_mark);
    EndJournal(journal_mark);
    fail(error_field, error_why);
  }
  EndJournal(journal_mark);
  for (const Move& m : event.moves) rest_[Idx(m.node)] = m.rest;
  version_ = event.version;
}

}  // namespace cutsim::cutting
