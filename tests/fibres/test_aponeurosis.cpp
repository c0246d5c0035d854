// Aponeurosis attachment areas, the pennation-derived template rise and the pennate harmonic
// field, on an analytic flattened cylinder.
#include "fascicle/core/error.hpp"
#include "fascicle/fibres/attachment.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/fibres/template_mapping.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

using namespace fascicle;

namespace {

// An elliptic cylinder along z (length 0.12 m), 0.016 m thick along x and 0.04 m wide along y.
TriMesh make_slab() {
  TriMesh m = make_cylinder(0.02, 0.12, 48, 30);
  m.V.col(0) *= 0.4;
  return m;
}

double median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// 60 harmonic fibres × 12 points in the slab, with aponeurosis areas of the given architecture and
// the pennate field at angle alpha (thickness along x), optionally turning towards target points.
Decomposition decompose_slab_pennate(
    Architecture architecture, double alpha,
    HarmonicOptions::PennationReference reference =
        HarmonicOptions::PennationReference::line_of_action,
    double fibre_length = 0.0, bool thickness_plane = false, const Points3& targets = Points3(0, 3)) {
  AponeurosisOptions o;
  o.architecture = architecture;
  o.pennation_rad = alpha;
  o.thickness_direction = Vec3::UnitX();
  const TriMesh m = make_slab();
  const Attachments a = find_aponeurosis_attachments(m, o);
  DecomposeOptions opt;
  opt.method = FibreMethod::harmonic;
  opt.count = 60;
  opt.resolution = 12;
  opt.harmonic.pennation_rad = alpha;
  opt.harmonic.pennation_reference = reference;
  opt.harmonic.fibre_length_m = fibre_length;
  if (thickness_plane) opt.harmonic.transverse_direction = a.thickness_direction;
  opt.harmonic.transverse_targets = targets;
  return decompose_muscle(m, a, opt);
}

}  // namespace

TEST(Aponeurosis, UnipennateAreasAreOffsetStripsOnOppositeFaces) {
  const TriMesh m = make_slab();
  AponeurosisOptions o;
  o.pennation_rad = 30.0 * M_PI / 180;
  o.thickness_direction = Vec3::UnitX();
  const Attachments a = find_aponeurosis_attachments(m, o);
  // Origin (proximal, +z end) on the -x face, insertion on the +x face.
  EXPECT_LT(a.origin.normal.x(), -0.9);
  EXPECT_GT(a.insertion.normal.x(), 0.9);
  // d = T / tan(30 deg) with T the mean x extent (0.016 m): the origin strip ends d before the
  // distal end, the insertion strip starts d after the proximal end.
  const double L = 0.12, T = 0.016, d = T / std::tan(o.pennation_rad);
  double origin_lowest = 1.0, insertion_highest = -1.0;
  for (int v : a.origin.vertices) origin_lowest = std::min(origin_lowest, m.V(v, 2));
  for (int v : a.insertion.vertices) insertion_highest = std::max(insertion_highest, m.V(v, 2));
  const double ring = L / 31;  // spacing of the cylinder's rings
  EXPECT_NEAR(origin_lowest, L / 2 - (L - d), ring);
  EXPECT_NEAR(insertion_highest, L / 2 - d, ring);
  EXPECT_EQ(a.insertion_interior.rows(), 0);
}

TEST(Aponeurosis, BipennateHasACentralSheetInside) {
  const TriMesh m = make_slab();
  AponeurosisOptions o;
  o.architecture = Architecture::bipennate;
  o.pennation_rad = 20.0 * M_PI / 180;
  o.thickness_direction = Vec3::UnitX();
  const Attachments a = find_aponeurosis_attachments(m, o);
  ASSERT_GT(a.insertion_interior.rows(), 100);
  // The sheet lies at mid-thickness (x = 0), inside the ellipse, distal of d = (T/2)/tan(20 deg).
  const double d = 0.008 / std::tan(o.pennation_rad);
  for (Eigen::Index i = 0; i < a.insertion_interior.rows(); ++i) {
    const Vec3 p = a.insertion_interior.row(i);
    EXPECT_NEAR(p.x(), 0.0, 1e-3);
    EXPECT_LT(std::pow(p.x() / 0.008, 2) + std::pow(p.y() / 0.02, 2), 1.0);
    EXPECT_LE(p.z(), 0.06 - d + 1e-9);
  }
  // Origin on both faces.
  int minus = 0, plus = 0;
  for (int v : a.origin.vertices) (m.V(v, 0) < 0 ? minus : plus)++;
  EXPECT_GT(minus, 50);
  EXPECT_GT(plus, 50);
}

