// The session's measures (common/sim/session_metrics.h): the tool's force,
// travel and contact against sums done by hand; the stress outside the
// incision against the analytic StVK stress of a homogeneous stretch and
// against a brute-force scan of the tets the incision leaves; the volume
// cut off against the pieces' volumes; the sampling period; the message's
// checks.

#include <algorithm>
#include <cmath>
#include <limits>
#include <span>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "common/core/error.h"
#include "common/cutting/cut_mesh.h"
#include "common/fem/forces.h"
#include "common/fem/model.h"
#include "common/fem/state.h"
#include "common/mesh/generators.h"
#include "common/sim/metrics_proto.h"
#include "common/sim/session_metrics.h"
#include "cutsim/v1/report.pb.h"

namespace cutsim::sim {
namespace {

using Meter = SessionMeter<double>;

ToolReport ToolAt(const Eigen::Vector3d& tip, bool touching, const Eigen::Vector3d& force) {
  ToolReport r;
  r.present = true;
  r.touching = touching;
  r.pose.tip = tip;
  r.force_on_tool = force;
  return r;
}

TEST(SessionMeter, ToolMeasuresAreTheSumsOverFrames) {
  Meter meter({});
  const double dt = 1.0 / 60.0;
  double path = 0, contact = 0, impulse = 0, peak = 0;
  Eigen::Vector3d last = Eigen::Vector3d::Zero();
  for (int i = 0; i < 120; ++i) {
    // A helix: the path's length is the sum of the chords the meter sees.
    const Eigen::Vector3d tip(0.01 * std::cos(0.1 * i), 0.01 * std::sin(0.1 * i), 1e-4 * i);
    const bool touching = (i / 10) % 2 == 1;
    const Eigen::Vector3d f(0.0, 0.02 * i, -0.5);
    meter.AddFrame(dt, ToolAt(tip, touching, f));
    if (i > 0) path += (tip - last).norm();
    last = tip;
    if (touching) {
      contact += dt;
      impulse += f.norm() * dt;
      peak = std::max(peak, f.norm());
    }
  }
  const SessionMetrics& m = meter.metrics();
  EXPECT_NEAR(m.path_length(), path, 1e-12);
  EXPECT_NEAR(m.contact_time(), contact, 1e-12);
  EXPECT_NEAR(m.force_impulse(), impulse, 1e-12);
  EXPECT_DOUBLE_EQ(m.peak_force(), peak);
  EXPECT_NEAR(m.mean_force(), impulse / contact, 1e-12);
  EXPECT_LE(m.mean_force(), m.peak_force());
  EXPECT_GT(m.path_length(), 0.05);  // not vacuous: the helix is 6 cm long
}

TEST(SessionMeter, NoToolMeasuresNothing) {
  Meter meter({});
  ToolReport none;  // present = false
  for (int i = 0; i < 10; ++i) meter.AddFrame(0.01, none);
  EXPECT_EQ(meter.metrics().path_length(), 0.0);
  EXPECT_EQ(meter.metrics().contact_time(), 0.0);
}

TEST(SessionMeter, SamplesOncePerPeriodWhateverTheFrameTime) {
  for (const double dt : {1.0 / 60.0, 1.0 / 1000.0, 0.013}) {
    Meter meter({.sample_period = 0.05});
    const mesh::TetMesh box = mesh::MakeBox({0, 0, 0}, {0.01, 0.01, 0.01}, 1, 1, 1);
    const fem::Material mat = fem::Material::FromYoungPoisson(1e4, 0.3, 1000.0);
    const fem::Model<double> model(box, std::span(&mat, 1));
    const fem::State<double> state(model);
    double t = 0.0;
    int samples = 0;
    while (t < 1.0 - 1e-9) {
      t += dt;
      if (meter.SampleDue(t)) {
        meter.Sample(model, state.x.data(), {}, t);
        ++samples;
      }
    }
    // One per period boundary crossed, plus the first frame's.
    EXPECT_NEAR(samples, 20, 1) << "dt " << dt;
    EXPECT_EQ(meter.metrics().stress_samples(), samples);
  }
}

/// Cauchy von Mises of StVK under x = F·X, from the definitions.
double AnalyticVonMises(const Eigen::Matrix3d& F, double lambda, double mu) {
  const Eigen::Matrix3d E = 0.5 * (F.transpose() * F - Eigen::Matrix3d::Identity());
  const Eigen::Matrix3d S = lambda * E.trace() * Eigen::Matrix3d::Identity() + 2.0 * mu * E;
  const Eigen::Matrix3d sigma = F * S * F.transpose() / F.determinant();
  const double sxx = sigma(0, 0), syy = sigma(1, 1), szz = sigma(2, 2);
  return std::sqrt(0.5 * ((sxx - syy) * (sxx - syy) + (syy - szz) * (syy - szz) + (szz - sxx) * (szz - sxx)) +
                   3.0 * (sigma(0, 1) * sigma(0, 1) + sigma(1, 2) * sigma(1, 2) + sigma(0, 2) * sigma(0, 2)));
}

TEST(SessionMeter, HomogeneousStretchGivesTheAnalyticStress) {
  const mesh::TetMesh box = mesh::MakeBox({0, 0, 0}, {0.04, 0.02, 0.02}, 4, 2, 2);
  const fem::Material mat = fem::Material::FromYoungPoisson(3e4, 0.3, 1000.0);
  const fem::Model<double> model(box, std::span(&mat, 1));
  fem::State<double> state(model);
  Eigen::Matrix3d F;
  F << 1.12, 0.05, 0.0, 0.0, 0.97, 0.02, 0.01, 0.0, 1.03;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d X = box.nodes.row(n).transpose();
    const Eigen::Vector3d x = F * X;
    for (int k = 0; k < 3; ++k) state.x[3 * static_cast<size_t>(n) + static_cast<size_t>(k)] = x[k];
  }
  Meter meter({});
  meter.Sample(model, state.x.data(), {}, 0.0);
  const double expected = AnalyticVonMises(F, mat.lambda, mat.mu);
  EXPECT_NEAR(meter.metrics().stress_outside(), expected, 1e-9 * expected);
  EXPECT_EQ(meter.metrics().max_stress_outside(), meter.metrics().stress_outside());
  EXPECT_GT(expected, 100.0);  // not vacuous
}

/// A box with one node pulled far out: the stress peaks in the tets on it.
struct PulledNode {
  mesh::TetMesh box = mesh::MakeBox({0, 0, 0}, {0.03, 0.03, 0.03}, 3, 3, 3);
  fem::Material mat = fem::Material::FromYoungPoisson(1e4, 0.3, 1000.0);
  fem::Model<double> model{box, std::span(&mat, 1)};
  fem::State<double> state{model};
  int32_t node = -1;
  std::vector<double> von_mises;

