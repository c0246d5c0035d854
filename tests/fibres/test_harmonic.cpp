// Tetrahedralisation, Laplace solve and streamline tracing on analytic shapes.
#include "fascicle/core/error.hpp"
#include "fascicle/fibres/attachment.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <string>

using namespace fascicle;

namespace {

// A cylinder of radius r, height h along z, with its two caps as origin (z = +h/2, proximal) and
// insertion (z = -h/2).
struct CylinderCase {
  TriMesh mesh;
  Attachments areas;
};

CylinderCase make_cylinder_case(double r, double h) {
  CylinderCase c;
  c.mesh = make_cylinder(r, h, 32, 12);
  std::vector<int> top, bottom;
  for (Eigen::Index v = 0; v < c.mesh.num_vertices(); ++v) {
    if (c.mesh.V(v, 2) > h / 2 - 1e-12) top.push_back(static_cast<int>(v));
    if (c.mesh.V(v, 2) < -h / 2 + 1e-12) bottom.push_back(static_cast<int>(v));
  }
  c.areas = {make_attachment_area(c.mesh, top, "origin"),
             make_attachment_area(c.mesh, bottom, "insertion")};
  return c;
}

}  // namespace

TEST(TetMesh, KeepsSurfaceAndVolume) {
  const TriMesh sphere = make_icosphere(0.02, 3);
  const TetMesh t = calc_tet_mesh(sphere);
  ASSERT_GE(t.num_vertices(), sphere.num_vertices());
  EXPECT_TRUE(t.V.topRows(sphere.num_vertices()) == sphere.V);
  // The tet volume equals the enclosed volume of the polyhedron exactly (same boundary).
  double enclosed = 0.0;
  for (Eigen::Index f = 0; f < sphere.num_faces(); ++f)
    enclosed += Vec3(sphere.V.row(sphere.F(f, 0)))
                    .dot(Vec3(sphere.V.row(sphere.F(f, 1))).cross(Vec3(sphere.V.row(sphere.F(f, 2))))) /
                6.0;
  EXPECT_NEAR(calc_tet_volume(t), enclosed, 1e-12 * enclosed + 1e-18);
  // Every face is shared by two tets or lies on the boundary; boundary faces = surface triangles.
  int boundary = 0;
  for (Eigen::Index k = 0; k < t.num_tets(); ++k)
    for (int c = 0; c < 4; ++c) boundary += t.neighbours(k, c) < 0;
  EXPECT_EQ(boundary, sphere.num_faces());
}

TEST(Laplace, StiffnessAnnihilatesConstantsAndIsSymmetric) {
  const TetMesh t = calc_tet_mesh(make_box(Vec3(0.01, 0.02, 0.03)));
  const Eigen::SparseMatrix<double> K = calc_stiffness_matrix(t);
  const VecX ones = VecX::Ones(t.num_vertices());
  EXPECT_LT((K * ones).cwiseAbs().maxCoeff(), 1e-12 * K.coeffs().cwiseAbs().maxCoeff());
  EXPECT_LT((Eigen::SparseMatrix<double>(K.transpose()) - K).norm(), 1e-14 * K.norm());
  // Energy of a linear function a.x equals |a|^2 volume.
  const Vec3 a(1.0, -2.0, 0.5);
  const VecX u = t.V * a;
  EXPECT_NEAR(u.dot(K * u), a.squaredNorm() * calc_tet_volume(t), 1e-9 * a.squaredNorm() * calc_tet_volume(t));
}

TEST(Laplace, CylinderSolutionIsLinearInZ) {
  // Linear elements reproduce linear fields exactly: u = (h/2 - z) / h.
  const double h = 0.1;
  const CylinderCase c = make_cylinder_case(0.015, h);
  const HarmonicField f = calc_harmonic_field(c.mesh, c.areas);
  for (Eigen::Index v = 0; v < f.tets.num_vertices(); ++v)
    ASSERT_NEAR(f.u(v), (h / 2 - f.tets.V(v, 2)) / h, 1e-9);
  for (Eigen::Index k = 0; k < f.tets.num_tets(); ++k)
    ASSERT_LT((Vec3(f.tet_gradient.row(k)) - Vec3(0, 0, -1 / h)).norm(), 1e-6 / h);
}

