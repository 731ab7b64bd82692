#pragma once
/// @file
/// A haptic station and the physics server joined by a simulated link, run
/// tick by tick on a simulated clock (deterministic: the same inputs and
/// seeds give the same numbers on every machine). Shared by the link
/// fidelity benchmark and its regression test.
///
/// One run:
/// * the station ticks at 1 kHz: it takes the models the link has delivered
///   (HapticRenderer::SetModel), reads the device (the scripted tool path
///   itself, or a virtual hand holding the handle), renders the force
///   (HapticRenderer::Tick: buffer model, watchdog, passivity controller,
///   device limits) and sends the tool pose;
/// * the server runs a physics frame every `frame_dt`: at the frame's start
///   it takes the newest tool pose the link has delivered, advances the
///   tissue by one frame and publishes the local model at the frame's end
///   (the model describes the tissue at that time);
/// * the link (transport::FaultInjector, one per direction) delays every
///   datagram by the one-way delay ±`jitter_fraction` (uniform) and loses a
///   fraction of them.
///
/// The station renders the same model stream with one or more stiffness
/// stations (Station): a stiffness term (the server's K, none = a zero-order
/// hold of f0, or K with the tissue's part from the static contact patch
/// only), with or without the passivity controller. With a scripted device
/// every station sees the same stream from one server run; with a virtual
/// hand the force moves the tool, so each station has its own.
///
/// The virtual hand is a mass on a spring and damper whose other end
/// follows the scripted path: m ẍ = F + k_h (x_set − x) + b_h (ẋ_set − ẋ),
/// integrated semi-implicitly at the tick rate.

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "common/core/tool_pose.h"
#include "common/haptics/haptic_renderer.h"
#include "common/haptics/local_model.h"
#include "common/haptics/tool_path.h"
#include "common/sim/scene_loader.h"
#include "common/sim/simulation.h"
#include "common/transport/fault_injection.h"