TEST(Aponeurosis, BadOptionsAreRejected) {
  const TriMesh m = make_slab();
  AponeurosisOptions o;
  o.pennation_rad = 0.0;
  EXPECT_THROW(find_aponeurosis_attachments(m, o), Error);
  o.pennation_rad = 0.3;
  o.thickness_direction = Vec3::UnitZ();  // along the muscle
  EXPECT_THROW(find_aponeurosis_attachments(m, o), Error);
  EXPECT_THROW(parse_architecture("multipennate"), Error);
  EXPECT_THROW(calc_pennate_rise(0.0, 0.01, 0.1), Error);
}

TEST(PennateRise, GivesTheTargetAngle) {
  // tan(a) = T / (h L).
  EXPECT_NEAR(calc_pennate_rise(M_PI / 4, 0.02, 0.1), 0.2, 1e-12);
  EXPECT_NEAR(calc_pennate_rise(std::atan(0.5), 0.01, 0.1), 0.2, 1e-12);
  EXPECT_DOUBLE_EQ(calc_pennate_rise(0.01, 0.05, 0.1), 1.0);  // clamped
  // Unit-cube fibres of the pennate template with that rise climb h over x in [0, 1].
  const FibreSet f = make_template_fibres(FibreTemplate::pennate, 10, 5, 0.2);
  for (const Points3& P : f.fibres) {
    EXPECT_NEAR(P(4, 0) - P(0, 0), 1.0, 1e-12);
    EXPECT_NEAR(P(4, 2) - P(0, 2), 0.2, 1e-12);
  }
}

class PennateHarmonicFieldReference
    : public ::testing::TestWithParam<HarmonicOptions::PennationReference> {};

// In the slab the aponeuroses (the +-x faces) are parallel to the line of action (z), so both
// references give the same fibres: cos(a) z + sin(a) x in the middle.
TEST_P(PennateHarmonicFieldReference, FibresRunAtThePennationAngle) {
  const double alpha = 30.0 * M_PI / 180;
  const Decomposition d = decompose_slab_pennate(Architecture::unipennate, alpha, GetParam());
  ASSERT_GE(d.fibres.size(), 55u);
  std::vector<double> angles, crossings;
  for (const Points3& P : d.fibres.fibres) {
    // Middle segment: in the slab's middle the along-field is z and the across field x, so the
    // fibre direction is cos(a) z + sin(a) x (a fibre runs distally, -z, towards +x).
    const Eigen::Index k = P.rows() / 2;
    const Vec3 t = (P.row(k) - P.row(k - 1)).normalized();
    angles.push_back(std::acos(std::abs(t.z())));
    EXPECT_GT(t.x(), 0.0);
    EXPECT_LT(t.z(), 0.0);
    crossings.push_back(P(P.rows() - 1, 0) - P(0, 0));
  }
  std::printf("median mid-fibre angle %.2f deg (target 30), median x crossing %.2f mm\n",
              median(angles) * 180 / M_PI, median(crossings) * 1e3);
  EXPECT_NEAR(median(angles), alpha, 2.0 * M_PI / 180);
  // Fibres cross from the -x face to the +x face.
  EXPECT_GT(median(crossings), 0.008);
}

INSTANTIATE_TEST_SUITE_P(
    Fibres, PennateHarmonicFieldReference,
    ::testing::Values(HarmonicOptions::PennationReference::line_of_action,
                      HarmonicOptions::PennationReference::aponeurosis));

