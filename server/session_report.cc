#include "server/session_report.h"

#include <algorithm>
#include <cmath>
#include <filesystem>

#include <fmt/format.h>

#include "common/core/input_file.h"
#include "common/sim/metrics_proto.h"
#include "common/transport/proto_vec.h"
#include "common/transport/report_json.h"

namespace cutsim::server {

void FillObservedSession(const sim::Simulation& simulation, v1::ObserverSession* observed) {
  *observed->mutable_metrics() = simulation.Metrics();
  if (!simulation.has_tool()) return;
  const sim::ToolReport tool = simulation.Tool();
  observed->set_cuts(tool.cuts);
  v1::ToolView* view = observed->add_tools();
  transport::SetVec3(tool.pose.tip, view->mutable_tip());
  transport::SetVec3(tool.pose.blade_dir, view->mutable_blade_dir());
  view->set_blade_length(tool.blade_length);
  transport::SetVec3(tool.force_on_tool, view->mutable_force());
  view->set_contact(tool.touching);
}

v1::SessionReport MakeSessionReport(const sim::Simulation& simulation, const std::string& session,
                                    const std::string& scene) {
  v1::SessionReport r;
  r.set_session(session);
  r.set_scene(scene);
  r.set_sim_time(simulation.sim_time());
  const sim::SimulationSummary summary = simulation.QuickSummary();
  r.set_status(summary.status);
  r.set_diagnosis(summary.diagnosis);
  r.set_unconverged_steps(transport::ReportCount(summary.implicit.unconverged_steps));
  r.set_max_residual_unconverged(summary.implicit.max_residual_unconverged);
  *r.mutable_metrics() = simulation.Metrics();
  for (const sim::ForceSample& f : simulation.ForceSeries()) {
    r.add_force_t(f.t);
    r.add_force_n(f.force);
  }
  if (const std::optional<sim::IncisionScore> score = simulation.Score()) {
    *r.mutable_score() = *score;
    for (const sim::CutPoint& c : simulation.ScoredCutPoints()) {
      r.add_cut_t(c.t);
      r.add_cut_deviation(c.deviation);
    }
    r.set_planned_depth(simulation.Plan()->depth);
    r.set_tolerance(simulation.Plan()->tolerance);
  }
  return r;
}

namespace {

/// `text` with the five XML specials escaped.
std::string Xml(const std::string& text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '&': out += "&amp;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default: out += c;
    }
  }
  return out;
}

/// A "nice" axis top ≥ v: 1, 2 or 5 × 10^k.
double NiceTop(double v) {
  if (!(v > 0.0)) return 1.0;
  const double p = std::pow(10.0, std::floor(std::log10(v)));
  for (const double m : {1.0, 2.0, 5.0, 10.0}) {
    if (m * p >= v) return m * p;
  }
  return 10.0 * p;
}

struct Panel {
  double x0, y0, w, h;  // px
  double t_end;         // s
  double v_top;         // value at the top edge
  [[nodiscard]] double X(double t) const { return x0 + w * std::clamp(t / t_end, 0.0, 1.0); }
  [[nodiscard]] double Y(double v) const { return y0 + h * (1.0 - std::clamp(v / v_top, 0.0, 1.0)); }
};

void Axes(std::string& svg, const Panel& p, const std::string& label, double scale, const char* unit) {
  svg += fmt::format(R"(<rect x="{}" y="{}" width="{}" height="{}" fill="none" stroke="#888"/>)", p.x0, p.y0, p.w,
                     p.h);
  for (int k = 0; k <= 4; ++k) {
    const double v = p.v_top * k / 4.0;
    const double y = p.Y(v);
    svg += fmt::format(R"(<line x1="{}" y1="{:.1f}" x2="{}" y2="{:.1f}" stroke="#ddd"/>)", p.x0, y, p.x0 + p.w, y);
    svg += fmt::format(R"(<text x="{}" y="{:.1f}" text-anchor="end" font-size="11">{:.3g}</text>)", p.x0 - 4,
                       y + 4, v * scale);
  }
  for (int k = 0; k <= 5; ++k) {
    const double t = p.t_end * k / 5.0;
    svg += fmt::format(R"(<text x="{:.1f}" y="{}" text-anchor="middle" font-size="11">{:.3g}</text>)", p.X(t),
                       p.y0 + p.h + 14, t);
  }
  svg += fmt::format(R"(<text x="{}" y="{}" font-size="12" font-weight="bold">{} ({})</text>)", p.x0, p.y0 - 6,
                     label, unit);
}

}  // namespace

