// Fitting B-spline solids to samples and to the Visible Human female muscle meshes (§3.1.2).
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

#include <cstdio>
#include <random>

namespace fascicle {
namespace {

TEST(Fitting, RecoversControlPointsFromExactSamples) {
  auto design = make_cylindrical_lattice(0.01, 0.1, {2, 3, 3}, {3, 8, 6});
  auto truth = design.solid;
  for (int r = 0; r < truth.P.rows(); ++r) truth.P(r, 1) += 2.0 * truth.P(r, 2) * truth.P(r, 2);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> U01(0, 1);
  Points3 M(2000, 3), X(2000, 3);
  for (int r = 0; r < 2000; ++r) {
    M.row(r) << U01(rng), U01(rng), U01(rng);
    X.row(r) = calc_point(truth, M.row(r).transpose()).transpose();
  }
  const Points3 P = fit_control_points(design.solid, design.constraints, M, X, {}, 0.0);
  EXPECT_LT((P - truth.P).cwiseAbs().maxCoeff(), 1e-12);
  // too few samples -> clear error
  EXPECT_THROW(fit_control_points(design.solid, design.constraints, M.topRows(5), X.topRows(5), {}, 0.0), Error);
}

TEST(Fitting, SpindleMeshToleranceAndBadSlices) {
  const TriMesh spindle = make_ellipsoid(Vec3(0.012, 0.015, 0.06), 5);
  const auto fit = fit_solid_to_mesh(spindle);
  EXPECT_LT(fit.mean_distance_m, 2e-4);
  EXPECT_LT(std::abs(fit.volume_difference), 0.01);
  // two disjoint blobs: slices with two contours are reported by index
  TriMesh two = make_ellipsoid(Vec3(0.01, 0.01, 0.05), 3);
  TriMesh other = two;
  other.V.col(0).array() += 0.05;
  TriMesh both;
  both.V.resize(two.V.rows() * 2, 3);
  both.V << two.V, other.V;
  both.F.resize(two.F.rows() * 2, 3);
  both.F << two.F, (other.F.array() + static_cast<int>(two.V.rows())).matrix();
  MeshFitOptions o;
  o.origin = Vec3(0, 0, -0.05);
  o.insertion = Vec3(0, 0, 0.05);
  try {
    fit_solid_to_mesh(both, o);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("slice"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("single closed contour"), std::string::npos) << e.what();
  }
}

class VisibleHumanFit : public ::testing::TestWithParam<const char*> {};

TEST_P(VisibleHumanFit, MeetsTargets) {
  const auto path = test::data_path(std::string("visible_human_female/right/VHF_Right_Muscle_") +
                                    GetParam() + "_smooth.stl");
  const TriMesh mesh = read_mesh(path, LengthUnit::millimetre);
  MeshFitOptions o;
  o.name = GetParam();
  o.lattice_candidates = {{4, 20, 20}};
  const auto fit = fit_solid_to_mesh(mesh, o);
  std::printf("%s: lattice %dx%dx%d, samples %d, mean %.3f mm, max %.3f mm, mesh %.2f cm3, solid %.2f cm3 (%+.3f%%)\n",
              GetParam(), fit.solid.num_control(0), fit.solid.num_control(1),
              fit.solid.num_control(2), fit.num_samples, fit.mean_distance_m * 1e3, fit.max_distance_m * 1e3,
              fit.mesh_volume_m3 * 1e6, fit.solid_volume_m3 * 1e6, 100 * fit.volume_difference);
  EXPECT_LE(fit.mean_distance_m, 1e-3);
  EXPECT_LE(fit.max_distance_m, 3e-3);
  EXPECT_LE(std::abs(fit.volume_difference), 0.01);
  EXPECT_NEAR(calc_volume(fit.solid), fit.solid_volume_m3, 1e-12 * fit.solid_volume_m3);
}

INSTANTIATE_TEST_SUITE_P(Muscles, VisibleHumanFit,
                         ::testing::Values("Soleus", "TibialisAnterior", "GastrocnemiusMedial"));

}  // namespace
}  // namespace fascicle