TEST(PennateHarmonicField, UnipennateAreasCarryBothWholeFaces) {
  AponeurosisOptions o;
  o.pennation_rad = 30.0 * M_PI / 180;
  o.thickness_direction = Vec3::UnitX();
  const TriMesh m = make_slab();
  const Attachments a = find_aponeurosis_attachments(m, o);
  // The whole faces contain the strips, and each is more than the strip (full length).
  EXPECT_GT(a.face_minus.size(), a.origin.vertices.size());
  EXPECT_GT(a.face_plus.size(), a.insertion.vertices.size());
  for (int v : a.face_minus) EXPECT_LT(m.V(v, 0), 0.0);
  for (int v : a.face_plus) EXPECT_GT(m.V(v, 0), 0.0);
}

TEST(PennateHarmonicField, InteriorSheetReceivesTheFibres) {
  const double alpha = 20.0 * M_PI / 180;
  const Decomposition d = decompose_slab_pennate(Architecture::bipennate, alpha);
  ASSERT_GE(d.fibres.size(), 55u);
  // Fibres start on a face (|x| near the ellipse) and end near the central sheet x = 0.
  std::vector<double> end_x, start_x;
  for (const Points3& P : d.fibres.fibres) {
    start_x.push_back(std::abs(P(0, 0)));
    end_x.push_back(std::abs(P(P.rows() - 1, 0)));
  }
  std::printf("median |x| start %.2f mm, end %.2f mm\n", median(start_x) * 1e3,
              median(end_x) * 1e3);
  EXPECT_LT(median(end_x), 1.5e-3);
  EXPECT_GT(median(start_x), 4e-3);
}

// HarmonicOptions::transverse_direction: fibres turn in the plane of the thickness direction. In
// the slab (aponeuroses on the +-x faces, elliptic section) grad(u) also points sideways (y) near
// the rounded edges, so plain pennate fibres drift in y; in the x-z plane they keep their y.
TEST(PennateHarmonicField, ThicknessPlaneKeepsFibresInTheirXZPlane) {
  const double alpha = 30.0 * M_PI / 180;
  AponeurosisOptions o;
  o.pennation_rad = alpha;
  o.thickness_direction = Vec3::UnitX();
  const Attachments a = find_aponeurosis_attachments(make_slab(), o);
  EXPECT_NEAR(a.thickness_direction.x(), 1.0, 1e-12);  // towards the insertion (+x) face
  double drift[2] = {0.0, 0.0};
  for (int plane = 0; plane < 2; ++plane) {
    const Decomposition d = decompose_slab_pennate(
        Architecture::unipennate, alpha, HarmonicOptions::PennationReference::line_of_action, 0.0,
        plane == 1);
    ASSERT_GE(d.fibres.size(), 55u);
    std::vector<double> angles, dy;
    for (const Points3& P : d.fibres.fibres) {
      const Eigen::Index k = P.rows() / 2;
      const Vec3 t = (P.row(k) - P.row(k - 1)).normalized();
      angles.push_back(std::acos(std::abs(t.z())));
      dy.push_back(std::abs(P(P.rows() - 1, 1) - P(0, 1)));
    }
    drift[plane] = median(dy);
    std::printf("%s plane: median mid-fibre angle %.2f deg, median y drift %.3f mm, "
                "largest %.2f mm\n",
                plane ? "thickness" : "gradient", median(angles) * 180 / M_PI, drift[plane] * 1e3,
                *std::max_element(dy.begin(), dy.end()) * 1e3);
    EXPECT_NEAR(median(angles), alpha, 2.0 * M_PI / 180);
  }
  // The axis field grad(u_along) is z up to discretisation: the median fibre keeps its y to
  // 0.05 mm (measured 0.011 mm; 0.13 mm in the gradient plane). A few fibres at the rounded
  // edges slide along the surface where they meet it (at most 2.2 mm, 4.9 mm before).
  EXPECT_LT(drift[1], 5e-5);
  EXPECT_GT(drift[0], 3.0 * drift[1]);
}

TEST(PennateHarmonicField, ThicknessPlaneTurnsTowardsTheSheetFromEitherSide) {
  const Decomposition d =
      decompose_slab_pennate(Architecture::bipennate, 20.0 * M_PI / 180,
                             HarmonicOptions::PennationReference::line_of_action, 0.0, true);
  ASSERT_GE(d.fibres.size(), 55u);
  int towards = 0;
  for (const Points3& P : d.fibres.fibres)
    towards += std::abs(P(P.rows() - 1, 0)) < std::abs(P(0, 0));
  EXPECT_GE(towards, static_cast<int>(d.fibres.size()) - 2);
  // A non-finite direction is a usage error.
  AponeurosisOptions o;
  o.pennation_rad = 0.3;
  const TriMesh m = make_slab();
  HarmonicOptions h;
  h.pennation_rad = 0.3;
  h.transverse_direction = Vec3(std::nan(""), 0.0, 0.0);
  EXPECT_THROW(calc_harmonic_field(m, find_aponeurosis_attachments(m, o), h), Error);
}

