// cutsim-fake-mesh-server: a test-only stand-in for the server's real-time
// mode. Builds a box (or the organ), pokes it, makes a plane cut at
// --cut-at seconds (nodes on the plane split, tets on +x re-pointed, the new
// faces flagged opened, the cut then opens like a wedge), and publishes it
// through MeshStreamPublisher at --rate Hz. With --hash-log it writes one line
// per published frame: "seq hash(hex) mono_ns sim_time", so tests can check
// that every frame a viewer rendered is one the publisher sent.
#include <csignal>
#include <cstdio>
#include <fstream>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "common/core/clock.h"
#include "common/core/error.h"
#include "common/core/log.h"
#include "common/mesh/generators.h"
#include "common/mesh/surface.h"
#include "common/transport/dds.h"
#include "common/transport/mesh_stream.h"

namespace {

volatile std::sig_atomic_t g_stop = 0;
void OnSignal(int) { g_stop = 1; }

struct Fake {
  cutsim::mesh::Positions rest0;  // initial rest, #N0×3
  cutsim::mesh::Positions rest;
  cutsim::mesh::Tets tets;
  cutsim::mesh::Triangles surface;
  std::vector<uint8_t> opened;
  std::vector<int8_t> side;  // per node: −1 left of the cut, +1 right (duplicates), 0 on the plane
  uint64_t version = 1;
  bool cut = false;
  double cut_x = 0, cut_z = 0, top = 0, lo_x = 0, hi_x = 0;

  void Resurface() {
    surface = cutsim::mesh::ExtractSurface(tets).tris;
    opened.assign(static_cast<size_t>(surface.rows()), 0);
    if (!cut) return;
    for (Eigen::Index f = 0; f < surface.rows(); ++f) {
      bool on_plane = true;
      for (int k = 0; k < 3; ++k) on_plane &= std::abs(rest(surface(f, k), 0) - cut_x) < 1e-9;
      opened[static_cast<size_t>(f)] = on_plane ? 1 : 0;
    }
  }

  void Cut() {
    const Eigen::Index n = rest.rows();
    std::vector<int32_t> dup(static_cast<size_t>(n), -1);
    Eigen::Index next = n;
    for (Eigen::Index i = 0; i < n; ++i) {
      if (std::abs(rest(i, 0) - cut_x) < 1e-9 && rest(i, 2) > cut_z + 1e-9) {
        dup[static_cast<size_t>(i)] = static_cast<int32_t>(next++);
      }
    }
    rest.conservativeResize(next, 3);
    side.resize(static_cast<size_t>(next), 1);
    for (Eigen::Index i = 0; i < n; ++i) {
      if (dup[static_cast<size_t>(i)] >= 0) rest.row(dup[static_cast<size_t>(i)]) = rest.row(i);
    }
    for (Eigen::Index t = 0; t < tets.rows(); ++t) {
      double cx = 0;
      for (int k = 0; k < 4; ++k) cx += rest(tets(t, k), 0) / 4;
      if (cx <= cut_x) continue;
      for (int k = 0; k < 4; ++k) {
        if (const int32_t d = dup[static_cast<size_t>(tets(t, k))]; d >= 0) tets(t, k) = d;
      }
    }
    cut = true;
    ++version;
    Resurface();
  }

  /// World positions at time t (s): a travelling poke on the top, and after
  /// the cut a wedge opening of the two sides above cut_z.
  void World(double t, double cut_at, cutsim::mesh::Positions& world) const {
    world = rest;
    const double span = hi_x - lo_x;
    const Eigen::Vector3d centre(lo_x + 0.25 * span, rest0.col(1).mean() + 0.3 * span * std::sin(0.7 * t), top);
    const double radius = 0.2 * span, depth = 0.03 * span * (0.6 + 0.4 * std::sin(3.0 * t));
    for (Eigen::Index i = 0; i < world.rows(); ++i) {
      const double r = (rest.row(i).transpose() - centre).norm();
      if (r < radius) world(i, 2) -= depth * 0.5 * (1 + std::cos(M_PI * r / radius));
    }
    if (!cut) return;
    const double open = 0.06 * span * std::min(1.0, (t - cut_at) / 0.5);
    for (Eigen::Index i = 0; i < world.rows(); ++i) {
      const double s = side[static_cast<size_t>(i)];
      if (s == 0) continue;
      world(i, 0) += s * open * std::max(0.0, (rest(i, 2) - cut_z) / (top - cut_z));
    }
  }
};

}  // namespace

