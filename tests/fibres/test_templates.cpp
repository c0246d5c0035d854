// Fibre templates, polyline helpers.
#include "fascicle/core/error.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/fibres/template_mapping.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

using namespace fascicle;

TEST(FibreTemplates, ParseNames) {
  EXPECT_EQ(parse_fibre_template("Parallel"), FibreTemplate::parallel);
  EXPECT_EQ(parse_fibre_template("unipennate"), FibreTemplate::pennate);
  EXPECT_EQ(parse_fibre_template("bipennate"), FibreTemplate::bipennate);
  EXPECT_EQ(to_string(FibreTemplate::fanned), "fanned");
  EXPECT_THROW(parse_fibre_template("spiral"), Error);
}

TEST(FibreTemplates, R2SequenceIsWellSpread) {
  // Every cell of an 8 x 8 grid receives 3 to 5 of the first 256 points (mean 4): a
  // low-discrepancy sequence. Uniform random points would leave about one cell empty.
  int cells[8][8] = {};
  for (int i = 0; i < 256; ++i) {
    const Vec2 r = get_r2_point(i);
    ASSERT_GE(r.minCoeff(), 0.0);
    ASSERT_LT(r.maxCoeff(), 1.0);
    ++cells[static_cast<int>(r.x() * 8)][static_cast<int>(r.y() * 8)];
  }
  for (auto& row : cells)
    for (int c : row) {
      EXPECT_GE(c, 3);
      EXPECT_LE(c, 5);
    }
}

TEST(FibreTemplates, ShapesStayInCubeAndFollowTheirDefinition) {
  for (auto t : {FibreTemplate::parallel, FibreTemplate::pennate, FibreTemplate::bipennate,
                 FibreTemplate::curved, FibreTemplate::fanned}) {
    const FibreSet s = make_template_fibres(t, 50, 11);
    ASSERT_EQ(s.size(), 50u);
    for (const Points3& f : s.fibres) {
      ASSERT_EQ(f.rows(), 11);
      EXPECT_GE(f.minCoeff(), 0.0) << to_string(t);
      EXPECT_LE(f.maxCoeff(), 1.0) << to_string(t);
    }
  }
  // Parallel: straight along z from z = 0 to z = 1, length exactly 1.
  for (const Points3& f : make_template_fibres(FibreTemplate::parallel, 20, 7).fibres) {
    EXPECT_DOUBLE_EQ(f(0, 2), 0.0);
    EXPECT_DOUBLE_EQ(f(6, 2), 1.0);
    EXPECT_NEAR(calc_polyline_length(f), 1.0, 1e-14);
  }
  // Pennate: from x = 0 to x = 1 rising 0.35 in z: length sqrt(1 + 0.35^2).
  for (const Points3& f : make_template_fibres(FibreTemplate::pennate, 20, 5).fibres) {
    EXPECT_DOUBLE_EQ(f(0, 0), 0.0);
    EXPECT_DOUBLE_EQ(f(4, 0), 1.0);
    EXPECT_NEAR(calc_polyline_length(f), std::sqrt(1.0 + 0.35 * 0.35), 1e-12);
  }
  // Bipennate: starts on the central plane, half of the fibres to each side.
  int left = 0;
  for (const Points3& f : make_template_fibres(FibreTemplate::bipennate, 40, 5).fibres) {
    EXPECT_DOUBLE_EQ(f(0, 0), 0.5);
    left += f(4, 0) < 0.5;
  }
  EXPECT_NEAR(left, 20, 3);
  // Fanned: the spread in y at the origin is a quarter of that at the insertion.
  const FibreSet fan = make_template_fibres(FibreTemplate::fanned, 64, 9);
  double y0min = 1, y0max = 0, y1min = 1, y1max = 0;
  for (const Points3& f : fan.fibres) {
    y0min = std::min(y0min, f(0, 1));
    y0max = std::max(y0max, f(0, 1));
    y1min = std::min(y1min, f(8, 1));
    y1max = std::max(y1max, f(8, 1));
  }
  EXPECT_NEAR((y0max - y0min) / (y1max - y1min), 0.25, 1e-12);
  EXPECT_THROW(make_template_fibres(FibreTemplate::parallel, 0, 5), Error);
  EXPECT_THROW(make_template_fibres(FibreTemplate::parallel, 5, 1), Error);
}