TEST(FaceThickness, MatchesTheEllipseChordsAlongTheInwardNormals) {
  // Elliptic slab: semi-axes a = 8 mm (x, the thickness direction), b = 20 mm. For a point (x, y)
  // on the ellipse with unit normal n, the chord along -n has length
  // t = 2 (x n_x / a^2 + y n_y / b^2) / (n_x^2 / a^2 + n_y^2 / b^2). The median over the vertices
  // whose normal is within 60 degrees of +-x is computed here independently of the library.
  const TriMesh m = make_slab();
  const double a = 0.008, b = 0.02;
  std::vector<double> chords;
  for (int k = 0; k < 48; ++k) {
    const double phi = 2.0 * M_PI * k / 48;
    const double x = a * std::cos(phi), y = b * std::sin(phi);
    const Vec2 n = Vec2(x / (a * a), y / (b * b)).normalized();
    if (std::abs(n.x()) < 0.5) continue;
    chords.push_back(2.0 * (x * n.x() / (a * a) + y * n.y() / (b * b)) /
                     (n.x() * n.x() / (a * a) + n.y() * n.y() / (b * b)));
  }
  const double expected = median(chords);
  AponeurosisOptions o;
  o.thickness_direction = Vec3::UnitX();
  const double t = calc_face_thickness(m, o);
  std::printf("face thickness %.3f mm, analytic median chord %.3f mm\n", t * 1e3, expected * 1e3);
  EXPECT_NEAR(t, expected, 0.02 * expected);  // the mesh is a 48-gon, not the ellipse
  EXPECT_LE(t, 2 * a * (1 + 1e-9));           // never more than the thickness at y = 0
  // A face angle outside (0, 90) degrees would select every vertex: a usage error, as in
  // find_aponeurosis_attachments.
  for (const double bad : {0.0, 0.5 * M_PI, 2.0, std::nan("")}) {
    o.face_angle_rad = bad;
    EXPECT_THROW(calc_face_thickness(m, o), fascicle::Error) << bad;
    EXPECT_THROW(find_aponeurosis_attachments(m, o), fascicle::Error) << bad;
  }
}

TEST(PennateRise, MappedCrossingGivesTheTargetAngleInABox) {
  // Box 16 x 40 x 120 mm: every slice is a 16 x 40 mm rectangle, the template's x lines map
  // straight across (crossing = 16 mm = mean thickness), so a pennate fibre's chord makes exactly
  // the target angle with the line of action and is 16 mm / sin(alpha) long.
  const TriMesh m = make_box(Vec3(0.008, 0.02, 0.06));
  const Attachments areas = find_end_attachments(m);
  const TemplateMapper mapper(m, areas);
  EXPECT_NEAR(mapper.get_mean_crossing(), 0.016, 1e-9);
  EXPECT_NEAR(mapper.get_mean_thickness(), 0.016, 1e-9);
  const double alpha = 20.0 * M_PI / 180;
  DecomposeOptions opt;
  opt.fibre_template = FibreTemplate::pennate;
  opt.count = 40;
  opt.resolution = 9;
  opt.pennation_rad = alpha;
  opt.rise_crossing = DecomposeOptions::RiseCrossing::mapped_crossing;
  const Decomposition d = decompose_muscle(m, areas, opt);
  ASSERT_EQ(d.fibres.size(), 40u);
  const Vec3 ez = mapper.get_box_frame().linear().col(2);
  for (const Points3& P : d.fibres.fibres) {
    const Vec3 chord = P.row(P.rows() - 1) - P.row(0);
    EXPECT_NEAR(std::acos(std::abs(chord.normalized().dot(ez))), alpha, 0.2 * M_PI / 180);
    EXPECT_NEAR(calc_polyline_length(P), 0.016 / std::sin(alpha), 0.5e-3);
  }
}

