#include "common/render/surface_renderer.h"

#include <GL/gl.h>
#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <numbers>
#include <utility>

#include "common/core/error.h"
#include "common/render/osmesa_context.h"
#include "common/render/palette.h"

namespace cutsim::render {
namespace {

constexpr int kToolSides = 16;  // facets around a cylinder or cone (the force arrow)

// Lighting budget (see palette.h): ambient + key + fill ≤ 1 keeps every lit
// colour an unclamped multiple of its base colour, so hue survives shading.
constexpr float kAmbient = static_cast<float>(kMinLight);
constexpr float kKeyDiffuse = 0.66F;
constexpr float kFillDiffuse = 0.12F;
static_assert(kAmbient + kKeyDiffuse + kFillDiffuse <= 1.0F);

void Fail(const char* field, const std::string& message) {
  ThrowInputError(SourceRef{.field = field}, message);
}

void ValidateSurface(const SurfaceInput& surface, const RenderOptions& options) {
  const Eigen::Index num_vertices = surface.positions.rows();
  const Eigen::Index num_faces = surface.triangles.rows();
  for (Eigen::Index f = 0; f < num_faces; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int32_t v = surface.triangles(f, k);
      if (v < 0 || v >= num_vertices) {
        Fail("render.triangles",
             fmt::format("triangle {} refers to vertex {}, outside [0, {})", f, v, num_vertices));
      }
    }
  }
  if (!surface.opened.empty() && static_cast<Eigen::Index>(surface.opened.size()) != num_faces) {
    Fail("render.opened",
         fmt::format("has {} flags for {} triangles", surface.opened.size(), num_faces));
  }
  if (!surface.vertex_scalar.empty() &&
      static_cast<Eigen::Index>(surface.vertex_scalar.size()) != num_vertices) {
    Fail("render.vertex_scalar",
         fmt::format("has {} values for {} vertices", surface.vertex_scalar.size(), num_vertices));
  }
  if (options.scalar_range) {
    const ScalarRange& r = *options.scalar_range;
    if (!std::isfinite(r.min) || !std::isfinite(r.max) || r.max < r.min) {
      Fail("render.scalar_range", fmt::format("[{}, {}] is not a finite range", r.min, r.max));
    }
  }
  if (options.tool) {
    const ToolSegment& t = *options.tool;
    if (!t.pose.tip.allFinite() || !t.pose.blade_dir.allFinite() || !std::isfinite(t.length) ||
        !std::isfinite(t.radius) || !t.edge_dir.allFinite()) {
      Fail("render.tool", "tip, blade and edge directions, length and radius must be finite");
    }
    if (!(t.pose.blade_dir.norm() > 0.0)) Fail("render.tool", "the blade direction must not be zero");
  }
  if (options.force) {
    const ForceOverlay& f = *options.force;
    if (!f.at.allFinite() || !f.force.allFinite() || !(f.full_scale > 0.0) || !std::isfinite(f.full_scale)) {
      Fail("render.force", "position and force must be finite and full_scale positive");
    }
  }
}

/// The scalar range to colour with: the given one, or the data's finite extent.
ScalarRange EffectiveRange(std::span<const double> values, const RenderOptions& options) {
  if (options.scalar_range) return *options.scalar_range;
  ScalarRange range{std::numeric_limits<double>::infinity(),
                    -std::numeric_limits<double>::infinity()};
  for (double v : values) {
    if (std::isfinite(v)) {
      range.min = std::min(range.min, v);
      range.max = std::max(range.max, v);
    }
  }
  if (!(range.max >= range.min)) range = ScalarRange{0.0, 1.0};
  return range;
}

void SetupLighting() {
  // Called with an identity modelview: light directions are in eye space, so
  // the lights follow the camera (key from upper right, fill from lower left).
  glEnable(GL_LIGHTING);
  const GLfloat global_ambient[] = {kAmbient, kAmbient, kAmbient, 1.0F};
  glLightModelfv(GL_LIGHT_MODEL_AMBIENT, global_ambient);
  glLightModeli(GL_LIGHT_MODEL_TWO_SIDE, GL_TRUE);
  glLightModeli(GL_LIGHT_MODEL_LOCAL_VIEWER, GL_FALSE);

  const GLfloat zero[] = {0.0F, 0.0F, 0.0F, 1.0F};
  const GLfloat key_diffuse[] = {kKeyDiffuse, kKeyDiffuse, kKeyDiffuse, 1.0F};
  const GLfloat key_direction[] = {-0.35F, 0.45F, 1.0F, 0.0F};  // w = 0: directional
  glEnable(GL_LIGHT0);
  glLightfv(GL_LIGHT0, GL_AMBIENT, zero);
  glLightfv(GL_LIGHT0, GL_DIFFUSE, key_diffuse);
  glLightfv(GL_LIGHT0, GL_SPECULAR, zero);
  glLightfv(GL_LIGHT0, GL_POSITION, key_direction);

  const GLfloat fill_diffuse[] = {kFillDiffuse, kFillDiffuse, kFillDiffuse, 1.0F};
  const GLfloat fill_direction[] = {0.6F, -0.3F, 0.4F, 0.0F};
  glEnable(GL_LIGHT1);
  glLightfv(GL_LIGHT1, GL_AMBIENT, zero);
  glLightfv(GL_LIGHT1, GL_DIFFUSE, fill_diffuse);
  glLightfv(GL_LIGHT1, GL_SPECULAR, zero);
  glLightfv(GL_LIGHT1, GL_POSITION, fill_direction);

  // Per-vertex colours drive ambient and diffuse; no specular, no emission.
  glEnable(GL_COLOR_MATERIAL);
  glColorMaterial(GL_FRONT_AND_BACK, GL_AMBIENT_AND_DIFFUSE);
  glMaterialfv(GL_FRONT_AND_BACK, GL_SPECULAR, zero);
  glMaterialfv(GL_FRONT_AND_BACK, GL_EMISSION, zero);
}

}  // namespace