TEST(Laplace, MissingBoundaryIsAnError) {
  const TetMesh t = calc_tet_mesh(make_box(Vec3(0.01, 0.01, 0.01)));
  EXPECT_THROW(solve_laplace(t, {}, {0}), Error);
  EXPECT_THROW(solve_laplace(t, {0}, {0}), Error);
  // The messages name the sets as the caller calls them (aponeurosis faces, not origin/insertion).
  const auto message = [&](const std::vector<int>& zero, const std::vector<int>& one) {
    try {
      solve_laplace(t, zero, one, "the -x aponeurosis face", "the +x aponeurosis face");
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string empty_plus = message({0}, {});
  EXPECT_NE(empty_plus.find("the +x aponeurosis face has none"), std::string::npos) << empty_plus;
  EXPECT_EQ(empty_plus.find("origin"), std::string::npos) << empty_plus;
  const std::string shared = message({0}, {0});
  EXPECT_NE(shared.find("both the -x aponeurosis face and the +x aponeurosis face"),
            std::string::npos)
      << shared;
}

TEST(HarmonicFibres, CylinderStreamlinesAreStraightAndFullLength) {
  const double h = 0.1, r = 0.015;
  const CylinderCase c = make_cylinder_case(r, h);
  const HarmonicField f = calc_harmonic_field(c.mesh, c.areas);
  const FibreSet s = trace_harmonic_fibres(f, c.areas.origin, {.count = 40, .resolution = 11});
  ASSERT_EQ(s.size(), 40u);
  for (const Points3& P : s.fibres) {
    ASSERT_EQ(P.rows(), 11);
    EXPECT_NEAR(P(0, 2), h / 2, 1e-12);                 // starts on the origin cap
    EXPECT_NEAR(P(10, 2), -h / 2, 1e-6);                // ends on the insertion cap
    EXPECT_NEAR(calc_polyline_length(P), h, 1e-5);      // straight along z
    for (int k = 0; k < 11; ++k) {
      EXPECT_NEAR(P(k, 0), P(0, 0), 1e-6);
      EXPECT_NEAR(P(k, 1), P(0, 1), 1e-6);
      EXPECT_LE(std::hypot(P(k, 0), P(k, 1)), r + 1e-12);
    }
  }
}

// Seeds inside the volume (level set u = 1/2, or the tets by volume), traced both ways: on the
// cylinder every fibre still runs straight from cap to cap, and the fibres fill the cross-section
// evenly (area-proportional seeds: mean squared radius r^2 / 2 of a uniform disk).
TEST(HarmonicFibres, InteriorSeedsTraceBothWaysToTheCaps) {
  const double h = 0.1, r = 0.015;
  const CylinderCase c = make_cylinder_case(r, h);
  const HarmonicField f = calc_harmonic_field(c.mesh, c.areas);
  for (const TraceOptions::Seeding seeding :
       {TraceOptions::Seeding::level_set, TraceOptions::Seeding::volume}) {
    const FibreSet s = trace_harmonic_fibres(
        f, c.areas.origin, {.count = 200, .resolution = 11, .seeding = seeding});
    ASSERT_EQ(s.size(), 200u);
    double mean_r2 = 0.0;
    for (const Points3& P : s.fibres) {
      EXPECT_NEAR(P(0, 2), h / 2, 1e-6);    // origin end first
      EXPECT_NEAR(P(10, 2), -h / 2, 1e-6);  // on the insertion cap
      EXPECT_NEAR(calc_polyline_length(P), h, 1e-5);
      EXPECT_NEAR(P(10, 0), P(0, 0), 1e-6);
      EXPECT_NEAR(P(10, 1), P(0, 1), 1e-6);
      mean_r2 += (P(0, 0) * P(0, 0) + P(0, 1) * P(0, 1)) / s.size();
    }
    // The polygonal disk (32 sides) has a slightly smaller second moment than the circle.
    EXPECT_NEAR(mean_r2 / (0.5 * r * r), 1.0, 0.06) << static_cast<int>(seeding);
  }
}

// Oversampled volume seeds with fibres chosen by farthest-point order of their shapes: still
// straight cap to cap, and the cross-section is covered more evenly than by the seeds alone (the
// largest gap from a disk point to the nearest fibre: 1.86 sqrt(A/n) for the 100 seeds, 1.08 with
// 4 x candidates), without a strong bias to the periphery (second moment within 10 % of uniform).
TEST(HarmonicFibres, FarthestCandidatesCoverTheSectionEvenly) {
  const double h = 0.1, r = 0.015;
  const CylinderCase c = make_cylinder_case(r, h);
  const HarmonicField f = calc_harmonic_field(c.mesh, c.areas);
  // Largest distance from a point of the disk (within 0.95 r) to the nearest fibre's middle point,
  // in units of sqrt(A/n).
  const auto calc_gap = [&](const FibreSet& s) {
    double worst = 0.0;
    for (int i = -40; i <= 40; ++i)
      for (int j = -40; j <= 40; ++j) {
        const Vec2 p(r * i / 40.0, r * j / 40.0);
        if (p.norm() > 0.95 * r) continue;
        double best = 1e300;
        for (const Points3& P : s.fibres) best = std::min(best, std::hypot(P(5, 0) - p.x(), P(5, 1) - p.y()));
        worst = std::max(worst, best);
      }
    return worst / std::sqrt(M_PI * r * r / 100.0);
  };
  const auto largest_gap = [&](int factor) {
    const FibreSet s = trace_harmonic_fibres(f, c.areas.origin,
                                             {.count = 100,
                                              .resolution = 11,
                                              .seeding = TraceOptions::Seeding::volume,
                                              .candidate_factor = factor});
    EXPECT_EQ(s.size(), 100u);
    double mean_r2 = 0.0;
    for (const Points3& P : s.fibres) {
      EXPECT_NEAR(P(0, 2), h / 2, 1e-6);
      EXPECT_NEAR(P(10, 2), -h / 2, 1e-6);
      EXPECT_NEAR(calc_polyline_length(P), h, 1e-5);
      mean_r2 += (P(0, 0) * P(0, 0) + P(0, 1) * P(0, 1)) / s.size();
    }
    if (factor > 1) {
      EXPECT_NEAR(mean_r2 / (0.5 * r * r), 1.0, 0.1);
    }
    return calc_gap(s);
  };
  const double seeds_only = largest_gap(1), chosen = largest_gap(4);
  EXPECT_GT(seeds_only, 1.5);
  EXPECT_LT(chosen, 1.2);
  // With area candidates (100 on each cap) the fibres stay straight cap to cap and spread.
  const FibreSet s = trace_harmonic_fibres(f, c.areas.origin,
                                           {.count = 100,
                                            .resolution = 11,
                                            .seeding = TraceOptions::Seeding::volume,
                                            .candidate_factor = 4,
                                            .area_candidate_factor = 1},
                                           &c.areas.insertion);
  ASSERT_EQ(s.size(), 100u);
  const double with_areas = calc_gap(s);
  for (const Points3& P : s.fibres) {
    EXPECT_NEAR(P(0, 2), h / 2, 1e-6);
    EXPECT_NEAR(P(10, 2), -h / 2, 1e-6);
    EXPECT_NEAR(calc_polyline_length(P), h, 1e-5);
  }
  std::printf("largest gap with area candidates %.2f sqrt(A/n)\n", with_areas);
  EXPECT_LT(with_areas, 1.2);
}

TEST(AttachmentSamples, StratifiedAlongALongStrip) {
  // A 100 x 4 mm strip of 1 mm squares whose triangles are stored in a scrambled order: the
  // samples still fall evenly along it (each 10 mm tenth gets 10 +- 2 of 100), so the ends of
  // re-routed fibres cannot leave part of a long attachment area empty.
  const int nx = 100, ny = 4;
  TriMesh strip;
  strip.V.resize((nx + 1) * (ny + 1), 3);
  for (int i = 0; i <= nx; ++i)
    for (int j = 0; j <= ny; ++j) strip.V.row(i * (ny + 1) + j) << 1e-3 * i, 1e-3 * j, 0.0;
  const int nt = 2 * nx * ny;
  strip.F.resize(nt, 3);
  for (int t = 0; t < nt; ++t) {
    const int k = (t * 397) % nt;  // scrambled storage order (397 is prime to 800)
    const int q = k / 2, i = q / ny, j = q % ny;
    const int a = i * (ny + 1) + j, b = a + ny + 1;
    if (k % 2 == 0) strip.F.row(t) << a, b, b + 1;
    else strip.F.row(t) << a, b + 1, a + 1;
  }
  std::vector<int> all(strip.num_vertices());
  for (int v = 0; v < strip.num_vertices(); ++v) all[v] = v;
  const AttachmentArea area = make_attachment_area(strip, all, "origin");
  ASSERT_NEAR(area.area_m2, 4e-4, 1e-12);
  const Points3 P = calc_area_samples(strip, area, 100);
  ASSERT_EQ(P.rows(), 100);
  std::vector<int> per_tenth(10, 0);
  for (Eigen::Index k = 0; k < P.rows(); ++k) {
    EXPECT_GE(P(k, 1), -1e-12);
    EXPECT_LE(P(k, 1), 4e-3 + 1e-12);
    ++per_tenth[std::clamp(static_cast<int>(P(k, 0) / 1e-2), 0, 9)];
  }
  for (int b = 0; b < 10; ++b) EXPECT_NEAR(per_tenth[b], 10, 2) << "tenth " << b;
}

TEST(BoneAttachments, DropsContactSpecks) {
  // A cylinder (z up, origin towards +z) touching a box along its upper side, and a small sphere
  // 1 mm from one side vertex on the other side of the upper half: that one-vertex contact
  // (no triangle) is not part of the origin area.
  const double r = 0.015, h = 0.1;
  const TriMesh muscle = make_cylinder(r, h, 32, 12);
  TriMesh box = make_box(Vec3(0.005, 0.02, 0.02));
  box.V.rowwise() += Eigen::RowVector3d(r + 0.005 + 0.001, 0.0, 0.025);
  int speck = -1;
  for (Eigen::Index v = 0; v < muscle.num_vertices(); ++v)
    if (muscle.V(v, 0) < -r + 1e-9 && muscle.V(v, 2) > 0.01 && muscle.V(v, 2) < 0.03) speck = v;
  ASSERT_GE(speck, 0);
  TriMesh ball = make_icosphere(0.0005, 2);
  ball.V.rowwise() += muscle.V.row(speck) + Eigen::RowVector3d(-0.0015, 0.0, 0.0);
  const Attachments a = find_bone_attachments(muscle, {box, ball}, 0.002);
  EXPECT_FALSE(std::binary_search(a.origin.vertices.begin(), a.origin.vertices.end(), speck));
  ASSERT_FALSE(a.origin.triangles.empty());
  for (int v : a.origin.vertices) EXPECT_GT(muscle.V(v, 0), 0.0);  // only the box side
}

TEST(BoneAttachments, RolesWithTheTendonOutsideTheMesh) {
  // A cylinder (z up, origin towards +z) lying along a box over its whole length on the +x side;
  // the insertion bone lies far below (its tendon is not part of the mesh). The origin is the box
  // contact minus the distal end region, which becomes the insertion; with origin_reach = 2/3
  // only the upper two thirds of the contact remain.
  const double r = 0.015, h = 0.1;
  const TriMesh muscle = make_cylinder(r, h, 32, 12);
  TriMesh box = make_box(Vec3(0.005, 0.02, 0.12));
  box.V.rowwise() += Eigen::RowVector3d(r + 0.0025 + 0.001, 0.0, 0.0);
  TriMesh foot = make_box(Vec3(0.02, 0.02, 0.02));
  foot.V.rowwise() += Eigen::RowVector3d(0.0, 0.0, -0.2);
  const Attachments a = find_bone_role_attachments(muscle, {box}, {foot});
  ASSERT_FALSE(a.origin.triangles.empty());
  ASSERT_FALSE(a.insertion.triangles.empty());
  double origin_lowest = 1.0;
  for (int v : a.origin.vertices) {
    EXPECT_GT(muscle.V(v, 0), 0.0);  // the box side
    origin_lowest = std::min(origin_lowest, muscle.V(v, 2));
  }
  const double end_level = -h / 2 + 0.08 * h;
  EXPECT_GT(origin_lowest, end_level);  // gave up the distal end region
  EXPECT_LT(origin_lowest, end_level + h / 11 + 1e-9);  // but kept the rest (12 rings)
  for (int v : a.insertion.vertices) EXPECT_LE(muscle.V(v, 2), end_level + 1e-9);
  BoneRoleOptions o;
  o.origin_reach = 2.0 / 3.0;
  const Attachments b = find_bone_role_attachments(muscle, {box}, {foot}, o);
  for (int v : b.origin.vertices) EXPECT_GE(muscle.V(v, 2), h / 2 - 2.0 / 3.0 * h - 1e-9);
  EXPECT_LT(b.origin.area_m2, a.origin.area_m2);
  // Neither side touching its bones is an error.
  EXPECT_THROW(find_bone_role_attachments(muscle, {foot}, {foot}), Error);
}