// Local angle from one fibre length (HarmonicOptions::fibre_length_m): in the elliptic slab the
// faces are t(y) = 16 mm sqrt(1 - (y / 20 mm)^2) apart, so a fibre of length L = 32 mm makes
// asin(t(y) / L) with the axis: 30 degrees in the middle, less towards the thin edges. The fixed
// angle (10 degrees) is only the fallback.
TEST(PennateHarmonicField, LocalAngleFollowsTheCrossingDistance) {
  const double L = 0.032;
  const Decomposition d = decompose_slab_pennate(Architecture::unipennate, 10.0 * M_PI / 180,
                                                 HarmonicOptions::PennationReference::line_of_action, L);
  ASSERT_GE(d.fibres.size(), 55u);
  std::vector<double> centre_error, centre, edge;
  for (const Points3& P : d.fibres.fibres) {
    const Eigen::Index k = P.rows() / 2;
    const Vec3 t = (P.row(k) - P.row(k - 1)).normalized();
    const double angle = std::acos(std::abs(t.z()));
    const double y = 0.5 * (P(k, 1) + P(k - 1, 1));
    const double thickness = 0.016 * std::sqrt(std::max(0.0, 1.0 - (y / 0.02) * (y / 0.02)));
    if (std::abs(y) < 0.006) {
      centre.push_back(angle);
      centre_error.push_back(std::abs(angle - std::asin(thickness / L)));
    }
    if (std::abs(y) > 0.013) edge.push_back(angle);
  }
  ASSERT_GE(centre.size(), 5u);
  ASSERT_GE(edge.size(), 5u);
  std::printf("local angle: centre median %.2f deg (|error| median %.2f deg), edge median %.2f deg\n",
              median(centre) * 180 / M_PI, median(centre_error) * 180 / M_PI,
              median(edge) * 180 / M_PI);
  EXPECT_LT(median(centre_error), 2.0 * M_PI / 180);
  EXPECT_LT(median(edge), median(centre) - 3.0 * M_PI / 180);
}

// find_aponeurosis_border (session 10): a sheet in the x = 0 plane of the slab, 16 mm wide, whose
// distal third shifts sideways by up to 4 mm (as a central aponeurosis narrowing into its tendon
// on one side). The border is the sheet's edge on that side, one point per bin.
namespace {

// Sheet points on a 1 mm grid, z from 0.05 (proximal, the origin end is +z) down to -0.05 m,
// y in [-8, 8] mm + shift(s), s the distance from the proximal end over the extent.
double sheet_shift(double z, double lean) {
  const double s = (0.05 - z) / 0.10;
  return s > 2.0 / 3.0 ? lean * (s - 2.0 / 3.0) * 3.0 : 0.0;
}

Points3 make_leaning_sheet(double lean) {
  std::vector<Vec3> pts;
  for (int i = 0; i <= 100; ++i)
    for (int j = 0; j <= 16; ++j) {
      const double z = 0.05 - 1e-3 * i;
      pts.emplace_back(0.0, -8e-3 + 1e-3 * j + sheet_shift(z, lean), z);
    }
  Points3 P(static_cast<Eigen::Index>(pts.size()), 3);
  for (std::size_t i = 0; i < pts.size(); ++i)
    P.row(static_cast<Eigen::Index>(i)) = pts[i].transpose();
  return P;
}

}  // namespace

