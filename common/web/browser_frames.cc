#include "common/web/browser_frames.h"

#include <cstring>

#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>

namespace cutsim::web {

namespace {

template <typename V>
void Append(std::string& out, V value) {
  char bytes[sizeof(V)];
  std::memcpy(bytes, &value, sizeof(V));  // the wire is little-endian, as this host
  out.append(bytes, sizeof(V));
}

}  // namespace

void BrowserFrameEncoder::Renumber(const transport::MeshReplica& mesh) {
  const mesh::Triangles& surface = mesh.surface();
  const std::vector<uint8_t>& opened = mesh.opened();
  vertex_of_node_.assign(static_cast<size_t>(mesh.world().rows()), -1);
  node_of_vertex_.clear();
  triangles_.clear();
  triangles_.reserve(static_cast<size_t>(3 * surface.rows()));
  opened_count_ = 0;
  // Intact faces first, then the opened ones: the page draws them as two
  // groups with their own colours.
  for (const bool want_opened : {false, true}) {
    for (Eigen::Index f = 0; f < surface.rows(); ++f) {
      const bool is_opened = !opened.empty() && opened[static_cast<size_t>(f)] != 0;
      if (is_opened != want_opened) continue;
      for (int k = 0; k < 3; ++k) {
        const auto node = static_cast<size_t>(surface(f, k));
        if (vertex_of_node_[node] < 0) {
          vertex_of_node_[node] = static_cast<int32_t>(node_of_vertex_.size());
          node_of_vertex_.push_back(static_cast<int32_t>(node));
        }
        triangles_.push_back(static_cast<uint32_t>(vertex_of_node_[node]));
      }
      if (is_opened) ++opened_count_;
    }
  }
  have_topology_ = true;
  topology_version_ = mesh.topology_version();
  surface_rows_ = surface.rows();
}

std::string BrowserFrameEncoder::Header(uint8_t kind, const transport::MeshReplica& mesh, uint32_t triangles,
                                        uint32_t opened) const {
  std::string out;
  out.reserve(kBrowserFrameHeaderBytes);
  Append<uint8_t>(out, kind);
  Append<uint8_t>(out, kBrowserFrameVersion);
  Append<uint16_t>(out, 0);
  Append<uint32_t>(out, static_cast<uint32_t>(node_of_vertex_.size()));
  Append<uint32_t>(out, triangles);
  Append<uint32_t>(out, opened);
  Append<double>(out, mesh.sim_time());
  Append<double>(out, static_cast<double>(mesh.seq()));
  return out;
}

void BrowserFrameEncoder::AppendPositions(const transport::MeshReplica& mesh, std::string& out) const {
  const mesh::Positions& world = mesh.world();
  for (const int32_t node : node_of_vertex_) {
    for (int c = 0; c < 3; ++c) Append<float>(out, static_cast<float>(world(node, c)));
  }
}

std::shared_ptr<const std::string> BrowserFrameEncoder::Snapshot(const transport::MeshReplica& mesh) {
  if (!have_topology_ || mesh.topology_version() != topology_version_ || mesh.surface().rows() != surface_rows_ ||
      static_cast<Eigen::Index>(vertex_of_node_.size()) != mesh.world().rows()) {
    Renumber(mesh);
  }
  const auto num_triangles = static_cast<uint32_t>(triangles_.size() / 3);
  std::string out = Header(kSurfaceSnapshot, mesh, num_triangles, opened_count_);
  out.reserve(out.size() + 12 * node_of_vertex_.size() + 4 * triangles_.size());
  AppendPositions(mesh, out);
  for (const uint32_t v : triangles_) Append<uint32_t>(out, v);
  return std::make_shared<const std::string>(std::move(out));
}

std::shared_ptr<const std::string> BrowserFrameEncoder::Frame(const transport::MeshReplica& mesh) {
  const bool changed = !have_topology_ || mesh.topology_version() != topology_version_ ||
                       mesh.surface().rows() != surface_rows_ ||
                       static_cast<Eigen::Index>(vertex_of_node_.size()) != mesh.world().rows();
  if (changed) return Snapshot(mesh);
  std::string out = Header(kPositionsUpdate, mesh, 0, 0);
  out.reserve(out.size() + 12 * node_of_vertex_.size());
  AppendPositions(mesh, out);
  return std::make_shared<const std::string>(std::move(out));
}

std::shared_ptr<const std::string> BrowserFrameEncoder::Session(uint64_t seq,
                                                                const std::optional<v1::ObserverSession>& observed,
                                                                const LinkHealth& link) {
  std::string observed_json = "{}";
  if (observed) {
    observed_json.clear();
    if (!google::protobuf::util::MessageToJsonString(*observed, &observed_json).ok()) observed_json = "{}";
  }
  return std::make_shared<const std::string>(
      fmt::format(R"({{"type":"session","seq":{},"observed":{},"link":{{"frame_age_ms":{:.3f},"bridge_gaps":{},"clients":{}}}}})",
                  seq, observed_json, link.frame_age_ms, link.bridge_gaps, link.clients));
}

std::shared_ptr<const std::string> BrowserFrameEncoder::Hello(const std::string& session) {
  // Session names are restricted to [A-Za-z0-9_-] (transport::ValidateSessionName).
  return std::make_shared<const std::string>(
      fmt::format(R"({{"type":"hello","protocol":1,"session":"{}"}})", session));
}

}  // namespace cutsim::web