TEST(FibreTemplates, ResampleKeepsEndsAndSpacing) {
  Points3 P(3, 3);
  P << 0, 0, 0, 1, 0, 0, 1, 3, 0;  // length 4
  const Points3 R = resample_polyline(P, 5);
  ASSERT_EQ(R.rows(), 5);
  for (int k = 1; k < 5; ++k) {
    // Chords across the corner are shorter than 1; the others exactly 1.
    const double chord = (R.row(k) - R.row(k - 1)).norm();
    EXPECT_LE(chord, 1.0 + 1e-12);
  }
  EXPECT_TRUE(R.row(0).isApprox(P.row(0)));
  EXPECT_TRUE(R.row(4).isApprox(P.row(2)));
  EXPECT_NEAR(R(2, 1), 1.0, 1e-12);  // arc length 2 = 1 along x + 1 along y
  EXPECT_NEAR(R(2, 0), 1.0, 1e-12);
}

// Re-routing targets chosen by farthest-point order among 4 x stratified area samples
// (TemplateMapOptions::target_factor) reach closer to the rim of an attachment area and leave
// smaller gaps than the stratified samples themselves: on a cylinder's origin cap, the largest
// distance from a cap point to the nearest fibre start.
TEST(TemplateMapping, FarthestTargetsSpreadEndsToTheRim) {
  const double r = 0.015, h = 0.1;
  const TriMesh mesh = make_cylinder(r, h, 32, 12);
  std::vector<int> top, bottom;
  for (Eigen::Index v = 0; v < mesh.num_vertices(); ++v) {
    if (mesh.V(v, 2) > h / 2 - 1e-12) top.push_back(static_cast<int>(v));
    if (mesh.V(v, 2) < -h / 2 + 1e-12) bottom.push_back(static_cast<int>(v));
  }
  const Attachments areas{make_attachment_area(mesh, top, "origin"),
                          make_attachment_area(mesh, bottom, "insertion")};
  const FibreSet unit = make_template_fibres(FibreTemplate::parallel, 100, 11);
  const auto largest_gap = [&](int factor) {
    TemplateMapOptions o;
    o.target_factor = factor;
    const FibreSet s = TemplateMapper(mesh, areas, o).calc_fibres(unit, true);
    EXPECT_EQ(s.size(), 100u);
    double worst = 0.0;
    for (int i = -40; i <= 40; ++i)
      for (int j = -40; j <= 40; ++j) {
        const Vec2 p(r * i / 40.0, r * j / 40.0);
        if (p.norm() > 0.97 * r) continue;
        double best = 1e300;
        for (const Points3& P : s.fibres) {
          EXPECT_NEAR(P(0, 2), h / 2, 1e-4);  // starts on the cap (10 um inside at most)
          best = std::min(best, std::hypot(P(0, 0) - p.x(), P(0, 1) - p.y()));
        }
        worst = std::max(worst, best);
      }
    const double gap = worst / std::sqrt(M_PI * r * r / 100.0);
    std::printf("target factor %d: largest gap %.2f sqrt(A/n)\n", factor, gap);
    return gap;
  };
  const double stratified = largest_gap(1), farthest = largest_gap(4);
  // Measured: 1.09 and 0.88.
  EXPECT_LT(farthest, 0.9 * stratified);
  EXPECT_LT(farthest, 0.95);
}

// Field slicing and side re-routing (session 8) on a cylinder (r = 15 mm, h = 100 mm, z up):
// caps keep plane slicing; a strip along the side of the upper half with the bottom cap as the
// other area is sliced by iso-contours of the Laplace potential, so fibres start over the whole
// strip and fill the belly above its centroid level; two strips abutting at mid-height keep
// planes, with the ends re-routed onto the strips from the point where that turns least.
namespace {

struct SideStrips {
  TriMesh mesh;
  std::vector<int> top, bottom, strip_upper, strip_lower;
};

SideStrips make_side_strips(double r, double h) {
  SideStrips s{make_cylinder(r, h, 32, 24), {}, {}, {}, {}};
  for (Eigen::Index v = 0; v < s.mesh.num_vertices(); ++v) {
    const double x = s.mesh.V(v, 0), y = s.mesh.V(v, 1), z = s.mesh.V(v, 2);
    const bool lateral = std::hypot(x, y) > r * (1 - 1e-9) && std::abs(z) < h / 2 - 1e-12;
    const bool strip = lateral && x > r * std::cos(40.0 * M_PI / 180);
    if (z > h / 2 - 1e-12) s.top.push_back(static_cast<int>(v));
    if (z < -h / 2 + 1e-12) s.bottom.push_back(static_cast<int>(v));
    if (strip && z > 1e-9) s.strip_upper.push_back(static_cast<int>(v));
    if (strip && z < -1e-9) s.strip_lower.push_back(static_cast<int>(v));
  }
  return s;
}

// Share of interior grid points with z above z_min within 1.5 sqrt(pi r^2 / n) of a fibre point.
double calc_cylinder_coverage(const FibreSet& s, double r, double h, double z_min) {
  std::vector<Vec3> pts;
  for (const Points3& P : s.fibres) {
    const Points3 R = resample_polyline(P, 8 * static_cast<int>(P.rows()));
    for (Eigen::Index k = 0; k < R.rows(); ++k) pts.emplace_back(R.row(k));
  }
  const double radius = 1.5 * std::sqrt(M_PI * r * r / static_cast<double>(s.size()));
  int inside = 0, covered = 0;
  for (int i = -8; i <= 8; ++i)
    for (int j = -8; j <= 8; ++j)
      for (int k = 0; k <= 20; ++k) {
        const Vec3 p(0.95 * r * i / 8, 0.95 * r * j / 8, -h / 2 + h * (0.02 + 0.96 * k / 20));
        if (std::hypot(p.x(), p.y()) > 0.95 * r || p.z() < z_min) continue;
        ++inside;
        double best = 1e300;
        for (const Vec3& q : pts) best = std::min(best, (q - p).squaredNorm());
        covered += std::sqrt(best) <= radius;
      }
  return static_cast<double>(covered) / inside;
}

}  // namespace