namespace cutsim::test_support {

/// The link between station and server, the same in both directions.
struct LinkSpec {
  double one_way_ms = 0.0;        ///< ms, mean one-way delay
  double jitter_fraction = 0.2;   ///< the delay is drawn uniformly from one_way·(1 ± this)
  double loss = 0.0;              ///< probability a datagram is lost (each direction)
  uint64_t seed = 1;              ///< fault generator seed (the two directions derive theirs)
};

/// Fault injector settings for `link`: delay (1 − j)·d plus U[0, 2j·d].
[[nodiscard]] inline transport::FaultConfig FaultsFor(const LinkSpec& link, uint64_t direction) {
  transport::FaultConfig f;
  f.delay_ms = link.one_way_ms * (1.0 - link.jitter_fraction);
  f.jitter_ms = link.one_way_ms * 2.0 * link.jitter_fraction;
  f.drop = link.loss;
  f.seed = link.seed * 2 + direction;
  return f;
}

/// Which stiffness the station renders with f0.
enum class StiffnessTerm : uint8_t {
  kServer,  ///< the server's K (Simulation::ContactStiffness)
  kNone,    ///< no stiffness term: a zero-order hold of f0
  kPatch,   ///< K with the tissue's part from the static patch (Simulation::PatchContactStiffness)
};

[[nodiscard]] inline const char* Name(StiffnessTerm term) {
  switch (term) {
    case StiffnessTerm::kServer: return "buffer_model";
    case StiffnessTerm::kNone: return "zero_order_hold";
    case StiffnessTerm::kPatch: return "buffer_model_patch_k";
  }
  return "?";
}

/// One station's rendering: its stiffness term and whether the passivity
/// controller acts (off: the observer still sums, so the energy the
/// rendering would put into the hand shows).
struct Station {
  StiffnessTerm term = StiffnessTerm::kServer;
  bool passivity = true;
};

/// "buffer_model", "zero_order_hold", ..., with "_no_pc" when the passivity
/// controller is off.
[[nodiscard]] inline std::string Name(const Station& station) {
  return std::string(Name(station.term)) + (station.passivity ? "" : "_no_pc");
}

/// A virtual hand holding the handle: mass, grip stiffness and damping.
struct HandModel {
  double mass = 0.1;        ///< kg, hand and handle
  double stiffness = 400.0; ///< N/m, grip
  double damping = 4.0;     ///< N·s/m, grip
};

/// What one station felt, per 1 ms tick.
struct StationTrace {
  Station station;
  std::vector<Eigen::Vector3d> position;  ///< #ticks, tool tip, m
  std::vector<Eigen::Vector3d> force;     ///< #ticks, force commanded to the device, N
  std::vector<double> watchdog_gain;      ///< #ticks, 0..1
  haptics::RendererStats stats;           ///< at the end of the run
};

/// A whole run: one trace per station and the link's counters.
struct TeleopResult {
  std::vector<StationTrace> stations;
  transport::FaultStats uplink;    ///< tool poses, station → server
  transport::FaultStats downlink;  ///< models, server → station
  int frames = 0;                  ///< physics frames the server ran
};

/// Settings of one run.
struct TeleopOptions {
  LinkSpec link;
  std::vector<Station> stations{Station{}};
  std::optional<HandModel> hand;       ///< empty: the device follows the path exactly
  haptics::RendererConfig renderer;    ///< device limits, watchdog, passivity
  double tick = 1e-3;                  ///< s, station loop period
};

namespace teleop_detail {

/// Tool pose datagram (trivially copyable; sent as its bytes).
struct PoseDatagram {
  uint64_t seq = 0;
  double tip[3] = {0, 0, 0};
  double dir[3] = {0, 0, 1};
};

/// Model datagram: the contact linearisation with both stiffness estimates.
struct ModelDatagram {
  uint64_t seq = 0;
  double sim_time = 0;
  int32_t contact = 0;
  double x0[3] = {0, 0, 0};
  double normal[3] = {0, 0, 1};
  double f0[3] = {0, 0, 0};
  double k_server[9] = {};
  double k_patch[9] = {};
};

template <class T>
std::span<const uint8_t> Bytes(const T& value) {
  return {reinterpret_cast<const uint8_t*>(&value), sizeof(T)};
}

template <class T>
bool FromBytes(std::span<const uint8_t> bytes, T& value) {
  if (bytes.size() != sizeof(T)) return false;
  std::memcpy(&value, bytes.data(), sizeof(T));
  return true;
}

inline Eigen::Vector3d Vec(const double* p) { return {p[0], p[1], p[2]}; }
inline void Put(const Eigen::Vector3d& v, double* p) { for (int i = 0; i < 3; ++i) p[i] = v[i]; }

/// The local model a station renders from a datagram with stiffness `term`.
inline haptics::LocalModel ToModel(const ModelDatagram& d, StiffnessTerm term) {
  haptics::ContactLinearisation c;
  c.contact = d.contact != 0;
  c.x0 = Vec(d.x0);
  c.normal = Vec(d.normal);
  c.f0 = Vec(d.f0);
  if (term == StiffnessTerm::kServer) c.stiffness = Eigen::Map<const Eigen::Matrix3d>(d.k_server);
  if (term == StiffnessTerm::kPatch) c.stiffness = Eigen::Map<const Eigen::Matrix3d>(d.k_patch);
  haptics::ModelHeader h;
  h.seq = d.seq;
  h.sim_time = d.sim_time;
  return haptics::BuildLocalModel(h, c);
}

/// The server side: the tissue, the newest pose it has, its frame clock.
class ServerSide {
 public:
  ServerSide(const sim::LoadedScene& scene, const ToolPose& start)
      : sim_(sim::Simulation::Create(scene)), frame_ns_(std::llround(sim_->frame_dt() * 1e9)) {
    pose_ = start;
  }

