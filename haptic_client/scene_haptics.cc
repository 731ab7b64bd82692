#include "haptic_client/scene_haptics.h"

#include <cmath>
#include <fstream>
#include <sstream>
#include <string>

#include <fmt/format.h>
#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include "common/core/error.h"
#include "cutsim/v1/scene.pb.h"

namespace cutsim::haptic_client {
namespace {

class FirstError : public google::protobuf::io::ErrorCollector {
 public:
  void AddError(int at_line, google::protobuf::io::ColumnNumber at_column, const std::string& what) override {
    if (has_error) return;
    has_error = true;
    line = at_line;
    column = at_column;
    message = what;
  }
  void AddWarning(int, google::protobuf::io::ColumnNumber, const std::string&) override {}
  bool has_error = false;
  int line = 0;
  int column = 0;
  std::string message;
};

}  // namespace

SceneWorkspace ReadSceneWorkspace(const std::filesystem::path& scene) {
  const std::string file = scene.string();
  std::ifstream in(scene, std::ios::binary);
  if (!in) ThrowFileError(file, "cannot open scene file (--scene)");
  std::ostringstream text;
  text << in.rdbuf();
  v1::Scene msg;
  google::protobuf::TextFormat::Parser parser;
  FirstError errors;
  parser.RecordErrorsTo(&errors);
  if (!parser.ParseFromString(text.str(), &msg)) {
    ThrowInputError(SourceRef{.file = file, .line = errors.line + 1, .column = errors.column + 1},
                    errors.has_error ? errors.message : "cannot parse scene");
  }
  const v1::HapticParams& h = msg.haptics();
  SceneWorkspace w;
  w.scale = h.device_scale() == 0.0 ? 1.0 : h.device_scale();
  if (!(std::isfinite(w.scale) && w.scale > 0.0)) {
    ThrowInputError(SourceRef{.file = file, .field = "haptics.device_scale"}, fmt::format("{} must be > 0", w.scale));
  }
  w.offset = {h.device_offset().x(), h.device_offset().y(), h.device_offset().z()};
  if (!w.offset.allFinite()) {
    ThrowInputError(SourceRef{.file = file, .field = "haptics.device_offset"}, "must be finite");
  }
  constexpr int kMaxPlanPoints = 10000;
  const auto& points = msg.planned_incision().points();
  if (points.size() > kMaxPlanPoints) {
    ThrowInputError(SourceRef{.file = file, .field = "planned_incision.points"},
                    fmt::format("{} points; at most {}", points.size(), kMaxPlanPoints));
  }
  for (int i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p(points[i].x(), points[i].y(), points[i].z());
    if (!(p.allFinite() && p.cwiseAbs().maxCoeff() <= 1e3)) {
      ThrowInputError(SourceRef{.file = file, .field = fmt::format("planned_incision.points[{}]", i)},
                      "must be finite and within 1000 m");
    }
    w.planned_incision.push_back(p);
  }
  w.blade_length = msg.tool().blade_length();
  if (!(std::isfinite(w.blade_length) && w.blade_length >= 0.0 && w.blade_length < 1.0)) {
    ThrowInputError(SourceRef{.file = file, .field = "tool.blade_length"},
                    fmt::format("{} m is out of range [0, 1) m", w.blade_length));
  }
  return w;
}

}  // namespace cutsim::haptic_client