TEST(AponeurosisBorder, IsTheEdgeOnTheSideTheSheetLeansToDistally) {
  const TriMesh m = make_slab();
  for (const double lean : {4e-3, -4e-3}) {
    const Points3 border = find_aponeurosis_border(m, make_leaning_sheet(lean), Vec3::UnitX());
    ASSERT_EQ(border.rows(), 50);  // 101 rows of the grid in 50 bins: every bin holds points
    const double side = lean > 0.0 ? 1.0 : -1.0;
    double worst = 0.0;
    for (Eigen::Index i = 0; i < border.rows(); ++i) {
      const double z = border(i, 2);
      worst = std::max(worst, std::abs(border(i, 1) - (side * 8e-3 + sheet_shift(z, lean))));
    }
    EXPECT_LT(worst, 1e-12) << "lean " << lean;
  }
  // Fewer bins: one point per bin still, on the same edge.
  EXPECT_EQ(
      find_aponeurosis_border(m, make_leaning_sheet(4e-3), Vec3::UnitX(), Vec3::UnitZ(), 10).rows(),
      10);
  // No lean (the distal third centred): no tendon side, a clear error; so are too few bins,
  // too few points and a normal along the muscle's axis.
  EXPECT_THROW(find_aponeurosis_border(m, make_leaning_sheet(0.0), Vec3::UnitX()), Error);
  EXPECT_THROW(
      find_aponeurosis_border(m, make_leaning_sheet(4e-3), Vec3::UnitX(), Vec3::UnitZ(), 1), Error);
  EXPECT_THROW(find_aponeurosis_border(m, Points3::Zero(2, 3), Vec3::UnitX()), Error);
  EXPECT_THROW(find_aponeurosis_border(m, make_leaning_sheet(4e-3), Vec3::UnitZ()), Error);
}

// HarmonicOptions::transverse_targets: the fibres turn towards the nearest target point (here a
// line along z at x = 0, y = +12 mm in the bipennate slab) at the pennation angle, so they drift
// towards it in y while keeping the angle to the axis.
TEST(PennateHarmonicField, TransverseTargetsTurnTheFibresTowardsThem) {
  const double alpha = 20.0 * M_PI / 180;
  const double target_y = 12e-3;
  Points3 targets(61, 3);
  for (int i = 0; i <= 60; ++i) targets.row(i) = Vec3(0.0, target_y, -0.06 + 2e-3 * i).transpose();
  // Per fibre: the mid-fibre angle to the axis, whether it ends nearer the target line in y, and
  // its drift towards that line from start to end.
  struct Shape {
    std::vector<double> angles, drift;
    int towards = 0;
  };
  const auto measure = [&](const Decomposition& d) {
    Shape s;
    for (const Points3& P : d.fibres.fibres) {
      const Eigen::Index k = P.rows() / 2;
      const Vec3 t = (P.row(k) - P.row(k - 1)).normalized();
      s.angles.push_back(std::acos(std::abs(t.z())));
      const double y0 = P(0, 1), y1 = P(P.rows() - 1, 1);
      s.towards += std::abs(y1 - target_y) < std::abs(y0 - target_y);
      s.drift.push_back((y1 - y0) * (target_y > y0 ? 1.0 : -1.0));
    }
    return s;
  };
  const Decomposition d = decompose_slab_pennate(Architecture::bipennate, alpha,
                                                 HarmonicOptions::PennationReference::line_of_action,
                                                 0.0, false, targets);
  ASSERT_GE(d.fibres.size(), 55u);
  Shape s = measure(d);
  std::printf("median mid-fibre angle %.2f deg, %d of %zu fibres end nearer the target line in y, "
              "median drift towards it %.2f mm\n",
              median(s.angles) * 180 / M_PI, s.towards, d.fibres.size(), median(s.drift) * 1e3);
  EXPECT_NEAR(median(s.angles), alpha, 2.0 * M_PI / 180);
  EXPECT_GE(s.towards, static_cast<int>(0.9 * static_cast<double>(d.fibres.size())));
  EXPECT_GT(median(s.drift), 2e-3);
  // Without targets the fibres turn towards the sheet and keep their y: the drift is the targets'.
  Shape plain = measure(decompose_slab_pennate(Architecture::bipennate, alpha));
  std::printf("without targets: median drift %.3f mm\n", median(plain.drift) * 1e3);
  EXPECT_LT(std::abs(median(plain.drift)), 1e-3);  // 0.57 mm, against 8.6 mm with the targets
  // Non-finite targets are a usage error.
  AponeurosisOptions o;
  o.architecture = Architecture::bipennate;
  o.pennation_rad = alpha;
  o.thickness_direction = Vec3::UnitX();
  const TriMesh m = make_slab();
  HarmonicOptions h;
  h.pennation_rad = alpha;
  h.transverse_targets = targets;
  h.transverse_targets(3, 1) = std::nan("");
  EXPECT_THROW(calc_harmonic_field(m, find_aponeurosis_attachments(m, o), h), Error);
}