std::string SessionPlotSvg(const v1::SessionReport& r) {
  constexpr double kWidth = 760, kHeight = 460;
  const double t_end = std::max({r.sim_time(), r.force_t().empty() ? 0.0 : r.force_t(r.force_t_size() - 1), 1e-3});
  double f_max = 0.0;
  for (const double f : r.force_n()) f_max = std::max(f_max, f);
  std::string svg = fmt::format(
      R"(<svg xmlns="http://www.w3.org/2000/svg" width="{}" height="{}" font-family="sans-serif">)"
      R"(<rect width="100%" height="100%" fill="white"/>)",
      kWidth, kHeight);
  svg += fmt::format(R"(<text x="60" y="20" font-size="14">session {} — scene {}, {:.2f} s</text>)", Xml(r.session()),
                     Xml(r.scene()), r.sim_time());
  // A plot of an answer that does not hold says so above the plot.
  if (!r.status().empty() && r.status() != sim::kStatusOk) {
    svg += fmt::format(R"(<text x="60" y="36" font-size="12" fill="#c33">status {}: {}</text>)", Xml(r.status()),
                       Xml(r.diagnosis()));
  }

  const Panel force{.x0 = 60, .y0 = 50, .w = 680, .h = 150, .t_end = t_end, .v_top = NiceTop(f_max)};
  Axes(svg, force, "|f| on the tool", 1.0, "N");
  if (r.force_t_size() > 0) {
    svg += R"(<polyline fill="none" stroke="#2a8f3f" stroke-width="1.5" points=")";
    for (int i = 0; i < r.force_t_size(); ++i) svg += fmt::format("{:.1f},{:.1f} ", force.X(r.force_t(i)), force.Y(r.force_n(i)));
    svg += R"("/>)";
  }

  const Panel dev{.x0 = 60, .y0 = 260, .w = 680, .h = 150, .t_end = t_end, .v_top = 1.0};
  if (r.has_score()) {
    double d_max = r.tolerance();
    for (const double d : r.cut_deviation()) d_max = std::max(d_max, d);
    Panel p = dev;
    p.v_top = NiceTop(1.2 * d_max);
    Axes(svg, p, "deviation of each cut step from the plan", 1e3, "mm");
    const double band = p.Y(r.tolerance());
    svg += fmt::format(R"(<line x1="{}" y1="{:.1f}" x2="{}" y2="{:.1f}" stroke="#c33" stroke-dasharray="6 4"/>)", p.x0,
                       band, p.x0 + p.w, band);
    svg += fmt::format(R"(<text x="{}" y="{:.1f}" text-anchor="end" font-size="11" fill="#c33">tolerance</text>)",
                       p.x0 + p.w - 4, band - 4);
    for (int i = 0; i < r.cut_t_size(); ++i) {
      svg += fmt::format(R"(<circle cx="{:.1f}" cy="{:.1f}" r="2.5" fill="#2650a8"/>)", p.X(r.cut_t(i)),
                         p.Y(r.cut_deviation(i)));
    }
    const v1::IncisionScore& s = r.score();
    svg += fmt::format(R"(<text x="60" y="{}" font-size="12">mean {:.2f} mm, max {:.2f} mm, depth error {:+.2f} mm, )"
                       R"(coverage {:.0f} %, opened outside {:.1f} mm²</text>)",
                       kHeight - 12, 1e3 * s.mean_deviation(), 1e3 * s.max_deviation(), 1e3 * s.depth_error(),
                       100.0 * s.coverage(), 1e6 * s.opened_area_outside());
  } else {
    svg += fmt::format(R"(<text x="60" y="{}" font-size="12">no planned incision in the scene: no deviation</text>)",
                       dev.y0 + 20);
  }
  svg += "</svg>\n";
  return svg;
}

std::string SessionPlotPath(const std::string& path) {
  std::filesystem::path svg(path);
  svg.replace_extension(".svg");
  return svg.string();
}

void WriteSessionReport(const std::string& path, const v1::SessionReport& report) {
  WriteFileAtomically(path, transport::ReportJson(report) + "\n");
  WriteFileAtomically(SessionPlotPath(path), SessionPlotSvg(report));
}

}  // namespace cutsim::server
