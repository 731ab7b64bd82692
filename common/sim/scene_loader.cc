#include "common/sim/scene_loader.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <tuple>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <google/protobuf/io/tokenizer.h>
#include <google/protobuf/text_format.h>

#include "common/core/error.h"
#include "common/core/input_file.h"
#include "common/mesh/generators.h"

namespace cutsim::sim {
namespace {

/// Newton iterations a scene may ask of one implicit step: beyond this a
/// frame's cost has no useful bound.
constexpr int kMaxNewtonIterations = 200;

namespace pb = google::protobuf;

/// Keeps the first parse error with its position (protobuf reports 0-based).
class FirstErrorCollector : public pb::io::ErrorCollector {
 public:
  void AddError(int line, pb::io::ColumnNumber column, const std::string& message) override {
    if (!has_error_) {
      has_error_ = true;
      line_ = line;
      column_ = column;
      message_ = message;
    }
  }
  void AddWarning(int, pb::io::ColumnNumber, const std::string&) override {}

  bool has_error_ = false;
  int line_ = 0;
  int column_ = 0;
  std::string message_;
};

[[noreturn]] void FieldError(const std::string& source, const std::string& field,
                             const std::string& message) {
  ThrowInputError({.file = source, .field = field}, message);
}

void RequireFinite(const std::string& source, const std::string& field, double value) {
  if (!std::isfinite(value)) FieldError(source, field, "must be finite");
}

void RequirePositive(const std::string& source, const std::string& field, double value) {
  RequireFinite(source, field, value);
  if (value <= 0.0) FieldError(source, field, fmt::format("must be > 0 (got {})", value));
}

void RequireNonNegative(const std::string& source, const std::string& field, double value) {
  RequireFinite(source, field, value);
  if (value < 0.0) FieldError(source, field, fmt::format("must be >= 0 (got {})", value));
}

/// A finite value at most `limit` (in `unit`).
void RequireAtMost(const std::string& source, const std::string& field, double value, double limit,
                   const char* unit) {
  RequireFinite(source, field, value);
  if (value > limit) FieldError(source, field, fmt::format("{:g} {} is above {:g} {}", value, unit, limit, unit));
}

/// A vector with every component finite and within ±`limit` (positions by
/// default: ±kMaxCoordinate m).
void RequireFiniteVec(const std::string& source, const std::string& field, const cutsim::v1::Vec3& v,
                      double limit = kMaxCoordinate, const char* unit = "m") {
  for (const auto& [axis, value] : {std::pair{".x", v.x()}, std::pair{".y", v.y()}, std::pair{".z", v.z()}}) {
    RequireFinite(source, field + axis, value);
    if (std::abs(value) > limit) {
      FieldError(source, field + axis, fmt::format("{:g} {} is outside ±{:g} {}", value, unit, limit, unit));
    }
  }
}

double Norm(const cutsim::v1::Vec3& v) {
  return std::sqrt(v.x() * v.x() + v.y() * v.y() + v.z() * v.z());
}

void ValidateMesh(cutsim::v1::MeshSource& mesh, const std::string& s) {
  using MS = cutsim::v1::MeshSource;
  switch (mesh.source_case()) {
    case MS::SOURCE_NOT_SET:
      FieldError(s, "mesh", "a mesh source is required (file, box, cylinder or surface)");
    case MS::kFile:
      if (mesh.file().empty()) FieldError(s, "mesh.file", "must name a file");
      break;
    case MS::kBox: {
      const auto& b = mesh.box();
      RequireFiniteVec(s, "mesh.box.min", b.min());
      RequireFiniteVec(s, "mesh.box.max", b.max());
      if (!(b.max().x() > b.min().x() && b.max().y() > b.min().y() && b.max().z() > b.min().z())) {
        FieldError(s, "mesh.box", "max must exceed min on every axis");
      }
      if (b.nx() < 1 || b.ny() < 1 || b.nz() < 1) {
        FieldError(s, "mesh.box.nx/ny/nz", "cell counts must be >= 1");
      }
      mesh::CheckGeneratedSize({.file = s, .field = "mesh.box.nx/ny/nz"},
                               (b.nx() + 1.0) * (b.ny() + 1.0) * (b.nz() + 1.0), 6.0 * b.nx() * b.ny() * b.nz());
      break;
    }
    case MS::kCylinder: {
      const auto& c = mesh.cylinder();
      RequirePositive(s, "mesh.cylinder.radius", c.radius());
      RequirePositive(s, "mesh.cylinder.length", c.length());
      if (c.segments() < 3) FieldError(s, "mesh.cylinder.segments", "must be >= 3");
      if (c.rings() < 1) FieldError(s, "mesh.cylinder.rings", "must be >= 1");
      if (c.slices() < 1) FieldError(s, "mesh.cylinder.slices", "must be >= 1");
      mesh::CheckGeneratedSize({.file = s, .field = "mesh.cylinder.segments/rings/slices"},
                               (1.0 + 0.5 * c.segments() * (c.rings() + 1.0)) * (c.slices() + 1.0),
                               3.0 * c.segments() * (c.rings() + 1.0) * c.slices());
      break;
    }
    case MS::kSurface:
      if (mesh.surface().file().empty()) FieldError(s, "mesh.surface.file", "must name a file");
      RequirePositive(s, "mesh.surface.max_edge_length", mesh.surface().max_edge_length());
      break;
    case MS::kOrgan: {
      auto& o = *mesh.mutable_organ();
      RequireFiniteVec(s, "mesh.organ.semi_axes", o.semi_axes());
      if (o.semi_axes().x() <= 0 || o.semi_axes().y() <= 0 || o.semi_axes().z() <= 0) {
        FieldError(s, "mesh.organ.semi_axes", "must be > 0 on every axis");
      }
      RequirePositive(s, "mesh.organ.edge_length", o.edge_length());
      RequireFinite(s, "mesh.organ.bean_depth", o.bean_depth());
      if (o.bean_depth() < 0.0 || o.bean_depth() > 0.6) {
        FieldError(s, "mesh.organ.bean_depth", "must lie in [0, 0.6]");
      }
      const double smallest = std::min({o.semi_axes().x(), o.semi_axes().y(), o.semi_axes().z()});
      if (o.edge_length() > smallest) {
        FieldError(s, "mesh.organ.edge_length", "must not exceed the smallest semi-axis");
      }
      // A regular tet of edge h has volume h³/(6√2); the mesher's are smaller.
      const double volume = 4.0 / 3.0 * std::numbers::pi * o.semi_axes().x() * o.semi_axes().y() * o.semi_axes().z();
      const double tets = 2.0 * volume / (std::pow(o.edge_length(), 3) / (6.0 * std::numbers::sqrt2));
      mesh::CheckGeneratedSize({.file = s, .field = "mesh.organ.edge_length"}, tets / 4.0, tets);
      break;
    }
  }
  if (mesh.scale() == 0.0) mesh.set_scale(1.0);
  RequirePositive(s, "mesh.scale", mesh.scale());
  if (mesh.scale() < kMinScale || mesh.scale() > kMaxScale) {
    FieldError(s, "mesh.scale", fmt::format("{:g} is outside [{:g}, {:g}]", mesh.scale(), kMinScale, kMaxScale));
  }
  RequireFiniteVec(s, "mesh.translate", mesh.translate());
}

void ValidateMaterial(cutsim::v1::Material& m, const std::string& s, int index) {
  const std::string f = fmt::format("materials[{}]", index);
  using M = cutsim::v1::Material;
  switch (m.elasticity_case()) {
    case M::ELASTICITY_NOT_SET:
      FieldError(s, f, "needs `lame` or `young_poisson`");
    case M::kLame:
      RequireNonNegative(s, f + ".lame.lambda", m.lame().lambda());
      RequirePositive(s, f + ".lame.mu", m.lame().mu());
      break;
    case M::kYoungPoisson: {
      RequirePositive(s, f + ".young_poisson.youngs_modulus", m.young_poisson().youngs_modulus());
      const double nu = m.young_poisson().poisson_ratio();
      RequireFinite(s, f + ".young_poisson.poisson_ratio", nu);
      if (!(nu > -1.0 && nu < 0.5)) {
        FieldError(s, f + ".young_poisson.poisson_ratio",
                   fmt::format("must lie in (-1, 0.5) (got {})", nu));
      }
      break;
    }
  }
  RequirePositive(s, f + ".density", m.density());
  RequireNonNegative(s, f + ".damping_psi", m.damping_psi());
  RequireNonNegative(s, f + ".damping_phi", m.damping_phi());
  if (m.has_box()) {
    if (m.regions_size() > 0) FieldError(s, f + ".box", "a material selects its tets by `regions` or by `box`, not both");
    RequireFiniteVec(s, f + ".box.min", m.box().min());
    RequireFiniteVec(s, f + ".box.max", m.box().max());
    const auto& lo = m.box().min();
    const auto& hi = m.box().max();
    if (!(hi.x() > lo.x() && hi.y() > lo.y() && hi.z() > lo.z())) {
      FieldError(s, f + ".box", "max must exceed min on every axis");
    }
  }
}

/// The kind of a boundary condition and the fields it reads: a field that
/// another kind reads is refused rather than ignored.
void ValidateBoundaryKind(const cutsim::v1::BoundaryCondition& bc, const std::string& s, const std::string& f) {
  using BC = cutsim::v1::BoundaryCondition;
  if (!BC::Kind_IsValid(bc.kind())) {
    FieldError(s, f + ".kind", fmt::format("unknown value {}", static_cast<int>(bc.kind())));
  }
  RequireFiniteVec(s, f + ".force", bc.force(), kMaxBoundaryForce, "N");
  RequireFiniteVec(s, f + ".displacement", bc.displacement(), kMaxBoundaryDisplacement, "m");
  RequireNonNegative(s, f + ".ramp_time", bc.ramp_time());
  if (bc.ramp_time() > kMaxSimSeconds) {
    FieldError(s, f + ".ramp_time", fmt::format("{:g} s is above {:g} s", bc.ramp_time(), kMaxSimSeconds));
  }
  const bool has_force = bc.has_force() && Norm(bc.force()) > 0.0;
  const bool has_displacement = bc.has_displacement() && Norm(bc.displacement()) > 0.0;
  if (has_force && bc.kind() != BC::KIND_FORCE) {
    FieldError(s, f + ".force", "is only read with kind: KIND_FORCE");
  }
  if (bc.kind() != BC::KIND_DISPLACEMENT) {
    if (has_displacement) FieldError(s, f + ".displacement", "is only read with kind: KIND_DISPLACEMENT");
    if (bc.ramp_time() > 0.0) FieldError(s, f + ".ramp_time", "is only read with kind: KIND_DISPLACEMENT");
  }
}

}  // namespace

/// The planned incision: 2 to kMaxPlanPoints finite points with a
/// non-degenerate extent, a unit normal (defaulted to +z, normalised),
/// depth > 0 and a tolerance > 0 (defaulted to 2 mm).
void ValidatePlannedIncision(cutsim::v1::PlannedIncision& p, const std::string& s) {
  constexpr int kMaxPlanPoints = 10000;
  if (p.points_size() < 2 || p.points_size() > kMaxPlanPoints) {
    FieldError(s, "planned_incision.points", fmt::format("needs 2 to {} points (got {})", kMaxPlanPoints, p.points_size()));
  }
  double length = 0.0;
  for (int i = 0; i < p.points_size(); ++i) {
    RequireFiniteVec(s, fmt::format("planned_incision.points[{}]", i), p.points(i));
    if (i > 0) {
      const auto& a = p.points(i - 1);
      const auto& b = p.points(i);
      length += std::hypot(b.x() - a.x(), b.y() - a.y(), b.z() - a.z());
    }
  }
  if (!(length > 1e-6)) FieldError(s, "planned_incision.points", "the line must be longer than 1 µm");
  if (!p.has_normal()) p.mutable_normal()->set_z(1.0);
  RequireFiniteVec(s, "planned_incision.normal", p.normal());
  const double n = Norm(p.normal());
  if (!(n > 1e-9)) FieldError(s, "planned_incision.normal", "must not be zero");
  p.mutable_normal()->set_x(p.normal().x() / n);
  p.mutable_normal()->set_y(p.normal().y() / n);
  p.mutable_normal()->set_z(p.normal().z() / n);
  RequirePositive(s, "planned_incision.depth", p.depth());
  if (p.tolerance() == 0.0) p.set_tolerance(0.002);
  RequirePositive(s, "planned_incision.tolerance", p.tolerance());
}

void ValidateScene(cutsim::v1::Scene& scene, const std::string& s) {
  if (!scene.has_mesh()) FieldError(s, "mesh", "is required");
  ValidateMesh(*scene.mutable_mesh(), s);

  if (scene.materials_size() == 0) FieldError(s, "materials", "at least one material is required");
  int catch_all = 0;
  for (int i = 0; i < scene.materials_size(); ++i) {
    ValidateMaterial(*scene.mutable_materials(i), s, i);
    if (scene.materials(i).regions_size() == 0 && !scene.materials(i).has_box()) ++catch_all;
  }
  if (catch_all > 1) {
    FieldError(s, "materials", "only one material may omit both `regions` and `box` (it covers all other tets)");
  }

  for (int i = 0; i < scene.boundary_size(); ++i) {
    const auto& bc = scene.boundary(i);
    const std::string f = fmt::format("boundary[{}]", i);
    using BC = cutsim::v1::BoundaryCondition;
    switch (bc.selector_case()) {
      case BC::SELECTOR_NOT_SET:
        FieldError(s, f, "needs a selector: nodes, box or plane");
      case BC::kNodes:
        for (int k = 0; k < bc.nodes().ids_size(); ++k) {
          if (bc.nodes().ids(k) < 0) FieldError(s, fmt::format("{}.nodes.ids[{}]", f, k), "must be >= 0");
        }
        break;
      case BC::kBox:
        RequireFiniteVec(s, f + ".box.min", bc.box().min());
        RequireFiniteVec(s, f + ".box.max", bc.box().max());
        break;
      case BC::kPlane:
        RequireFiniteVec(s, f + ".plane.point", bc.plane().point());
        RequireFiniteVec(s, f + ".plane.normal", bc.plane().normal(), kMaxCoordinate, "");
        if (!(Norm(bc.plane().normal()) > 0.0)) FieldError(s, f + ".plane.normal", "must be non-zero");
        RequireNonNegative(s, f + ".plane.tolerance", bc.plane().tolerance());
        break;
    }
    ValidateBoundaryKind(bc, s, f);
  }

  RequireFiniteVec(s, "gravity", scene.gravity(), kMaxGravity, "m/s²");
  RequireNonNegative(s, "mass_damping", scene.mass_damping());

  auto& ts = *scene.mutable_time_step();
  if (ts.safety_factor() == 0.0) ts.set_safety_factor(0.85);
  RequirePositive(s, "time_step.safety_factor", ts.safety_factor());
  if (ts.safety_factor() > 1.0 || ts.safety_factor() < kMinSafetyFactor) {
    FieldError(s, "time_step.safety_factor",
               fmt::format("{:g} is outside [{:g}, 1] (a fraction of the stable limit)", ts.safety_factor(),
                           kMinSafetyFactor));
  }
  RequireNonNegative(s, "time_step.fixed_dt", ts.fixed_dt());
  if (ts.fixed_dt() != 0.0 && ts.fixed_dt() < kMinFixedDt) {
    FieldError(s, "time_step.fixed_dt",
               fmt::format("{:g} s is below {:g} s (more than {:g} steps per simulated second)", ts.fixed_dt(),
                           kMinFixedDt, kMaxStepsPerSimSecond));
  }
  if (ts.frame_dt() == 0.0) ts.set_frame_dt(0.01);
  RequirePositive(s, "time_step.frame_dt", ts.frame_dt());
  if (ts.frame_dt() < kMinFrameDt || ts.frame_dt() > kMaxFrameDt) {
    FieldError(s, "time_step.frame_dt",
               fmt::format("{:g} s is outside [{:g}, {:g}] s", ts.frame_dt(), kMinFrameDt, kMaxFrameDt));
  }
  CheckThreads(ts.threads(), {.file = s, .field = "time_step.threads"});
  if (!v1::TimeStepPolicy::Integrator_IsValid(ts.integrator())) {
    FieldError(s, "time_step.integrator", fmt::format("unknown value {}", static_cast<int>(ts.integrator())));
  }
  if (!v1::TimeStepPolicy::Precision_IsValid(ts.precision())) {
    FieldError(s, "time_step.precision", fmt::format("unknown value {}", static_cast<int>(ts.precision())));
  }
  if (!v1::TimeStepPolicy::Viscosity_IsValid(ts.viscosity())) {
    FieldError(s, "time_step.viscosity", fmt::format("unknown value {}", static_cast<int>(ts.viscosity())));
  }
  if (!v1::Scene::Element_IsValid(scene.element())) {
    FieldError(s, "element", fmt::format("unknown value {}", static_cast<int>(scene.element())));
  }
  if (scene.settle() && ts.precision() == v1::TimeStepPolicy::PRECISION_FLOAT) {
    FieldError(s, "settle", "needs time_step.precision double (the static solve is double precision)");
  }
  if (ts.refresh_every_steps() == 0) ts.set_refresh_every_steps(10);
  if (ts.refresh_every_steps() < 0) FieldError(s, "time_step.refresh_every_steps", "must be > 0");
  auto& im = *ts.mutable_implicit();
  RequireNonNegative(s, "time_step.implicit.force_tolerance", im.force_tolerance());
  if (im.linear_tolerance() == 0.0) im.set_linear_tolerance(1e-4);
  RequirePositive(s, "time_step.implicit.linear_tolerance", im.linear_tolerance());
  if (im.linear_tolerance() >= 1.0) {
    FieldError(s, "time_step.implicit.linear_tolerance", "must be < 1 (a fraction of the Newton residual)");
  }
  if (im.max_newton_iterations() == 0) im.set_max_newton_iterations(20);
  if (im.max_newton_iterations() < 0 || im.max_newton_iterations() > kMaxNewtonIterations) {
    FieldError(s, "time_step.implicit.max_newton_iterations", fmt::format("must be in [1, {}]", kMaxNewtonIterations));
  }

  RequireNonNegative(s, "rest.kinetic_energy", scene.rest().kinetic_energy());
  RequireNonNegative(s, "rest.residual_force", scene.rest().residual_force());

  if (scene.has_tool()) {
    auto& tool = *scene.mutable_tool();
    RequireNonNegative(s, "tool.blade_length", tool.blade_length());
    RequireNonNegative(s, "tool.contact_stiffness", tool.contact_stiffness());
    RequireNonNegative(s, "tool.contact_damping", tool.contact_damping());
    double prev_t = -INFINITY;
    for (int i = 0; i < tool.keyframes_size(); ++i) {
      const auto& k = tool.keyframes(i);
      const std::string f = fmt::format("tool.keyframes[{}]", i);
      RequireFinite(s, f + ".t", k.t());
      if (std::abs(k.t()) > kMaxSimSeconds) {
        FieldError(s, f + ".t", fmt::format("{:g} s is outside ±{:g} s", k.t(), kMaxSimSeconds));
      }
      if (k.t() <= prev_t) FieldError(s, f + ".t", "times must increase strictly");
      prev_t = k.t();
      RequireFiniteVec(s, f + ".tip", k.tip());
      RequireFiniteVec(s, f + ".blade_dir", k.blade_dir(), kMaxCoordinate, "");
    }
  }

  if (scene.has_planned_incision()) ValidatePlannedIncision(*scene.mutable_planned_incision(), s);

  if (scene.has_cutting() && scene.cutting().enabled()) {
    auto& c = *scene.mutable_cutting();
    RequirePositive(s, "cutting.alpha", c.alpha());
    RequirePositive(s, "cutting.kappa", c.kappa());
    RequireFinite(s, "cutting.zeta", c.zeta());
    if (c.zeta() < 0.1 || c.zeta() > 1.0) {
      FieldError(s, "cutting.zeta", fmt::format("must lie in [0.1, 1] (got {})", c.zeta()));
    }
    RequireNonNegative(s, "cutting.critical_stress", c.critical_stress());
    if (c.min_quality() == 0.0) c.set_min_quality(0.05);
    if (!(c.min_quality() > 0.0 && c.min_quality() < 1.0)) {
      FieldError(s, "cutting.min_quality", "must lie in (0, 1)");
    }
  }

  auto& h = *scene.mutable_haptics();
  RequireNonNegative(s, "haptics.decay_per_second", h.decay_per_second());
  if (h.device_scale() == 0.0) h.set_device_scale(1.0);
  RequirePositive(s, "haptics.device_scale", h.device_scale());
  RequireFiniteVec(s, "haptics.device_offset", h.device_offset());
  // The haptic station sets its own limits (the scene never reaches it), so
  // a scene that sets them would have no effect: refused, not ignored.
  for (const auto& [field, value, flag] : {std::tuple{"haptics.watchdog", h.watchdog(), "--watchdog"},
                                           std::tuple{"haptics.max_force", h.max_force(), "--max-force"},
                                           std::tuple{"haptics.max_stiffness", h.max_stiffness(), "--max-stiffness"}}) {
    if (value != 0.0) {
      FieldError(s, field,
                 fmt::format("is not read from the scene: set it on the haptic station (cutsim-haptic {})", flag));
    }
  }
  if (scene.has_outputs()) {
    FieldError(s, "outputs", "is not read from the scene: use cutsim-server --out (final state as .vtu)");
  }
  if (scene.has_camera()) {
    FieldError(s, "camera", "is not read from the scene: the viewer frames the mesh's bounding box");
  }
  CheckMagnitudes(scene, s);
}

void CheckMagnitudes(const cutsim::v1::Scene& scene, const std::string& s) {
  struct Bound {
    std::string field;
    double value;
    double limit;
    const char* unit;
  };
  std::vector<Bound> bounds;
  const auto& mesh = scene.mesh();
  if (mesh.has_cylinder()) {
    bounds.push_back({"mesh.cylinder.radius", mesh.cylinder().radius(), kMaxCoordinate, "m"});
    bounds.push_back({"mesh.cylinder.length", mesh.cylinder().length(), kMaxCoordinate, "m"});
  }
  if (mesh.has_surface()) {
    bounds.push_back({"mesh.surface.max_edge_length", mesh.surface().max_edge_length(), kMaxCoordinate, "m"});
  }
  if (mesh.has_organ()) bounds.push_back({"mesh.organ.edge_length", mesh.organ().edge_length(), kMaxCoordinate, "m"});
  for (int i = 0; i < scene.materials_size(); ++i) {
    const auto& m = scene.materials(i);
    const std::string f = fmt::format("materials[{}]", i);
    if (m.has_lame()) {
      bounds.push_back({f + ".lame.lambda", m.lame().lambda(), kMaxModulus, "Pa"});
      bounds.push_back({f + ".lame.mu", m.lame().mu(), kMaxModulus, "Pa"});
    } else {
      bounds.push_back({f + ".young_poisson.youngs_modulus", m.young_poisson().youngs_modulus(), kMaxModulus, "Pa"});
    }
    bounds.push_back({f + ".density", m.density(), kMaxDensity, "kg/m³"});
    bounds.push_back({f + ".damping_psi", m.damping_psi(), kMaxViscosity, "Pa·s"});
    bounds.push_back({f + ".damping_phi", m.damping_phi(), kMaxViscosity, "Pa·s"});
  }
  for (int i = 0; i < scene.boundary_size(); ++i) {
    if (!scene.boundary(i).has_plane()) continue;
    bounds.push_back({fmt::format("boundary[{}].plane.tolerance", i), scene.boundary(i).plane().tolerance(),
                      kMaxCoordinate, "m"});
  }
  bounds.push_back({"mass_damping", scene.mass_damping(), kMaxRate, "1/s"});
  bounds.push_back({"time_step.implicit.force_tolerance", scene.time_step().implicit().force_tolerance(),
                    kMaxBoundaryForce, "N"});
  bounds.push_back({"rest.kinetic_energy", scene.rest().kinetic_energy(), kMaxEnergy, "J"});
  bounds.push_back({"rest.residual_force", scene.rest().residual_force(), kMaxBoundaryForce, "N"});
  if (scene.has_tool()) {
    bounds.push_back({"tool.blade_length", scene.tool().blade_length(), kMaxCoordinate, "m"});
    bounds.push_back({"tool.contact_stiffness", scene.tool().contact_stiffness(), kMaxContactStiffness, "N/m"});
    bounds.push_back({"tool.contact_damping", scene.tool().contact_damping(), kMaxContactStiffness, "N·s/m"});
  }
  if (scene.has_planned_incision()) {
    bounds.push_back({"planned_incision.depth", scene.planned_incision().depth(), kMaxCoordinate, "m"});
    bounds.push_back({"planned_incision.tolerance", scene.planned_incision().tolerance(), kMaxCoordinate, "m"});
  }
  if (scene.has_cutting() && scene.cutting().enabled()) {
    bounds.push_back({"cutting.alpha", scene.cutting().alpha(), kMaxCuttingFactor, ""});
    bounds.push_back({"cutting.kappa", scene.cutting().kappa(), kMaxCuttingFactor, ""});
    bounds.push_back({"cutting.critical_stress", scene.cutting().critical_stress(), kMaxModulus, "Pa"});
  }
  bounds.push_back({"haptics.decay_per_second", scene.haptics().decay_per_second(), kMaxRate, "1/s"});
  bounds.push_back({"haptics.device_scale", scene.haptics().device_scale(), kMaxScale, ""});
  for (const Bound& b : bounds) RequireAtMost(s, b.field, b.value, b.limit, b.unit);
  // Moduli below a pascal leave no stiffness to speak of next to round-off.
  for (int i = 0; i < scene.materials_size(); ++i) {
    const auto& m = scene.materials(i);
    const std::string f = fmt::format("materials[{}]", i);
    const auto [field, value] = m.has_lame() ? std::pair{f + ".lame.mu", m.lame().mu()}
                                             : std::pair{f + ".young_poisson.youngs_modulus",
                                                         m.young_poisson().youngs_modulus()};
    if (value < kMinModulus) {
      FieldError(s, field, fmt::format("{:g} Pa is below {:g} Pa", value, kMinModulus));
    }
    if (m.density() < kMinDensity) {
      FieldError(s, f + ".density", fmt::format("{:g} kg/m³ is below {:g} kg/m³", m.density(), kMinDensity));
    }
  }
}

void CheckThreads(int64_t threads, const SourceRef& where) {
  if (threads < 0 || threads > kMaxThreads) {
    ThrowInputError(where, fmt::format("{} threads: must lie in [0, {}] (0 = automatic)", threads, kMaxThreads));
  }
}

LoadedScene ParseScene(const std::string& text, const std::string& source_name,
                       const std::filesystem::path& base_dir) {
  LoadedScene out;
  out.path = source_name;
  out.base_dir = base_dir;
  pb::TextFormat::Parser parser;
  FirstErrorCollector errors;
  parser.RecordErrorsTo(&errors);
  if (!parser.ParseFromString(text, &out.scene)) {
    ThrowInputError({.file = source_name,
                     .line = errors.line_ + 1,
                     .column = errors.column_ + 1},
                    errors.has_error_ ? errors.message_ : "cannot parse scene");
  }
  ValidateScene(out.scene, source_name);
  return out;
}

LoadedScene LoadScene(const std::filesystem::path& path) {
  const std::string text = ReadInputFile(path.string(), "scene file", kMaxSceneFileBytes);
  std::filesystem::path base = path.parent_path();
  if (base.empty()) base = ".";
  return ParseScene(text, path.string(), base);
}

}  // namespace cutsim::sim