SurfaceRenderer::SurfaceRenderer() = default;
SurfaceRenderer::~SurfaceRenderer() = default;

void SurfaceRenderer::EnsureContext(int width, int height) {
  if (context_ && context_->width() == width && context_->height() == height) return;
  context_.reset();  // destroy the old context before creating the new one
  context_ = std::make_unique<OsMesaContext>(width, height);
}

void SurfaceRenderer::BuildVertexArrays(const SurfaceInput& surface, const RenderOptions& options,
                                        const Eigen::Vector3d& origin) {
  const auto num_faces = static_cast<size_t>(surface.triangles.rows());
  vertices_.resize(num_faces * 9);
  normals_.resize(num_faces * 9);
  colours_.resize(num_faces * 12);

  const bool by_scalar = options.colour_by_scalar && !surface.vertex_scalar.empty();
  const ScalarRange range =
      by_scalar ? EffectiveRange(surface.vertex_scalar, options) : ScalarRange{};
  const double span = range.max - range.min;

  for (size_t f = 0; f < num_faces; ++f) {
    const auto row = static_cast<Eigen::Index>(f);
    Eigen::Vector3d p[3];
    for (int k = 0; k < 3; ++k) {
      p[k] = surface.positions.row(surface.triangles(row, k)).transpose() - origin;
    }
    // Flat shading: one unit face normal for all three corners. A degenerate
    // face gets a zero normal and shows only its ambient colour.
    Eigen::Vector3d n = (p[1] - p[0]).cross(p[2] - p[0]);
    const double length = n.norm();
    n = (length > 0.0 && std::isfinite(length)) ? Eigen::Vector3d(n / length)
                                                : Eigen::Vector3d::Zero();
    const bool opened = !surface.opened.empty() && surface.opened[f] != 0;
    for (int k = 0; k < 3; ++k) {
      const size_t v = 3 * f + static_cast<size_t>(k);
      for (int c = 0; c < 3; ++c) {
        vertices_[3 * v + static_cast<size_t>(c)] = static_cast<float>(p[k][c]);
        normals_[3 * v + static_cast<size_t>(c)] = static_cast<float>(n[c]);
      }
      Rgb rgb = kTissueRgb;
      if (opened) {
        rgb = kCutFaceRgb;
      } else if (by_scalar) {
        const double s = surface.vertex_scalar[static_cast<size_t>(surface.triangles(row, k))];
        rgb = StressColour(span > 0.0 ? (s - range.min) / span : 0.5);
      }
      colours_[4 * v] = rgb[0];
      colours_[4 * v + 1] = rgb[1];
      colours_[4 * v + 2] = rgb[2];
      colours_[4 * v + 3] = 255;
    }
  }
}

