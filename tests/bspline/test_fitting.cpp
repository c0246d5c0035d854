// Fitting B-spline solids to samples and to the Visible Human female muscle meshes (§3.1.2).
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/lattice.hpp"
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
  std::printf("%s: lattice %dx%dx%d, samples %d, mean %.3f mm, max %.3f mm, mesh %.2f cm3, solid %.2f cm3 (%+.3f%%), "
              "backed off %d, min det J %.3e m^3\n",
              GetParam(), fit.solid.num_control(0), fit.solid.num_control(1),
              fit.solid.num_control(2), fit.num_samples, fit.mean_distance_m * 1e3, fit.max_distance_m * 1e3,
              fit.mesh_volume_m3 * 1e6, fit.solid_volume_m3 * 1e6, 100 * fit.volume_difference,
              fit.correction_backed_off, fit.min_jacobian_det);
  // Known defect: with the automatic axis the soleus's uncorrected cubic fits are already inverted
  // (at u = 0.98, v = 0.47, w = 0.72, the shelf of docs/bspline-solids.md), so the correction has
  // nothing to back off to. The others would be inverted by the correction without the check.
  if (std::string(GetParam()) != "Soleus") EXPECT_GT(fit.min_jacobian_det, 0.0);
  EXPECT_LE(fit.mean_distance_m, 1e-3);
  EXPECT_LE(fit.max_distance_m, 3e-3);
  EXPECT_LE(std::abs(fit.volume_difference), 0.01);
  EXPECT_NEAR(calc_volume(fit.solid), fit.solid_volume_m3, 1e-12 * fit.solid_volume_m3);
}

INSTANTIATE_TEST_SUITE_P(Muscles, VisibleHumanFit,
                         ::testing::Values("Soleus", "TibialisAnterior", "GastrocnemiusMedial"));

TEST(Fitting, MinJacobianDeterminantOfAffineAndFoldedSolids) {
  // affine map of the unit box onto a 0.02 x 0.03 x 0.1 m box: det J = 6e-5 m^3 everywhere
  auto box = make_cubical_lattice(Vec3(0, 0, 0), Vec3(0.02, 0.03, 0.1), {2, 2, 3}, {4, 4, 6}).solid;
  const JacobianMinimum j = find_min_jacobian_determinant(box);
  EXPECT_NEAR(j.det_J, 0.02 * 0.03 * 0.1, 1e-15);
  // mirrored (x -> -x): left-handed, det J = -6e-5
  BSplineSolid mirrored = box;
  mirrored.P.col(0) *= -1.0;
  EXPECT_NEAR(find_min_jacobian_determinant(mirrored, 5).det_J, -0.02 * 0.03 * 0.1, 1e-15);
  // one interior control point pushed far along w past its neighbours: x_w < 0 where its basis
  // function falls, so the map folds in its support
  BSplineSolid folded = box;
  const int I = folded.index(1, 1, 2);
  folded.P(I, 2) += 0.5;
  const JacobianMinimum f = find_min_jacobian_determinant(folded);
  EXPECT_LT(f.det_J, 0.0);
  // at a point whose det J is indeed that value, in the support of the moved control point
  EXPECT_NEAR(calc_point_and_jacobian(folded, f.material).J.determinant(), f.det_J, 1e-18);
  EXPECT_LT(f.material[0], 0.75);
  EXPECT_LT(f.material[1], 0.75);
}

// The examples/solid/README.md fits (coarse quadratic lattices, automatic axis): the
// parameter correction used to fold their interior; the fitter now keeps the last non-inverted
// fit, which solid dynamics accepts.
struct CoarseCase {
  const char* muscle;
  std::array<int, 3> count;
};
class CoarseVisibleHumanFit : public ::testing::TestWithParam<CoarseCase> {};

TEST_P(CoarseVisibleHumanFit, IsNotInverted) {
  const CoarseCase c = GetParam();
  const TriMesh mesh = read_mesh(test::data_path(std::string("visible_human_female/right/VHF_Right_Muscle_") +
                                                 c.muscle + "_smooth.stl"),
                                 LengthUnit::millimetre);
  MeshFitOptions o;  // as `fascicle solid fit --axis auto --lattice ... --degree 2`
  o.name = c.muscle;
  o.count = c.count;
  o.degree = {2, 2, 2};
  const auto fit = fit_solid_to_mesh(mesh, o);
  std::printf("%s %dx%dx%d: vertex samples %d, rounds %d, backed off %d, min det J %.3e m^3 at "
              "(%.3f, %.3f, %.3f), mean %.3f mm, max %.3f mm, volume %+.3f%%\n",
              c.muscle, c.count[0], c.count[1], c.count[2], fit.mesh_vertex_samples_used,
              fit.reparametrise_rounds, fit.correction_backed_off, fit.min_jacobian_det,
              fit.min_jacobian_material[0], fit.min_jacobian_material[1],
              fit.min_jacobian_material[2], fit.mean_distance_m * 1e3, fit.max_distance_m * 1e3,
              100 * fit.volume_difference);
  EXPECT_GT(fit.min_jacobian_det, 0.0);
  // the reported minimum is the solid's own, at the dynamics rule and a finer one
  EXPECT_GE(find_min_jacobian_determinant(fit.solid).det_J, fit.min_jacobian_det);
  EXPECT_GE(find_min_jacobian_determinant(fit.solid, 4).det_J, fit.min_jacobian_det);
  EXPECT_GT(fit.max_distance_m, 0.0);
  EXPECT_LT(fit.max_distance_m, 0.02);  // a coarse lattice, but the muscle's shape
  EXPECT_LT(std::abs(fit.volume_difference), 0.05);
  // with the correction switched off the fit is the fallback: never better than the kept one
  MeshFitOptions plain = o;
  plain.reparametrise_iterations = 0;
  plain.mesh_vertex_samples = false;
  const auto base = fit_solid_to_mesh(mesh, plain);
  EXPECT_FALSE(base.correction_backed_off);
  EXPECT_EQ(base.reparametrise_rounds, 0);
  EXPECT_EQ(fit.correction_backed_off, !fit.mesh_vertex_samples_used || fit.reparametrise_rounds < 3);
  if (!fit.mesh_vertex_samples_used && fit.reparametrise_rounds == 0) EXPECT_EQ(fit.solid.P, base.solid.P);
  std::printf("  uncorrected: min det J %.3e m^3, mean %.3f mm, max %.3f mm\n", base.min_jacobian_det,
              base.mean_distance_m * 1e3, base.max_distance_m * 1e3);
}

INSTANTIATE_TEST_SUITE_P(Readme, CoarseVisibleHumanFit,
                         ::testing::Values(CoarseCase{"Soleus", {3, 8, 6}},
                                           CoarseCase{"GastrocnemiusMedial", {3, 8, 8}}),
                         [](const auto& info) { return std::string(info.param.muscle); });

}  // namespace
}  // namespace fascicle