  PulledNode() {
    // The interior node nearest the centre.
    double best = std::numeric_limits<double>::infinity();
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const double d = (box.nodes.row(n).transpose() - Eigen::Vector3d(0.015, 0.015, 0.015)).norm();
      if (d < best) best = d, node = n;
    }
    state.x[3 * static_cast<size_t>(node)] += 0.004;
    von_mises.resize(static_cast<size_t>(model.num_tets()));
    fem::ComputeElementStresses<double>(model, state.x.data(), {}, {}, std::span<double>(von_mises));
  }

  bool OnNode(int32_t t) const {
    for (int k = 0; k < 4; ++k) {
      if (model.tet_node(t, k) == node) return true;
    }
    return false;
  }
};

TEST(SessionMeter, IncisionExcludesTheTetsOnItsNodes) {
  PulledNode p;
  const double global = *std::max_element(p.von_mises.begin(), p.von_mises.end());
  double away = 0.0;  // brute force: the tets not on the node
  for (int32_t t = 0; t < p.model.num_tets(); ++t) {
    if (!p.OnNode(t)) away = std::max(away, p.von_mises[static_cast<size_t>(t)]);
  }
  ASSERT_LT(away, 0.9 * global);  // the pull is local: the case can tell them apart

  Meter plain({});
  plain.Sample(p.model, p.state.x.data(), {}, 0.0);
  EXPECT_DOUBLE_EQ(plain.metrics().stress_outside(), global);

  Meter contact({.incision_rings = 0});
  IncisionView at_blade;
  at_blade.contact_nodes = {p.node, -1, -1};
  contact.Sample(p.model, p.state.x.data(), at_blade, 0.0);
  EXPECT_DOUBLE_EQ(contact.metrics().stress_outside(), away);

  Meter wall({.incision_rings = 0});
  std::vector<uint8_t> walls(static_cast<size_t>(p.model.num_nodes()), 0);
  walls[static_cast<size_t>(p.node)] = 1;
  wall.Sample(p.model, p.state.x.data(), {.wall_nodes = walls}, 0.0);
  EXPECT_DOUBLE_EQ(wall.metrics().stress_outside(), away);

  // One more ring only removes tets: the reading cannot rise.
  Meter ringed({.incision_rings = 1});
  ringed.Sample(p.model, p.state.x.data(), at_blade, 0.0);
  EXPECT_LE(ringed.metrics().stress_outside(), away);
}