namespace {

/// Two unit vectors completing unit `a` to a right-handed frame (a, u, w).
void Perpendiculars(const Eigen::Vector3d& a, Eigen::Vector3d& u, Eigen::Vector3d& w) {
  const Eigen::Vector3d helper = std::abs(a.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  u = a.cross(helper).normalized();
  w = a.cross(u);
}

/// A closed cylinder from `from` to `to` in the current colour. Winding is
/// counter-clockwise seen from outside: with two-sided lighting a clockwise
/// outside would be lit as a back face, with the normal flipped inwards (dark).
void DrawCylinder(const Eigen::Vector3d& from, const Eigen::Vector3d& to, double radius) {
  const Eigen::Vector3d axis = from - to;
  const double length = axis.norm();
  if (!(length > 0.0)) return;
  const Eigen::Vector3d a = axis / length;
  Eigen::Vector3d u, w;
  Perpendiculars(a, u, w);
  glBegin(GL_TRIANGLE_STRIP);  // the side, smooth normals
  for (int i = 0; i <= kToolSides; ++i) {
    const double angle = 2.0 * std::numbers::pi * i / kToolSides;
    const Eigen::Vector3d radial = std::cos(angle) * u + std::sin(angle) * w;
    const Eigen::Vector3d p_from = from + radius * radial;
    const Eigen::Vector3d p_to = to + radius * radial;
    glNormal3d(radial.x(), radial.y(), radial.z());
    glVertex3d(p_from.x(), p_from.y(), p_from.z());
    glVertex3d(p_to.x(), p_to.y(), p_to.z());
  }
  glEnd();
  for (int end = 0; end < 2; ++end) {  // flat caps
    const Eigen::Vector3d& centre = end == 0 ? to : from;
    const Eigen::Vector3d normal = end == 0 ? Eigen::Vector3d(-a) : a;
    const double turn = end == 0 ? -1.0 : 1.0;  // counter-clockwise about `normal`
    glBegin(GL_TRIANGLE_FAN);
    glNormal3d(normal.x(), normal.y(), normal.z());
    glVertex3d(centre.x(), centre.y(), centre.z());
    for (int i = 0; i <= kToolSides; ++i) {
      const double angle = turn * 2.0 * std::numbers::pi * i / kToolSides;
      const Eigen::Vector3d p = centre + radius * (std::cos(angle) * u + std::sin(angle) * w);
      glVertex3d(p.x(), p.y(), p.z());
    }
    glEnd();
  }
}

/// A cone with its base disc at `base` and its apex at `apex`.
void DrawCone(const Eigen::Vector3d& base, const Eigen::Vector3d& apex, double radius) {
  const Eigen::Vector3d axis = apex - base;
  const double length = axis.norm();
  if (!(length > 0.0)) return;
  const Eigen::Vector3d a = axis / length;
  Eigen::Vector3d u, w;
  Perpendiculars(a, u, w);
  glBegin(GL_TRIANGLES);
  for (int i = 0; i < kToolSides; ++i) {
    const double a0 = 2.0 * std::numbers::pi * i / kToolSides, a1 = 2.0 * std::numbers::pi * (i + 1) / kToolSides;
    const Eigen::Vector3d r0 = std::cos(a0) * u + std::sin(a0) * w, r1 = std::cos(a1) * u + std::sin(a1) * w;
    const Eigen::Vector3d n = (r0 + r1).normalized() * length + a * radius;  // the slanted side's normal
    glNormal3d(n.x(), n.y(), n.z());
    const Eigen::Vector3d p0 = base + radius * r0, p1 = base + radius * r1;
    glVertex3d(p0.x(), p0.y(), p0.z());
    glVertex3d(p1.x(), p1.y(), p1.z());
    glVertex3d(apex.x(), apex.y(), apex.z());
    glNormal3d(-a.x(), -a.y(), -a.z());  // the base disc
    glVertex3d(base.x(), base.y(), base.z());
    glVertex3d(p1.x(), p1.y(), p1.z());
    glVertex3d(p0.x(), p0.y(), p0.z());
  }
  glEnd();
}

}  // namespace

namespace {

/// The blade's outline in its plane, tip first: (along the blade toward
/// the handle, across toward the edge) in blade lengths and belly widths.
/// The edge bellies out from the tip; the spine runs straight back from it.
constexpr double kBladeOutline[][2] = {{0.0, 0.0},  {0.06, 0.30}, {0.16, 0.62}, {0.30, 0.86}, {0.48, 0.98},
                                       {0.70, 1.0}, {1.0, 0.92},  {1.0, -0.05}, {0.5, -0.05}};

/// A flat box: `centre`, half-extents `h` along the unit axes a, e, n.
void DrawSlab(const Eigen::Vector3d& centre, const Eigen::Vector3d& a, const Eigen::Vector3d& e,
              const Eigen::Vector3d& n, const Eigen::Vector3d& h) {
  const Eigen::Vector3d axes[3] = {a * h[0], e * h[1], n * h[2]};
  glBegin(GL_QUADS);
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d& u = axes[(k + 1) % 3];
    const Eigen::Vector3d& w = axes[(k + 2) % 3];
    for (const double side : {-1.0, 1.0}) {
      const Eigen::Vector3d c = centre + side * axes[k];
      const Eigen::Vector3d normal = side * axes[k].normalized();
      glNormal3d(normal.x(), normal.y(), normal.z());
      // Counter-clockwise about `normal` (u × w is along axes[k]).
      const double s = side;
      for (const auto& [p, q] : {std::pair{-1.0, -1.0}, std::pair{s, -s}, std::pair{1.0, 1.0}, std::pair{-s, s}}) {
        const Eigen::Vector3d v = c + p * u + q * w;
        glVertex3d(v.x(), v.y(), v.z());
      }
    }
  }
  glEnd();
}

}  // namespace