  /// Takes delivered poses; runs a frame if one starts at `now_ns` and
  /// publishes its model at the frame's end through `downlink`.
  void Tick(int64_t now_ns, transport::FaultInjector& uplink, transport::FaultInjector& downlink) {
    uplink.Release(now_ns, [&](std::span<const uint8_t> bytes) {
      PoseDatagram p;
      if (FromBytes(bytes, p) && p.seq > newest_) {  // jitter reorders: keep the newest
        newest_ = p.seq;
        pose_.tip = Vec(p.tip);
        pose_.blade_dir = Vec(p.dir);
      }
    });
    if (now_ns < next_frame_ns_) return;
    next_frame_ns_ += frame_ns_;
    sim_->SetToolPose(pose_);
    sim_->AdvanceFrame(sim_->frame_dt());
    const sim::ToolReport tool = sim_->Tool();
    ModelDatagram d;
    d.seq = ++frames_;
    d.sim_time = sim_->sim_time();
    d.contact = tool.touching ? 1 : 0;
    Put(tool.pose.tip, d.x0);
    Put(tool.normal, d.normal);
    Put(tool.force_on_tool, d.f0);
    if (tool.touching) {
      const Eigen::Matrix3d ks = sim_->ContactStiffness();
      const Eigen::Matrix3d kp = sim_->PatchContactStiffness();
      std::copy(ks.data(), ks.data() + 9, d.k_server);
      std::copy(kp.data(), kp.data() + 9, d.k_patch);
    }
    downlink.Submit(Bytes(d), now_ns + frame_ns_);
  }

  [[nodiscard]] int frames() const { return static_cast<int>(frames_); }