TEST(TemplateMapping, SideStripIsSlicedByTheField) {
  const double r = 0.015, h = 0.1;
  const SideStrips s = make_side_strips(r, h);
  const FibreSet unit = make_template_fibres(FibreTemplate::parallel, 100, 16);
  {
    const Attachments caps{make_attachment_area(s.mesh, s.top, "origin"),
                           make_attachment_area(s.mesh, s.bottom, "insertion")};
    EXPECT_FALSE(TemplateMapper(s.mesh, caps).uses_field_slicing());
  }
  const Attachments areas{make_attachment_area(s.mesh, s.strip_upper, "origin"),
                          make_attachment_area(s.mesh, s.bottom, "insertion")};
  const TemplateMapper field(s.mesh, areas);
  ASSERT_TRUE(field.uses_field_slicing());
  TemplateMapOptions planes_options;
  planes_options.slicing = TemplateMapOptions::Slicing::planes;
  const TemplateMapper planes(s.mesh, areas, planes_options);
  const FibreSet a = field.calc_fibres(unit, true), b = planes.calc_fibres(unit, true);
  ASSERT_EQ(a.size(), 100u);
  double z_lo = 1e300, z_hi = -1e300;
  for (const Points3& P : a.fibres) {
    // Starts on the strip, ends on the bottom cap, inside.
    EXPECT_GT(P(0, 0), r * std::cos(40.0 * M_PI / 180) - 1e-3);
    EXPECT_GT(P(0, 2), -1e-3);
    EXPECT_NEAR(P(P.rows() - 1, 2), -h / 2, 1e-4);
    for (Eigen::Index k = 0; k < P.rows(); ++k)
      EXPECT_LE(std::hypot(P(k, 0), P(k, 1)), r + 1e-6);
    z_lo = std::min(z_lo, P(0, 2));
    z_hi = std::max(z_hi, P(0, 2));
  }
  EXPECT_GT(z_hi - z_lo, 0.8 * h / 2);  // starts spread along the strip
  // Above the strip's centroid level (z > h / 4) plane slicing leaves the belly to re-routed
  // ends.
  const double cov_field = calc_cylinder_coverage(a, r, h, h / 4);
  const double cov_planes = calc_cylinder_coverage(b, r, h, h / 4);
  const double cov_all = calc_cylinder_coverage(a, r, h, -h);
  std::printf("coverage above h/4: field %.3f, planes %.3f; field overall %.3f\n", cov_field,
              cov_planes, cov_all);
  // Measured: 0.893, 0.460 (planes with side re-routing: the strip is a side area), 0.975.
  EXPECT_GT(cov_field, 0.85);
  EXPECT_LT(cov_planes, 0.5);
  EXPECT_GT(cov_all, 0.95);
}