/// Two boxes side by side with no shared face: two pieces.
mesh::TetMesh TwoPieces() {
  const mesh::TetMesh a = mesh::MakeBox({0, 0, 0}, {0.02, 0.02, 0.02}, 2, 2, 2);
  const mesh::TetMesh b = mesh::MakeBox({0.03, 0, 0}, {0.04, 0.01, 0.01}, 1, 1, 1);
  mesh::TetMesh m;
  m.nodes.resize(a.num_nodes() + b.num_nodes(), 3);
  m.nodes << a.nodes, b.nodes;
  m.tets.resize(a.num_tets() + b.num_tets(), 4);
  m.tets << a.tets, (b.tets.array() + a.num_nodes()).matrix();
  return m;
}

double Volume(const fem::Model<double>& model, int32_t first, int32_t last) {
  double v = 0.0;
  for (int32_t t = first; t < last; ++t) v += model.rest_volume(t);
  return v;
}

TEST(SessionMeter, CutOffVolumeIsThePiecesAwayFromTheAnchor) {
  const mesh::TetMesh m = TwoPieces();
  const int32_t first_b = mesh::MakeBox({0, 0, 0}, {0.02, 0.02, 0.02}, 2, 2, 2).num_tets();
  const fem::Material mat = fem::Material::FromYoungPoisson(1e4, 0.3, 1000.0);
  const cutting::CutMesh cut(m);

  // None fixed: the larger piece is the body.
  fem::Model<double> model(m, std::span(&mat, 1));
  fem::State<double> state(model);
  Meter free_body({});
  free_body.Sample(model, state.x.data(), {.cut = &cut}, 0.0);
  EXPECT_NEAR(free_body.metrics().cut_off_volume(), Volume(model, first_b, model.num_tets()), 1e-15);

  // The small piece anchored: the large one is what was cut off.
  fem::Model<double> anchored(m, std::span(&mat, 1));
  anchored.SetFixed(m.num_nodes() - 1, true);
  Meter held({});
  held.Sample(anchored, state.x.data(), {.cut = &cut}, 0.0);
  EXPECT_NEAR(held.metrics().cut_off_volume(), Volume(anchored, 0, first_b), 1e-15);

  // The stress of a piece cut off does not count: pull a node of it.
  state.x[3 * static_cast<size_t>(m.num_nodes() - 1)] += 0.003;
  Meter away({});
  away.Sample(model, state.x.data(), {.cut = &cut}, 0.0);
  // The pulled piece is under kPa; the body keeps round-off only (FMA
  // builds round its rest state to ~1e-13 Pa).
  EXPECT_LT(away.metrics().stress_outside(), 1e-6);
}

TEST(SessionMeter, RestoreCarriesTheMeasuresOn) {
  Meter a({});
  for (int i = 0; i < 30; ++i) a.AddFrame(0.01, ToolAt({0.001 * i, 0, 0}, true, {0, 0, 0.1 * i}));
  Meter b({});
  b.Restore(a.metrics(), a.force_series(), 0.3, a.running());
  EXPECT_FALSE(b.SampleDue(0.3));  // the period's sample was taken before the save
  for (int i = 30; i < 60; ++i) {
    a.AddFrame(0.01, ToolAt({0.001 * i, 0, 0}, true, {0, 0, 0.1 * i}));
    b.AddFrame(0.01, ToolAt({0.001 * i, 0, 0}, true, {0, 0, 0.1 * i}));
  }
  // The restored meter knows the tip before the save: no chord is lost.
  EXPECT_NEAR(b.metrics().path_length(), a.metrics().path_length(), 1e-12);
  EXPECT_DOUBLE_EQ(b.metrics().peak_force(), a.metrics().peak_force());
  EXPECT_NEAR(b.metrics().force_impulse(), a.metrics().force_impulse(), 1e-12);
}