int main(int argc, char** argv) {
  try {
    CLI::App app{"cutsim-fake-mesh-server: test publisher of a deforming, cut box"};
    std::string session = "default", hash_log, mesh = "box", log_level = "info", key_file;
    uint32_t domain = 0;
    double rate = 20, duration = 10, cut_at = 3;
    int cells = 8;
    app.add_option("--session", session);
    app.add_option("--dds-domain", domain);
    app.add_option("--rate", rate)->check(CLI::Range(1.0, 1000.0));
    app.add_option("--duration", duration, "Wall seconds to run");
    app.add_option("--cut-at", cut_at, "Seconds until the cut (negative: never)");
    app.add_option("--cells", cells, "Box cells along x (even)")->check(CLI::Range(2, 64));
    app.add_option("--mesh", mesh)->check(CLI::IsMember({"box", "organ"}));
    app.add_option("--hash-log", hash_log);
    app.add_option("--log-level", log_level);
    app.add_option("--key-file", key_file, "Sign the frames with this session key (hex)");
    CLI11_PARSE(app, argc, argv);
    cutsim::InitLogging("fake-mesh-server", log_level);
    std::signal(SIGINT, OnSignal);
    std::signal(SIGTERM, OnSignal);

    Fake fake;
    cutsim::mesh::TetMesh m;
    if (mesh == "organ") {
      m = cutsim::mesh::MakeOrgan();
      cut_at = -1;  // the organ's nodes are not on a grid plane
    } else {
      cells += cells % 2;
      m = cutsim::mesh::MakeBox({0, 0, 0}, {0.1, 0.06, 0.05}, cells, std::max(2, cells * 6 / 10),
                                std::max(2, cells / 2));
    }
    fake.rest0 = m.nodes;
    fake.rest = m.nodes;
    fake.tets = m.tets;
    fake.lo_x = m.nodes.col(0).minCoeff();
    fake.hi_x = m.nodes.col(0).maxCoeff();
    fake.top = m.nodes.col(2).maxCoeff();
    fake.cut_x = 0.5 * (fake.lo_x + fake.hi_x);
    fake.cut_z = 0.5 * (m.nodes.col(2).minCoeff() + fake.top);
    fake.side.resize(static_cast<size_t>(m.nodes.rows()));
    for (Eigen::Index i = 0; i < m.nodes.rows(); ++i) {
      const double dx = m.nodes(i, 0) - fake.cut_x;
      fake.side[static_cast<size_t>(i)] = std::abs(dx) < 1e-9 ? -1 : (dx < 0 ? -1 : 1);
    }
    fake.Resurface();
    cutsim::Log().info("{}: {} nodes, {} tets, {} faces", mesh, m.nodes.rows(), m.tets.rows(),
                       fake.surface.rows());

    cutsim::transport::DdsParticipant participant(domain);
    cutsim::transport::MeshStreamPublisher pub(
        participant, session,
        {.key = key_file.empty() ? std::nullopt : cutsim::transport::LoadSessionKey(key_file)});
    std::ofstream log;
    if (!hash_log.empty()) log.open(hash_log, std::ios::trunc);

    const int64_t start = cutsim::MonotonicNs();
    const auto period = static_cast<int64_t>(1e9 / rate);
    int64_t next = start;
    uint64_t frame = 0, last_seq = 0;
    int64_t last_status = 0;
    while (!g_stop) {
      const int64_t now = cutsim::MonotonicNs();
      const double t = 1e-9 * static_cast<double>(now - start);
      if (t >= duration) break;
      if (cut_at >= 0 && !fake.cut && t >= cut_at) {
        fake.Cut();
        cutsim::Log().info("cut at t={:.2f} s: {} nodes, topology version {}", t, fake.rest.rows(),
                           fake.version);
      }
      ++frame;
      pub.PublishFrame([&](cutsim::transport::MeshFrame& f) {
        f.frame = frame;
        f.sim_time = t;
        f.topology_version = fake.version;
        fake.World(t, cut_at, f.world);
        f.rest = fake.rest;
        f.tets = fake.tets;
        f.surface = fake.surface;
        f.opened = fake.opened;
        f.stress.resize(static_cast<size_t>(f.world.rows()));
        for (Eigen::Index i = 0; i < f.world.rows(); ++i) {
          f.stress[static_cast<size_t>(i)] = 1e5 * (f.world.row(i) - f.rest.row(i)).norm();
        }
      });
      const auto s = pub.stats();
      if (s.last_seq != last_seq) {
        last_seq = s.last_seq;
        if (log) {
          log << s.last_seq << ' ' << fmt::format("{:016x}", s.last_hash) << ' '
              << cutsim::MonotonicNs() << ' ' << fmt::format("{:.9g}", t) << '\n';
          log.flush();
        }
      }
      if (now - last_status > 1'000'000'000LL) {
        last_status = now;
        cutsim::v1::SessionStatus status;
        status.set_frame(frame);
        status.set_sim_time(t);
        status.set_topology_version(fake.version);
        pub.PublishStatus(status);
      }
      next += period;
      cutsim::SleepUntilNs(std::max(next, cutsim::MonotonicNs()));
    }
    const auto s = pub.stats();
    std::printf(
        "{\"frames\": %llu, \"skipped_no_reader\": %llu, \"snapshots\": %llu, \"deltas\": %llu, "
        "\"snapshot_bytes\": %llu, \"delta_bytes\": %llu, \"encode_ms_mean\": %.4f, "
        "\"publish_failures\": %llu}\n",
        static_cast<unsigned long long>(s.frames), static_cast<unsigned long long>(s.skipped_no_reader),
        static_cast<unsigned long long>(s.snapshots), static_cast<unsigned long long>(s.deltas),
        static_cast<unsigned long long>(s.snapshot_bytes), static_cast<unsigned long long>(s.delta_bytes),
        s.frames > s.skipped_no_reader
            ? 1e-6 * static_cast<double>(s.encode_ns) / static_cast<double>(s.frames - s.skipped_no_reader)
            : 0.0,
        static_cast<unsigned long long>(s.publish_failures));
    return 0;
  } catch (const cutsim::InputError& e) {
    std::fprintf(stderr, "cutsim-fake-mesh-server: error: %s\n", e.what());
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "cutsim-fake-mesh-server: fatal: %s\n", e.what());
    return 1;
  }
}