TEST(TemplateMapping, AbuttingSideStripsAreReroutedFromTheSide) {
  const double r = 0.015, h = 0.1;
  const SideStrips s = make_side_strips(r, h);
  const Attachments areas{make_attachment_area(s.mesh, s.strip_upper, "origin"),
                          make_attachment_area(s.mesh, s.strip_lower, "insertion")};
  const FibreSet unit = make_template_fibres(FibreTemplate::parallel, 100, 16);
  const TemplateMapper side(s.mesh, areas);
  EXPECT_FALSE(side.uses_field_slicing());
  TemplateMapOptions old_options;
  old_options.side_reroute = false;
  const TemplateMapper old(s.mesh, areas, old_options);
  const auto count_smooth = [](const FibreSet& f) {
    int smooth = 0;
    for (const Points3& P : f.fibres) {
      double turn = 0.0;
      for (Eigen::Index k = 1; k + 1 < P.rows(); ++k) {
        const Vec3 a = P.row(k) - P.row(k - 1), b = P.row(k + 1) - P.row(k);
        turn = std::max(turn, std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0)));
      }
      smooth += turn < M_PI / 4;
    }
    return smooth;
  };
  const FibreSet a = side.calc_fibres(unit, true), b = old.calc_fibres(unit, true);
  const int smooth_side = count_smooth(a), smooth_old = count_smooth(b);
  const double cov_side = calc_cylinder_coverage(a, r, h, -h);
  const double cov_old = calc_cylinder_coverage(b, r, h, -h);
  std::printf("smooth fibres: side re-routing %d, centroid box %d; coverage %.3f / %.3f\n",
              smooth_side, smooth_old, cov_side, cov_old);
  // Measured: 99 / 45 smooth, coverage 0.719 / 0.661 (two strips on one side: the far side of
  // the belly is crossed by few fibres either way).
  EXPECT_GE(smooth_side, 90);
  EXPECT_LT(smooth_old, 60);
  EXPECT_GE(cov_side, cov_old);
  // Fibre budget along the origin strip (session 9): without it the targets are evenly spaced
  // over the strip and matched by least cost, so few fibres reach the upper end of the belly.
  TemplateMapOptions no_budget;
  no_budget.side_budget = false;
  const FibreSet c = TemplateMapper(s.mesh, areas, no_budget).calc_fibres(unit, true);
  const double top_budget = calc_cylinder_coverage(a, r, h, h / 4);
  const double top_even = calc_cylinder_coverage(c, r, h, h / 4);
  const auto count_upper_starts = [&](const FibreSet& f) {
    int n = 0;
    for (const Points3& P : f.fibres) n += P(0, 2) > h / 4;
    return n;
  };
  const int upper_budget = count_upper_starts(a), upper_even = count_upper_starts(c);
  std::printf("above h/4: coverage %.3f / %.3f, fibres starting %d / %d (budget / evenly spaced "
              "targets); smooth %d\n",
              top_budget, top_even, upper_budget, upper_even, count_smooth(c));
  // The section is constant, so its running maximum is reached at the strip's far end and the
  // budget starts a share 0.5 + 0.5 x 0.5 of the fibres on the upper half of the strip; evenly
  // spaced targets about half. Measured: 75 / 52 fibres, coverage 0.453 / 0.429 (the far side
  // of the belly is crossed by few fibres either way), 99 / 97 smooth.
  EXPECT_NEAR(upper_budget, 75, 2);
  EXPECT_NEAR(upper_even, 50, 4);
  EXPECT_GT(top_budget, top_even);
  for (const Points3& P : a.fibres) {
    EXPECT_GT(P(0, 0), r * std::cos(40.0 * M_PI / 180) - 1e-3);  // ends on the strips
    EXPECT_GT(P(P.rows() - 1, 0), r * std::cos(40.0 * M_PI / 180) - 1e-3);
  }
}

// The section samples come in an order whose every prefix is spread over the section, also past
// the 256 farthest-point candidates (the fibre budget's bands rely on it: band 0 is the first
// tenth of the fibres). Covering radius of a prefix: the largest distance from any sample to the
// nearest sample of the prefix, in the unit square.
TEST(TemplateMapping, SectionSamplePrefixesAreSpreadForEveryCount) {
  const double r = 0.015, h = 0.1;
  const SideStrips s = make_side_strips(r, h);
  const Attachments areas{make_attachment_area(s.mesh, s.strip_upper, "origin"),
                          make_attachment_area(s.mesh, s.strip_lower, "insertion")};
  const TemplateMapper mapper(s.mesh, areas);
  for (const int count : {100, 300, 1000}) {
    const std::vector<Vec2> p = mapper.calc_section_samples(count);
    ASSERT_EQ(static_cast<int>(p.size()), count);
    const std::size_t prefix = static_cast<std::size_t>(count) / 10;
    double cover = 0.0;
    for (const Vec2& q : p) {
      double nearest = std::numeric_limits<double>::infinity();
      for (std::size_t i = 0; i < prefix; ++i) nearest = std::min(nearest, (q - p[i]).norm());
      cover = std::max(cover, nearest);
    }
    std::printf("count %d: covering radius of the first tenth %.3f\n", count, cover);
    // k well-spread points cover the square within about 0.7 / sqrt(k). Measured 0.335, 0.146,
    // 0.077; in the stratified sample's own order (before session 9) the first tenth of 300 and
    // 1000 samples covered it half as well (0.285, 0.141: the test failed).
    EXPECT_LT(cover, 1.2 / std::sqrt(static_cast<double>(prefix)));
  }
}
