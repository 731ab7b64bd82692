// The volumetric term of the average-nodal-pressure element against its
// definitions: the volume derivatives of one element against finite
// differences, the term's forces against the energy's and its Hessian
// product against the forces' finite differences, zero energy and force
// under rigid motions, a uniform nodal ratio and no interior force under an
// affine deformation (patch test), and the nodal average over a patch.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include "common/fem/forces.h"
#include "common/fem/nodal_pressure.h"
#include "common/fem/tangent.h"
#include "tests/unit/fem/test_meshes.h"

namespace cutsim::fem {
namespace {

Model<double> MakeBlock() {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 2, 2, 0.03, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(1e4, 0.49, 1000.0);
  return Model<double>(mesh, std::span(&mat, 1));
}

std::vector<double> Kappas(const Model<double>& model) {
  std::vector<double> k(static_cast<size_t>(model.num_tets()));
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    k[static_cast<size_t>(t)] = model.lambdas()[t] + 2.0 / 3.0 * model.mus()[t];
  }
  return k;
}

/// Rest positions moved by a smooth field of amplitude `amp` (m).
std::vector<double> Deformed(const Model<double>& model, double amp) {
  std::vector<double> x(static_cast<size_t>(3 * model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    for (int d = 0; d < 3; ++d) {
      x[static_cast<size_t>(3 * n + d)] = model.rest_position(n)(d) + amp * std::sin(1.7 * (3 * n + d) + 0.3 * d);
    }
  }
  return x;
}

TEST(NodalPressureTest, VolumeDerivativesMatchFiniteDifferences) {
  Mat34<double> x;
  x << 0.0, 1.1, 0.1, 0.2, 0.0, 0.1, 0.9, 0.1, 0.1, 0.0, 0.2, 1.2;
  Mat34<double> u;
  u << 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1;
  const Mat3<double> dm_inv = EdgeMatrix(u).inverse();
  const double vol = EdgeMatrix(u).determinant() / 6.0;
  const Mat34<double> g = ShapeGradients(dm_inv);
  const auto volume = [&](const Mat34<double>& xx) { return vol * (EdgeMatrix(xx) * dm_inv).determinant(); };
  const Mat3<double> F = EdgeMatrix(x) * dm_inv;
  const Mat34<double> grad = VolumeGradient(F, g, vol);
  const double h = 1e-6;
  for (int a = 0; a < 4; ++a) {
    for (int d = 0; d < 3; ++d) {
      Mat34<double> xp = x, xm = x;
      xp(d, a) += h;
      xm(d, a) -= h;
      EXPECT_NEAR(grad(d, a), (volume(xp) - volume(xm)) / (2 * h), 1e-8) << a << " " << d;
      // Column d of block (b, a) of the Hessian: the change of ∂v/∂x_b.
      const Mat3<double> Fp = EdgeMatrix(xp) * dm_inv, Fm = EdgeMatrix(xm) * dm_inv;
      const Mat34<double> dg = (VolumeGradient(Fp, g, vol) - VolumeGradient(Fm, g, vol)) / (2 * h);
      for (int b = 0; b < 4; ++b) {
        const Mat3<double> H = b == a ? Mat3<double>::Zero() : VolumeHessianBlock(F, g.col(b), g.col(a), vol);
        EXPECT_LT((H.col(d) - dg.col(b)).norm(), 1e-7) << a << " " << b << " " << d;
      }
    }
  }
}

TEST(NodalPressureTest, ForceIsMinusTheEnergyGradient) {
  const Model<double> model = MakeBlock();
  const std::vector<double> kappa = Kappas(model);
  std::vector<double> x = Deformed(model, 1e-3);
  std::vector<double> f(x.size(), 0.0);
  NodalPressureEnergyAndForce(model, kappa, x.data(), f.data());
  const double h = 1e-8;
  double worst = 0, scale = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const double xi = x[i];
    x[i] = xi + h;
    const double ep = NodalPressureEnergyAndForce(model, kappa, x.data(), nullptr);
    x[i] = xi - h;
    const double em = NodalPressureEnergyAndForce(model, kappa, x.data(), nullptr);
    x[i] = xi;
    worst = std::max(worst, std::abs(-(ep - em) / (2 * h) - f[i]));
    scale = std::max(scale, std::abs(f[i]));
  }
  ASSERT_GT(scale, 0.0);
  EXPECT_LT(worst, 1e-5 * scale);
}

TEST(NodalPressureTest, HessianProductMatchesForceDifferences) {
  const Model<double> model = MakeBlock();
  const std::vector<double> kappa = Kappas(model);
  const std::vector<double> x = Deformed(model, 1e-3);
  std::vector<double> p(x.size());
  for (size_t i = 0; i < p.size(); ++i) p[i] = std::cos(0.9 * static_cast<double>(i) + 0.4);
  std::vector<double> kp(x.size(), 0.0);
  NodalPressureHessianProduct(model, kappa, x.data(), p.data(), kp.data());
  const double h = 1e-7;
  std::vector<double> xp = x, xm = x, fp(x.size(), 0.0), fm(x.size(), 0.0);
  for (size_t i = 0; i < x.size(); ++i) {
    xp[i] += h * p[i];
    xm[i] -= h * p[i];
  }
  NodalPressureEnergyAndForce(model, kappa, xp.data(), fp.data());
  NodalPressureEnergyAndForce(model, kappa, xm.data(), fm.data());
  double worst = 0, scale = 0;
  for (size_t i = 0; i < x.size(); ++i) {
    const double fd = -(fp[i] - fm[i]) / (2 * h);  // K p = −∂f/∂x p
    worst = std::max(worst, std::abs(fd - kp[i]));
    scale = std::max(scale, std::abs(kp[i]));
  }
  ASSERT_GT(scale, 0.0);
  EXPECT_LT(worst, 1e-5 * scale);
}

TEST(NodalPressureTest, RigidMotionsCarryNoEnergyOrForce) {
  const Model<double> model = MakeBlock();
  const std::vector<double> kappa = Kappas(model);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d shift(0.3, -0.1, 0.2);
  std::vector<double> x(static_cast<size_t>(3 * model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    Eigen::Map<Eigen::Vector3d>(x.data() + 3 * n) = R * model.rest_position(n) + shift;
  }
  std::vector<double> f(x.size(), 0.0), j(static_cast<size_t>(model.num_nodes()));
  EXPECT_NEAR(NodalPressureEnergyAndForce(model, kappa, x.data(), f.data(), j.data()), 0.0, 1e-15);
  for (const double fi : f) EXPECT_NEAR(fi, 0.0, 1e-10);
  for (const double ji : j) EXPECT_NEAR(ji, 1.0, 1e-12);
}

TEST(NodalPressureTest, AffineDeformationGivesOneRatioAndNoInteriorForce) {
  const Model<double> model = MakeBlock();
  const std::vector<double> kappa = Kappas(model);
  Eigen::Matrix3d A;
  A << 0.97, 0.02, 0.0, -0.01, 1.03, 0.01, 0.02, 0.0, 0.98;
  std::vector<double> x(static_cast<size_t>(3 * model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    Eigen::Map<Eigen::Vector3d>(x.data() + 3 * n) = A * model.rest_position(n);
  }
  std::vector<double> f(x.size(), 0.0), j(static_cast<size_t>(model.num_nodes()));
  NodalPressureEnergyAndForce(model, kappa, x.data(), f.data(), j.data());
  for (const double ji : j) EXPECT_NEAR(ji, A.determinant(), 1e-12);
  // A uniform pressure: the forces on an interior node cancel.
  int interior = 0;
  double boundary_force = 0;
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    const Eigen::Vector3d r = model.rest_position(n);
    const bool inside = r(0) > 1e-9 && r(0) < 0.03 - 1e-9 && r(1) > 1e-9 && r(1) < 0.02 - 1e-9 &&
                        r(2) > 1e-9 && r(2) < 0.02 - 1e-9;
    const double fn = Eigen::Map<const Eigen::Vector3d>(f.data() + 3 * n).norm();
    if (inside) {
      EXPECT_LT(fn, 1e-9) << "node " << n;
      ++interior;
    } else {
      boundary_force = std::max(boundary_force, fn);
    }
  }
  EXPECT_GT(interior, 0);
  EXPECT_GT(boundary_force, 1e-3);
}

TEST(NodalPressureTest, NodalRestVolumesSumToTheBodyAndAverageKappa) {
  const Model<double> model = MakeBlock();
  std::vector<double> kappa = Kappas(model);
  kappa[0] *= 3.0;  // one stiffer element: its nodes average it in
  std::vector<double> node_kappa, node_volume;
  NodalRestVolumes(model, kappa, node_kappa, node_volume);
  double total = 0;
  for (const double v : node_volume) total += v;
  EXPECT_NEAR(total, 0.03 * 0.02 * 0.02, 1e-15);
  const double k0 = kappa[1];
  for (int c = 0; c < 4; ++c) {
    const auto a = static_cast<size_t>(model.tet_node(0, c));
    EXPECT_GT(node_kappa[a], k0);
    EXPECT_LT(node_kappa[a], 3.0 * k0);
  }
}

// The stress the cut criterion reads: under a uniform F every nodal ratio is
// det F, so each element's Cauchy stress is its deviatoric part plus U'(det F)·I.
TEST(NodalPressureTest, ElementStressIsDeviatoricPlusTheNodalPressure) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(3, 2, 2, 0.03, 0.02, 0.02);
  const Material mat = Material::FromYoungPoisson(1e4, 0.49, 1000.0);
  ModelOptions opt;
  opt.element = ElementKind::kNodalPressure;
  const Model<double> model(mesh, std::span(&mat, 1), opt);
  Eigen::Matrix3d A;
  A << 1.02, 0.03, 0.0, -0.01, 0.97, 0.02, 0.01, 0.0, 1.01;
  std::vector<double> x(static_cast<size_t>(3 * model.num_nodes()));
  for (int32_t n = 0; n < model.num_nodes(); ++n) {
    Eigen::Map<Eigen::Vector3d>(x.data() + 3 * n) = A * model.rest_position(n);
  }
  const double mu = model.mus()[0];
  const double kappa = model.kappas()[0];
  const Mat3<double> dev = CauchyStress<double>(A, StvkFirstPiola<double>(A, -2.0 / 3.0 * mu, mu));
  const Mat3<double> expected = dev + VolumetricPressure(A.determinant(), kappa) * Mat3<double>::Identity();
  for (int32_t t = 0; t < model.num_tets(); ++t) {
    EXPECT_LT((ElementCauchyStress(model, x.data(), t) - expected).norm(), 1e-9 * expected.norm()) << "tet " << t;
  }
  // The linear element's stress under the same F is the plain StVK one.
  const Model<double> linear(mesh, std::span(&mat, 1));
  const Mat3<double> plain = CauchyStress<double>(A, StvkFirstPiola<double>(A, linear.lambdas()[0], mu));
  EXPECT_LT((ElementCauchyStress(linear, x.data(), 0) - plain).norm(), 1e-9 * plain.norm());
}

// The whole-mesh stress (node pressures gathered once) is the per-tet
// query's, tet by tet, under a non-affine deformation where every node's
// patch has its own J, for both elements.
TEST(NodalPressureStress, WholeMeshFormEqualsThePerTetQuery) {
  const mesh::TetMesh mesh = testing::MakeBoxMesh(4, 3, 2, 0.04, 0.03, 0.02);
  const Material mat = Material::FromYoungPoisson(2e4, 0.45, 1000.0);
  for (const ElementKind kind : {ElementKind::kNodalPressure, ElementKind::kLinear}) {
    ModelOptions opt;
    opt.element = kind;
    const Model<double> model(mesh, std::span(&mat, 1), opt);
    std::vector<double> x(static_cast<size_t>(3 * model.num_nodes()));
    for (int32_t n = 0; n < model.num_nodes(); ++n) {
      const Eigen::Vector3d r = model.rest_position(n);
      Eigen::Map<Eigen::Vector3d>(x.data() + 3 * n) =
          r + Eigen::Vector3d(3.0 * r.y() * r.y(), -2.0 * r.x() * r.z(), 4.0 * r.x() * r.x());  // m, strains ≈ 0.1
    }
    std::vector<double> tet_volume, pressure;
    ComputeNodePressures(model, x.data(), tet_volume, pressure, 2);
    ASSERT_EQ(pressure.size(), static_cast<size_t>(model.num_nodes()));
    double largest = 0;
    for (int32_t t = 0; t < model.num_tets(); ++t) {
      const Mat3<double> one = ElementCauchyStress(model, x.data(), t);
      const Mat3<double> whole = ElementCauchyStress(model, x.data(), t, std::span<const double>(pressure));
      EXPECT_LE((one - whole).norm(), 1e-12 * one.norm() + 1e-9) << "tet " << t;
      largest = std::max(largest, one.norm());
    }
    EXPECT_GT(largest, 1.0);  // the field is loaded, so the comparison can fail
    if (kind == ElementKind::kNodalPressure) {
      EXPECT_TRUE(std::any_of(pressure.begin(), pressure.end(), [](double p) { return std::abs(p) > 1.0; }));
    } else {
      EXPECT_TRUE(std::all_of(pressure.begin(), pressure.end(), [](double p) { return p == 0.0; }));
    }
  }
}

}  // namespace
}  // namespace cutsim::fem