 private:
  std::unique_ptr<sim::Simulation> sim_;
  int64_t frame_ns_;
  int64_t next_frame_ns_ = 0;
  uint64_t newest_ = 0;
  uint64_t frames_ = 0;
  ToolPose pose_;
};

/// The hand's state; x_set, v_set from the path.
struct HandState {
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  Eigen::Vector3d v = Eigen::Vector3d::Zero();
};

/// One run with the given stations sharing one server (scripted device) or
/// with one station and a virtual hand.
inline TeleopResult RunStations(const sim::LoadedScene& scene, const haptics::ToolPath& path,
                                const TeleopOptions& options, std::span<const Station> stations) {
  const int ticks = static_cast<int>(std::lround(path.end_time() / options.tick));
  const int64_t tick_ns = std::llround(options.tick * 1e9);
  transport::FaultInjector uplink(FaultsFor(options.link, 0), 4096);
  transport::FaultInjector downlink(FaultsFor(options.link, 1), 1024);
  ServerSide server(scene, path.Sample(0.0));

  TeleopResult result;
  std::vector<haptics::HapticRenderer> renderers;
  renderers.reserve(stations.size());
  for (const Station& station : stations) {
    haptics::RendererConfig config = options.renderer;
    config.passivity.enabled = station.passivity;
    renderers.emplace_back(config);
    StationTrace s;
    s.station = station;
    s.position.reserve(static_cast<size_t>(ticks));
    s.force.reserve(static_cast<size_t>(ticks));
    s.watchdog_gain.reserve(static_cast<size_t>(ticks));
    result.stations.push_back(std::move(s));
  }
  HandState hand{path.Sample(0.0).tip, Eigen::Vector3d::Zero()};
  for (int i = 0; i < ticks; ++i) {
    const int64_t now_ns = i * tick_ns;
    const double t = i * options.tick;
    const ToolPose set = path.Sample(t);
    const Eigen::Vector3d v_set = (path.Sample(t + options.tick).tip - set.tip) / options.tick;
    downlink.Release(now_ns, [&](std::span<const uint8_t> bytes) {
      ModelDatagram d;
      if (!FromBytes(bytes, d)) return;
      for (size_t r = 0; r < renderers.size(); ++r)
        renderers[r].SetModel(ToModel(d, result.stations[r].station.term), now_ns);
    });
    const Eigen::Vector3d x = options.hand ? hand.x : set.tip;
    const Eigen::Vector3d v = options.hand ? hand.v : v_set;
    for (size_t r = 0; r < renderers.size(); ++r) {
      const Eigen::Vector3d f = renderers[r].Tick(x, v, now_ns, options.tick);
      StationTrace& s = result.stations[r];
      s.position.push_back(x);
      s.force.push_back(f);
      s.watchdog_gain.push_back(renderers[r].watchdog_gain());
    }
    PoseDatagram p;
    p.seq = static_cast<uint64_t>(i) + 1;
    Put(x, p.tip);
    Put(set.blade_dir, p.dir);
    uplink.Submit(Bytes(p), now_ns);
    server.Tick(now_ns, uplink, downlink);
    if (options.hand) {
      // Semi-implicit Euler: the velocity first, then the position with it.
      const HandModel& h = *options.hand;
      const Eigen::Vector3d a = (result.stations[0].force.back() + h.stiffness * (set.tip - hand.x) +
                                 h.damping * (v_set - hand.v)) / h.mass;
      hand.v += options.tick * a;
      hand.x += options.tick * hand.v;
    }
  }
  for (size_t r = 0; r < renderers.size(); ++r) result.stations[r].stats = renderers[r].stats();
  result.uplink = uplink.stats();
  result.downlink = downlink.stats();
  result.frames = server.frames();
  return result;
}

}  // namespace teleop_detail

/// Runs the station and the server over the link for the whole path. With
/// a virtual hand each station gets its own server run, and the
/// link counters are those of the last.
[[nodiscard]] inline TeleopResult RunTeleop(const sim::LoadedScene& scene, const haptics::ToolPath& path,
                                            const TeleopOptions& options) {
  if (!options.hand) return teleop_detail::RunStations(scene, path, options, options.stations);
  TeleopResult all;
  for (const Station& station : options.stations) {
    const Station one[] = {station};
    TeleopResult r = teleop_detail::RunStations(scene, path, options, one);
    all.stations.push_back(std::move(r.stations[0]));
    all.uplink = r.uplink;
    all.downlink = r.downlink;
    all.frames = r.frames;
  }
  return all;
}

/// The in-process reference: the tissue stepped at `tick` with the tool at
/// the path's position of every tick, no link and no local model.
/// Returns the force on the tool per tick, N (#ticks).
[[nodiscard]] inline std::vector<Eigen::Vector3d> ReferenceForces(const sim::LoadedScene& scene,
                                                                  const haptics::ToolPath& path,
                                                                  double tick = 1e-3) {
  const int ticks = static_cast<int>(std::lround(path.end_time() / tick));
  auto sim = sim::Simulation::Create(scene);
  std::vector<Eigen::Vector3d> force(static_cast<size_t>(ticks), Eigen::Vector3d::Zero());
  // Tick 0 is the start pose; each later tick's frame ends at its time.
  sim->SetToolPose(path.Sample(0.0));
  for (int i = 1; i < ticks; ++i) {
    sim->SetToolPose(path.Sample(i * tick));
    sim->AdvanceFrame(tick);
    force[static_cast<size_t>(i)] = sim->Tool().force_on_tool;
  }
  return force;
}

/// Oscillation of the tool over the window [from, to) of ticks: the peak-to-
/// peak excursion of its position along `axis` (unit), m. A contact that
/// settles has a small one; a sustained oscillation keeps it large.
[[nodiscard]] inline double PeakToPeak(std::span<const Eigen::Vector3d> position, const Eigen::Vector3d& axis,
                                       size_t from, size_t to) {
  to = std::min(to, position.size());
  if (from >= to) return 0.0;
  double lo = position[from].dot(axis), hi = lo;
  for (size_t i = from; i < to; ++i) {
    const double p = position[i].dot(axis);
    lo = std::min(lo, p);
    hi = std::max(hi, p);
  }
  return hi - lo;
}

}  // namespace cutsim::test_support