void SurfaceRenderer::DrawTool(const ToolSegment& tool, const Eigen::Vector3d& eye) {
  if (!(tool.length > 0.0)) return;
  const Eigen::Vector3d a = tool.pose.blade_dir.normalized();
  // The blade's plane: across it toward the edge (e), and its face normal (n).
  Eigen::Vector3d e = tool.edge_dir - tool.edge_dir.dot(a) * a;
  Eigen::Vector3d n;
  if (e.norm() > 1e-9) {
    e.normalize();
    n = a.cross(e);
  } else {
    n = (eye - tool.pose.tip) - (eye - tool.pose.tip).dot(a) * a;  // the flat side toward the camera
    if (n.norm() > 1e-12) {
      n.normalize();
      e = n.cross(a);
    } else {
      Perpendiculars(a, e, n);
    }
  }
  const double half_width = tool.radius > 0.0 ? tool.radius : 0.1 * tool.length;
  const double belly = 2.2 * half_width;
  const Eigen::Vector3d& tip = tool.pose.tip;

  // The blade: a flat fan (lit on both sides) round a point inside the outline.
  glColor4ub(kToolRgb[0], kToolRgb[1], kToolRgb[2], 255);
  const auto at = [&](double along, double across) -> Eigen::Vector3d {
    return tip + along * tool.length * a + across * belly * e;
  };
  const Eigen::Vector3d centre = at(0.6, 0.45);
  glBegin(GL_TRIANGLE_FAN);
  glNormal3d(n.x(), n.y(), n.z());
  glVertex3d(centre.x(), centre.y(), centre.z());
  constexpr size_t kCorners = std::size(kBladeOutline);
  for (size_t i = 0; i <= kCorners; ++i) {  // backwards: counter-clockwise about n
    const auto& c = kBladeOutline[(kCorners - i) % kCorners];
    const Eigen::Vector3d p = at(c[0], c[1]);
    glVertex3d(p.x(), p.y(), p.z());
  }
  glEnd();

  // The handle: a flat bar from the blade's base, a narrow neck first.
  glColor4ub(kHandleRgb[0], kHandleRgb[1], kHandleRgb[2], 255);
  const double thickness = 0.3 * half_width;
  const double neck = 0.15 * tool.length;
  DrawSlab(tip + (tool.length + 0.5 * neck) * a + 0.4 * belly * e, a, e, n,
           {0.5 * neck, 0.5 * half_width, 0.7 * thickness});
  const double handle = ToolSegment::kHandleLengths * tool.length - neck;
  DrawSlab(tip + (tool.length + neck + 0.5 * handle) * a + 0.4 * belly * e, a, e, n,
           {0.5 * handle, half_width, thickness});
}