TEST(SessionMetricsProto, RoundTripsAndRefusesBadFields) {
  v1::SessionMetrics p;
  p.set_peak_force(2.0);
  p.set_mean_force(1.0);
  p.set_force_impulse(0.5);
  p.set_path_length(0.1);
  p.set_contact_time(0.5);
  p.set_cut_off_volume(1e-6);
  p.set_opened_area(2e-4);
  p.set_max_stress_outside(3e3);
  p.set_stress_outside(1e3);
  p.set_stress_samples(7);
  const SessionMetrics back = SessionMetricsFromProto(p, "ckpt");
  EXPECT_EQ(back.SerializeAsString(), p.SerializeAsString());

  // Every field, whichever the message holds, is checked by name.
  const google::protobuf::Descriptor* descriptor = v1::SessionMetrics::descriptor();
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* f = descriptor->field(i);
    ASSERT_EQ(f->cpp_type(), google::protobuf::FieldDescriptor::CPPTYPE_DOUBLE) << f->name();
    v1::SessionMetrics negative = p;
    negative.GetReflection()->SetDouble(&negative, f, -1.0);
    try {
      (void)SessionMetricsFromProto(negative, "ckpt");
      ADD_FAILURE() << f->name() << " = -1 accepted";
    } catch (const InputError& e) {
      EXPECT_NE(std::string(e.what()).find("metrics." + f->name()), std::string::npos) << e.what();
    }
  }

  v1::SessionMetrics bad = p;
  bad.set_path_length(std::nan(""));
  try {
    (void)SessionMetricsFromProto(bad, "ckpt");
    FAIL() << "NaN accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("metrics.path_length"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("ckpt"), std::string::npos) << e.what();
  }
  bad = p;
  bad.set_mean_force(3.0);  // above the peak
  EXPECT_THROW((void)SessionMetricsFromProto(bad, "ckpt"), InputError);
  bad = p;
  bad.set_contact_time(-1.0);
  EXPECT_THROW((void)SessionMetricsFromProto(bad, "ckpt"), InputError);
}

TEST(SummaryToReport, FillsEveryFieldOfTheHeadlessSummaryFromTheSummary) {
  // Every scalar field of the headless summary (the metrics and score are
  // messages of their own) has its entry in the summary's table: a field
  // added to the report without one fails here instead of printing zero.
  const std::vector<std::string> names = SummaryFieldNames();
  const google::protobuf::Descriptor* d = v1::HeadlessSummary::descriptor();
  for (int i = 0; i < d->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* f = d->field(i);
    if (f->cpp_type() == google::protobuf::FieldDescriptor::CPPTYPE_MESSAGE) continue;
    EXPECT_NE(std::find(names.begin(), names.end(), f->name()), names.end()) << f->name();
  }

  SimulationSummary s;
  s.scene = "block";
  s.num_tets = 384;
  s.frames = int64_t{1} << 40;  // saturates in a uint32 count
  s.sim_time = 2.5;
  s.at_rest = true;
  s.cuts = 7;
  s.status = kStatusUnconverged;
  s.implicit.max_pcg_iterations = 31;
  s.implicit.max_correction_seconds = 0.004;
  v1::HeadlessSummary r;
  SummaryToReport(s, &r);
  EXPECT_EQ(r.scene(), "block");
  EXPECT_EQ(r.tets(), 384u);
  EXPECT_EQ(r.frames(), std::numeric_limits<uint32_t>::max());
  EXPECT_EQ(r.sim_time(), 2.5);
  EXPECT_TRUE(r.at_rest());
  EXPECT_EQ(r.cuts(), 7u);
  EXPECT_EQ(r.status(), kStatusUnconverged);
  EXPECT_EQ(r.max_pcg_iterations(), 31u);
  EXPECT_EQ(r.max_correction_seconds(), 0.004);

  // The server's statistics take the entries they name and keep the rest.
  v1::ServerSessionStats stats;
  stats.set_session("s1");
  SummaryToReport(s, &stats);
  EXPECT_EQ(stats.session(), "s1");
  EXPECT_EQ(stats.cuts(), 7u);
  EXPECT_EQ(stats.max_correction_seconds(), 0.004);
}

}  // namespace
}  // namespace cutsim::sim