void SurfaceRenderer::DrawForceArrow(const ForceOverlay& force, double scene_radius) {
  const double magnitude = force.force.norm();
  if (!(magnitude > 0.0)) return;
  const double length = 0.5 * scene_radius * std::min(magnitude / force.full_scale, 1.5);
  const Eigen::Vector3d dir = force.force / magnitude;
  const double radius = 0.015 * scene_radius;
  const Eigen::Vector3d neck = force.at + 0.7 * length * dir;
  glColor4ub(kForceRgb[0], kForceRgb[1], kForceRgb[2], 255);
  DrawCylinder(force.at, neck, radius);
  DrawCone(neck, force.at + length * dir, 2.5 * radius);
}

void SurfaceRenderer::DrawForceGauge(const ForceOverlay& force, int width, int height) {
  // Pixel coordinates, origin at the bottom left; no lighting or depth.
  glDisable(GL_LIGHTING);
  glDisable(GL_DEPTH_TEST);
  glMatrixMode(GL_PROJECTION);
  glLoadIdentity();
  glOrtho(0.0, width, 0.0, height, -1.0, 1.0);
  glMatrixMode(GL_MODELVIEW);
  glLoadIdentity();
  const double x0 = std::max(4.0, 0.03 * width), x1 = x0 + std::max(6.0, 0.03 * width);
  const double y0 = 0.1 * height, y1 = 0.6 * height;
  const double fill = std::clamp(force.force.norm() / force.full_scale, 0.0, 1.0);
  glColor4ub(kForceRgb[0], kForceRgb[1], kForceRgb[2], 255);
  glBegin(GL_QUADS);
  glVertex2d(x0, y0);
  glVertex2d(x1, y0);
  glVertex2d(x1, y0 + fill * (y1 - y0));
  glVertex2d(x0, y0 + fill * (y1 - y0));
  glEnd();
  glColor4ub(kGaugeFrameRgb[0], kGaugeFrameRgb[1], kGaugeFrameRgb[2], 255);
  glBegin(GL_LINE_LOOP);
  glVertex2d(x0 - 1, y0 - 1);
  glVertex2d(x1 + 1, y0 - 1);
  glVertex2d(x1 + 1, y1 + 1);
  glVertex2d(x0 - 1, y1 + 1);
  glEnd();
}

Image SurfaceRenderer::Render(const Camera& camera, const SurfaceInput& surface,
                              const RenderOptions& options) {
  ValidateCamera(camera);
  ValidateSurface(surface, options);
  EnsureContext(camera.width, camera.height);
  context_->MakeCurrent();

  // Scene bounds: clip planes, the default tool radius, and a local origin
  // that keeps float vertex coordinates precise far from the world origin.
  Eigen::AlignedBox3d box = BoundingBox(surface.positions);
  if (options.tool) {
    box.extend(options.tool->end());
    box.extend(options.tool->pose.tip);
  }
  const Eigen::Vector3d origin = box.isEmpty() ? camera.target : box.center();
  const double scene_radius = box.isEmpty() ? 1.0 : std::max(0.5 * box.diagonal().norm(), 1e-6);
  BuildVertexArrays(surface, options, origin);

  const double distance = (camera.eye - origin).norm();
  const double far_m = 1.05 * (distance + scene_radius);
  const double near_m = std::max(0.95 * (distance - scene_radius), 1e-4 * far_m);

  glViewport(0, 0, camera.width, camera.height);
  glClearColor(kBackgroundRgb[0] / 255.0F, kBackgroundRgb[1] / 255.0F, kBackgroundRgb[2] / 255.0F,
               1.0F);
  glClearDepth(1.0);
  glClear(GL_COLOR_BUFFER_BIT | GL_DEPTH_BUFFER_BIT);
  glEnable(GL_DEPTH_TEST);
  glDepthFunc(GL_LESS);
  glDisable(GL_CULL_FACE);  // open cuts expose back faces
  glDisable(GL_BLEND);
  glDisable(GL_DITHER);     // keep lit colours exact multiples of the base colour
  glShadeModel(GL_SMOOTH);  // normals are per face already; colours may vary per vertex

  const Eigen::Matrix4d projection = camera.ProjectionMatrix(near_m, far_m);
  glMatrixMode(GL_PROJECTION);
  glLoadMatrixd(projection.data());  // Eigen's default storage is column-major, as GL expects
  glMatrixMode(GL_MODELVIEW);
  glLoadIdentity();
  SetupLighting();

  Eigen::Matrix4d model_view = camera.ViewMatrix();
  model_view.col(3).head<3>() += model_view.topLeftCorner<3, 3>() * origin;  // · translate(origin)
  glLoadMatrixd(model_view.data());

  if (!vertices_.empty()) {
    glEnableClientState(GL_VERTEX_ARRAY);
    glEnableClientState(GL_NORMAL_ARRAY);
    glEnableClientState(GL_COLOR_ARRAY);
    glVertexPointer(3, GL_FLOAT, 0, vertices_.data());
    glNormalPointer(GL_FLOAT, 0, normals_.data());
    glColorPointer(4, GL_UNSIGNED_BYTE, 0, colours_.data());
    glDrawArrays(GL_TRIANGLES, 0, static_cast<GLsizei>(vertices_.size() / 3));
    glDisableClientState(GL_COLOR_ARRAY);
    glDisableClientState(GL_NORMAL_ARRAY);
    glDisableClientState(GL_VERTEX_ARRAY);
  }
  if (options.tool || options.force) {
    glLoadMatrixd(camera.ViewMatrix().data());  // tool and arrow are drawn in world coordinates
    if (options.tool) DrawTool(*options.tool, camera.eye);
    if (options.force) DrawForceArrow(*options.force, scene_radius);
  }
  if (options.force) DrawForceGauge(*options.force, camera.width, camera.height);
  if (const GLenum error = glGetError(); error != GL_NO_ERROR) {
    throw std::runtime_error(fmt::format("OpenGL error 0x{:x} while rendering", error));
  }
  return context_->ReadImage();
}

}  // namespace cutsim::render
