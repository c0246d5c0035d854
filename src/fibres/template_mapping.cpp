// Template method: box frame, slices, mean value coordinate map, end re-routing, smoothing.
#include "fascicle/fibres/template_mapping.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/geometry/slicing.hpp"
#include "sampling.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numeric>
#include <unordered_map>

namespace fascicle {

using Poly2 = Eigen::Matrix<double, Eigen::Dynamic, 2>;

VecX calc_mean_value_coordinates(const Poly2& polygon, const Vec2& p) {
  const Eigen::Index n = polygon.rows();
  VecX w(n);
  // tan(alpha_i / 2) = sin / (1 + cos) with alpha_i the signed angle at p between q_i and q_{i+1}.
  std::vector<double> r(n), tan_half(n);
  for (Eigen::Index i = 0; i < n; ++i) r[i] = (Vec2(polygon.row(i)) - p).norm();
  for (Eigen::Index i = 0; i < n; ++i) {
    const Vec2 d0 = Vec2(polygon.row(i)) - p, d1 = Vec2(polygon.row((i + 1) % n)) - p;
    const double cross = d0.x() * d1.y() - d0.y() * d1.x();
    const double denom = r[i] * r[(i + 1) % n] + d0.dot(d1);
    tan_half[i] = cross / std::max(denom, 1e-300);
  }
  for (Eigen::Index i = 0; i < n; ++i)
    w(i) = (tan_half[(i + n - 1) % n] + tan_half[i]) / std::max(r[i], 1e-300);
  const double sum = w.sum();
  return w / sum;
}

namespace {

// The unit square's boundary sampled counter-clockwise from (0,0), n/4 points per side.
Poly2 make_square_boundary(int n) {
  const int q = n / 4;
  Poly2 S(4 * q, 2);
  const std::array<Vec2, 5> c{Vec2(0, 0), Vec2(1, 0), Vec2(1, 1), Vec2(0, 1), Vec2(0, 0)};
  for (int side = 0; side < 4; ++side)
    for (int k = 0; k < q; ++k) {
      const double t = static_cast<double>(k) / q;
      S.row(side * q + k) = ((1 - t) * c[side] + t * c[side + 1]).transpose();
    }
  return S;
}

// Resamples the closed polyline P (rows) from index a to b (cyclic, b after a) to `m` points
// equally spaced in arc length, excluding the end point b.
void resample_piece(const Points3& P, int a, int b, int m, Points3& out, int out_row) {
  const int n = static_cast<int>(P.rows());
  std::vector<Vec3> pts;
  for (int i = a;; i = (i + 1) % n) {
    pts.emplace_back(P.row(i));
    if (i == b) break;
  }
  if (pts.size() == 1) pts.push_back(pts[0]);
  std::vector<double> cum(pts.size(), 0.0);
  for (std::size_t i = 1; i < pts.size(); ++i) cum[i] = cum[i - 1] + (pts[i] - pts[i - 1]).norm();
  const double total = cum.back();
  std::size_t seg = 0;
  for (int k = 0; k < m; ++k) {
    const double target = total * k / m;
    while (seg + 2 < pts.size() && cum[seg + 1] < target) ++seg;
    const double len = cum[seg + 1] - cum[seg];
    const double t = len > 0 ? std::clamp((target - cum[seg]) / len, 0.0, 1.0) : 0.0;
    out.row(out_row + k) = ((1 - t) * pts[seg] + t * pts[seg + 1]).transpose();
  }
}

// A slice contour resampled to match the unit square's boundary samples: split at its extreme
// points in the four diagonal directions of the in-plane frame (ex, ey) and each quarter
// resampled by arc length; with its in-plane coordinates relative to o, its thickness along ex
// (area / extent along ey) and the mean mapped crossing (TemplateMapper::get_mean_crossing).
struct ResampledContour {
  Points3 points;
  Poly2 xy;
  double thickness = 0.0;
  double crossing = 0.0;
};

ResampledContour resample_contour(const Points3& C, const Vec3& ex, const Vec3& ey, const Vec3& o,
                                  int samples) {
  ResampledContour r;
  const int q = samples / 4;
  const int n = static_cast<int>(C.rows());
  // Contour in box coordinates, normalised by its bounding box.
  Poly2 xy(n, 2);
  xy.col(0) = C * ex;
  xy.col(1) = C * ey;
  const Eigen::RowVector2d lo = xy.colwise().minCoeff(), hi = xy.colwise().maxCoeff();
  const Eigen::RowVector2d ext = (hi - lo).cwiseMax(1e-300);
  // Corners: the extreme contour points in the four diagonal directions.
  std::array<int, 4> corner{};
  const std::array<Vec2, 4> dir{Vec2(-1, -1), Vec2(1, -1), Vec2(1, 1), Vec2(-1, 1)};
  for (int j = 0; j < 4; ++j) {
    double best_v = -1e300;
    for (int i = 0; i < n; ++i) {
      const Vec2 u = ((xy.row(i) - lo).cwiseQuotient(ext)).transpose();
      const double v = dir[j].dot(u);
      if (v > best_v) {
        best_v = v;
        corner[j] = i;
      }
    }
  }
  const auto offset = [&](int j) { return (corner[j] - corner[0] + n) % n; };
  const bool ordered = offset(1) > 0 && offset(2) > offset(1) && offset(3) > offset(2);
  if (!ordered) {
    // Fall back to equal arc-length quarters from the first corner.
    std::vector<double> cum(n + 1, 0.0);
    for (int i = 0; i < n; ++i)
      cum[i + 1] = cum[i] + (C.row((corner[0] + i + 1) % n) - C.row((corner[0] + i) % n)).norm();
    for (int j = 1; j < 4; ++j) {
      const double target = cum[n] * j / 4.0;
      const int i = static_cast<int>(std::lower_bound(cum.begin(), cum.end(), target) - cum.begin());
      corner[j] = (corner[0] + std::clamp(i, j, n - 4 + j)) % n;
    }
  }
  Points3& out = r.points;
  out.resize(samples, 3);
  for (int j = 0; j < 4; ++j) resample_piece(C, corner[j], corner[(j + 1) % 4], q, out, j * q);
  Poly2& out_xy = r.xy;
  out_xy.resize(out.rows(), 2);
  const Points3 rel = out.rowwise() - o.transpose();
  out_xy.col(0) = rel * ex;
  out_xy.col(1) = rel * ey;
  {
    // Thickness along x: contour area / extent along y.
    double area2 = 0.0;
    for (Eigen::Index i = 0, j = out_xy.rows() - 1; i < out_xy.rows(); j = i++)
      area2 += out_xy(j, 0) * out_xy(i, 1) - out_xy(i, 0) * out_xy(j, 1);
    const double width = out_xy.col(1).maxCoeff() - out_xy.col(1).minCoeff();
    if (width > 0.0) r.thickness = 0.5 * std::abs(area2) / width;
  }
  {
    // Crossing: the mapped square boundary points (0, y) and (1, y) are the contour points at
    // perimeter parameters 3 + (1 - y) and 1 + y (counter-clockwise from (0,0), q per side).
    const auto at = [&](double t) {
      const double idx = t * q;
      const int i0 = static_cast<int>(std::floor(idx)) % samples;
      const int i1 = (i0 + 1) % samples;
      const double w = idx - std::floor(idx);
      return Vec3((1 - w) * out.row(i0) + w * out.row(i1));
    };
    double crossing = 0.0;
    for (int j = 1; j <= 9; ++j) {
      const double y = 0.1 * j;
      crossing += (at(1.0 + y) - at(3.0 + (1.0 - y))).norm() / 9.0;
    }
    r.crossing = crossing;
  }
  return r;
}

// Closed iso-lines u = t of a per-vertex scalar on a closed triangle mesh (marching triangles),
// each an ordered loop. Vertices with u >= t count as above. In every triangle the line runs
// from the edge entered (below -> above in the triangle's order) to the edge left, so the
// loops have one orientation relative to the side where u > t, and neighbouring triangles
// continue each other through their shared edge.
std::vector<Points3> calc_iso_loops(const TriMesh& mesh, const VecX& u, double t) {
  const std::int64_t nv = mesh.V.rows();
  std::unordered_map<std::int64_t, int> crossing_id;
  std::vector<Vec3> point;
  std::vector<int> next;
  const auto crossing = [&](int i, int j) {
    const std::int64_t key = std::min(i, j) * nv + std::max(i, j);
    const auto [it, added] = crossing_id.emplace(key, static_cast<int>(point.size()));
    if (added) {
      const double w = (t - u(i)) / (u(j) - u(i));
      point.emplace_back(Vec3(mesh.V.row(i)) + w * (Vec3(mesh.V.row(j)) - Vec3(mesh.V.row(i))));
      next.push_back(-1);
    }
    return it->second;
  };
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    int entry = -1, exit = -1;
    for (int e = 0; e < 3; ++e) {
      const int i = mesh.F(f, e), j = mesh.F(f, (e + 1) % 3);
      const bool ai = u(i) >= t, aj = u(j) >= t;
      if (!ai && aj) entry = crossing(i, j);
      if (ai && !aj) exit = crossing(i, j);
    }
    if (entry >= 0 && exit >= 0) next[entry] = exit;
  }
  std::vector<Points3> loops;
  std::vector<char> seen(point.size(), 0);
  for (std::size_t s = 0; s < point.size(); ++s) {
    if (seen[s]) continue;
    std::vector<int> chain;
    int c = static_cast<int>(s);
    while (c >= 0 && !seen[c]) {
      seen[c] = 1;
      chain.push_back(c);
      c = next[c];
    }
    if (c != static_cast<int>(s) || chain.size() < 3) continue;  // open chain (open mesh)
    Points3 L(static_cast<Eigen::Index>(chain.size()), 3);
    for (std::size_t k = 0; k < chain.size(); ++k) L.row(static_cast<Eigen::Index>(k)) = point[chain[k]].transpose();
    loops.push_back(std::move(L));
  }
  return loops;
}

// Vector area of a closed polyline: (1/2) sum p_i x p_i+1 (its normal by the right-hand rule).
Vec3 calc_vector_area(const Points3& L) {
  Vec3 A = Vec3::Zero();
  for (Eigen::Index i = 0, j = L.rows() - 1; i < L.rows(); j = i++)
    A += 0.5 * Vec3(L.row(j)).cross(Vec3(L.row(i)));
  return A;
}

// Range of an area's vertices along the unit direction e, as fractions of the muscle's extent
// along e from its lowest point.
struct AxialRange {
  double lo = 0.0, hi = 0.0;
};

AxialRange calc_axial_range(const TriMesh& muscle, const AttachmentArea& area, const Vec3& e) {
  const VecX s = muscle.V * e;
  const double smin = s.minCoeff(), whole = s.maxCoeff() - smin;
  if (area.vertices.empty() || !(whole > 0.0)) return {};
  AxialRange r{std::numeric_limits<double>::infinity(), -std::numeric_limits<double>::infinity()};
  for (int v : area.vertices) {
    r.lo = std::min(r.lo, (s(v) - smin) / whole);
    r.hi = std::max(r.hi, (s(v) - smin) / whole);
  }
  return r;
}

}  // namespace

struct TemplateMapper::Slices {
  std::vector<double> section_area;  // area of each slice's contour (m^2)
  int samples = 0;              // points per contour (multiple of 4)
  Poly2 square;                 // #samples x 2 unit-square boundary
  std::vector<Points3> contour;  // per slice: #samples x 3 points matching `square`
  std::vector<Poly2> contour_xy;  // the same in box (x, y) coordinates
  // Cells of the template's start square (corners (r.x, r.y, 0)), weighted by the mean mapped
  // cross-section area (calc_section_samples).
  std::vector<detail::WeightedTriangle> section_cells;
  // Candidate start parameters (section-proportional), and the first quarter of them in
  // farthest-point order (a prefix of that order is the farthest-point selection of any size).
  std::vector<Vec2> candidate_r;
  std::vector<Vec2> farthest_first;
  // Field slicing: signed distances to the surface at the centres of a grid over the bounding
  // box (cell `cell`, dims n), for the inside pass: a point of a cell whose centre is deeper
  // than the cell's half diagonal (plus the margin) is inside (the distance is 1-Lipschitz).
  Vec3 grid_lo = Vec3::Zero();
  double cell = 0.0;
  Eigen::Vector3i n = Eigen::Vector3i::Zero();
  VecX grid_distance;
};

TemplateMapper::~TemplateMapper() = default;
TemplateMapper::TemplateMapper(TemplateMapper&&) noexcept = default;
TemplateMapper& TemplateMapper::operator=(TemplateMapper&&) noexcept = default;

TemplateMapper::TemplateMapper(const TriMesh& muscle, const Attachments& areas,
                               const TemplateMapOptions& options)
    : options_(options), areas_(areas), muscle_(muscle) {
  if (options.num_slices < 2 || options.contour_samples < 8)
    throw_usage("template mapping needs at least 2 slices and 8 contour samples");
  // Box frame: z from the origin to the insertion centroid; y the widest direction across it.
  const Vec3 d = areas.insertion.centroid - areas.origin.centroid;
  if (!(d.norm() > 0.0))
    throw_bad_input("the origin and insertion areas have the same centroid",
                    {.suggestion = "give attachment areas at the two ends of the muscle"});
  const Vec3 ez = d.normalized();
  const Vec3 mean = muscle.V.colwise().mean();
  Points3 D = muscle.V.rowwise() - mean.transpose();
  D -= (D * ez) * ez.transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(D.transpose() * D);
  Vec3 ey = eig.eigenvectors().col(2);
  ey = (ey - ey.dot(ez) * ez).normalized();
  Vec3 ex = ey.cross(ez);
  if (options.thickness_direction.norm() > 0.0) {
    const Vec3 t = options.thickness_direction - options.thickness_direction.dot(ez) * ez;
    if (!(t.norm() > 1e-6 * options.thickness_direction.norm()))
      throw_usage("the thickness direction is parallel to the line of action",
                  {.suggestion = "give a direction across the muscle"});
    ex = t.normalized();
    ey = ez.cross(ex);
  }
  if (ex.dot(options.insertion_side_towards) < 0.0) {
    ex = -ex;
    ey = ez.cross(ex);  // keep the frame right-handed
  }
  // Slicing (TemplateMapOptions::slicing) and side areas (an area whose extent along the axis
  // exceeds side_area_extent of the muscle's).
  const AxialRange range_o = calc_axial_range(muscle, areas.origin, ez);
  const AxialRange range_i = calc_axial_range(muscle, areas.insertion, ez);
  origin_side_ = range_o.hi - range_o.lo > options.side_area_extent;
  side_areas_ = origin_side_ || range_i.hi - range_i.lo > options.side_area_extent;
  switch (options.slicing) {
    case TemplateMapOptions::Slicing::planes: field_slicing_ = false; break;
    case TemplateMapOptions::Slicing::field: field_slicing_ = true; break;
    case TemplateMapOptions::Slicing::automatic: {
      const double gap = std::max(range_i.lo - range_o.hi, range_o.lo - range_i.hi);
      field_slicing_ = side_areas_ && gap > options.min_area_gap;
      break;
    }
  }
  // Axial range: from the origin level to the insertion level, kept clear of the tips. Planes
  // with side areas: from the origin area's far end to the insertion area's far end, so the
  // slices reach the whole belly the areas lie along.
  const VecX s = muscle.V * ez;
  const double smin = s.minCoeff(), smax = s.maxCoeff();
  const double margin = options.end_margin * (smax - smin);
  const bool whole_range = side_areas_ && !field_slicing_ && options.side_reroute;
  const double a = std::clamp(whole_range ? smin + range_o.lo * (smax - smin) : areas.origin.centroid.dot(ez),
                              smin + margin, smax - margin);
  const double b = std::clamp(whole_range ? smin + range_i.hi * (smax - smin) : areas.insertion.centroid.dot(ez),
                              smin + margin, smax - margin);
  if (!(b > a)) throw_bad_input("the attachment areas are not at the two ends of the muscle");
  axial_length_ = b - a;
  Mat3 R;
  R << ex, ey, ez;
  X_mesh_box_.linear() = R;
  X_mesh_box_.translation() = mean + (a - mean.dot(ez)) * ez;

  slices_ = std::make_unique<Slices>();
  slices_->samples = options.contour_samples / 4 * 4;
  slices_->square = make_square_boundary(slices_->samples);
  const int K = options.num_slices;
  if (field_slicing_) {
    // Iso-contours of the Laplace potential: u on the surface vertices (the first tet vertices),
    // at the levels splitting the volume (tets by their mean u) into equal parts.
    Attachments surface_areas = areas;
    surface_areas.insertion_interior = Points3(0, 3);  // the template ignores it
    HarmonicOptions ho;
    ho.tets = options.field_tets;
    const HarmonicField field = calc_harmonic_field(muscle, surface_areas, ho);
    const TetMesh& tm = field.tets;
    std::vector<std::pair<double, double>> u_volume(static_cast<std::size_t>(tm.num_tets()));
    double total = 0.0;
    for (Eigen::Index t = 0; t < tm.num_tets(); ++t) {
      const Vec3 p0 = tm.V.row(tm.T(t, 0)), p1 = tm.V.row(tm.T(t, 1)), p2 = tm.V.row(tm.T(t, 2)),
                 p3 = tm.V.row(tm.T(t, 3));
      const double vol = std::abs((p1 - p0).cross(p2 - p0).dot(p3 - p0)) / 6.0;
      const double um = 0.25 * (field.u(tm.T(t, 0)) + field.u(tm.T(t, 1)) + field.u(tm.T(t, 2)) +
                                field.u(tm.T(t, 3)));
      u_volume[static_cast<std::size_t>(t)] = {um, vol};
      total += vol;
    }
    std::sort(u_volume.begin(), u_volume.end());
    const VecX u_surface = field.u.head(muscle.V.rows());
    const double f0 = std::clamp(options.field_end_fraction, 0.0, 0.49);
    std::vector<Points3> loops(K);
    std::vector<Vec3> normal(K);
    double cum = 0.0;
    std::size_t it = 0;
    for (int k = 0; k < K; ++k) {
      const double target = (f0 + (1.0 - 2.0 * f0) * k / (K - 1)) * total;
      while (it + 1 < u_volume.size() && cum + u_volume[it].second < target) cum += u_volume[it++].second;
      const double level = std::clamp(u_volume[it].first, 1e-6, 1.0 - 1e-6);
      std::vector<Points3> L = calc_iso_loops(muscle, u_surface, level);
      if (L.empty())
        throw_bad_input("an iso-contour of the attachment potential is missing",
                        {.suggestion = "check the mesh is closed (run the mesh check/repair)"});
      // The largest loop (by vector area); others are small folds of the surface.
      int best = 0;
      double best_area = -1.0;
      for (std::size_t c = 0; c < L.size(); ++c)
        if (const double A = calc_vector_area(L[c]).norm(); A > best_area) {
          best_area = A;
          best = static_cast<int>(c);
        }
      if (L[best].rows() < 8)
        throw_bad_input("an iso-contour of the attachment potential crosses only " +
                            std::to_string(L[best].rows()) + " mesh edges, too few to map the template",
                        {.suggestion = "refine the muscle mesh or use plane slicing "
                                       "(TemplateMapOptions::slicing = planes)"});
      loops[k] = std::move(L[best]);
      normal[k] = calc_vector_area(loops[k]).normalized();
    }
    // One orientation for all loops (by construction), turned so the normals point from the
    // origin to the insertion; in-plane frames carried from the middle level (x from the box's x).
    const int mid = K / 2;
    if (normal[mid].dot(ez) < 0.0)
      for (int k = 0; k < K; ++k) {
        normal[k] = -normal[k];
        loops[k] = loops[k].colwise().reverse().eval();
      }
    std::vector<Vec3> fx(K);
    const auto carry = [&](const Vec3& x, const Vec3& n) {
      const Vec3 p = x - x.dot(n) * n;
      return p.norm() > 1e-6 ? Vec3(p.normalized()) : Vec3(n.unitOrthogonal());
    };
    fx[mid] = carry(ex, normal[mid]);
    for (int k = mid + 1; k < K; ++k) fx[k] = carry(fx[k - 1], normal[k]);
    for (int k = mid - 1; k >= 0; --k) fx[k] = carry(fx[k + 1], normal[k]);
    double length = 0.0;
    Vec3 previous = Vec3::Zero();
    for (int k = 0; k < K; ++k) {
      const Vec3 centre = loops[k].colwise().mean().transpose();
      const Vec3 fy = normal[k].cross(fx[k]);
      ResampledContour r = resample_contour(loops[k], fx[k], fy, centre, slices_->samples);
      mean_thickness_ += r.thickness / K;
      mean_crossing_ += r.crossing / K;
      slices_->contour.push_back(std::move(r.points));
      slices_->contour_xy.push_back(std::move(r.xy));
      if (k > 0) length += (centre - previous).norm();
      previous = centre;
    }
    axial_length_ = length;
  } else {
    VecX offsets(K);
    for (int k = 0; k < K; ++k) offsets(k) = a + (b - a) * k / (K - 1);
    const auto cuts = slice_mesh_parallel(muscle, ez, offsets);
    for (int k = 0; k < K; ++k) {
      // The largest closed contour; other sizeable ones make the slice an issue.
      int best = -1;
      double best_area = 0.0;
      std::vector<double> areas_k;
      for (std::size_t c = 0; c < cuts[k].size(); ++c) {
        if (!cuts[k][c].closed) continue;
        const double A = compute_contour_area(cuts[k][c], ez);
        areas_k.push_back(A);
        if (A > best_area) {
          best_area = A;
          best = static_cast<int>(c);
        }
      }
      if (best < 0)
        throw_bad_input("a slice of the muscle between its attachment areas has no closed contour",
                        {.suggestion = "check the mesh is closed (run the mesh check/repair)"});
      const int sizeable = static_cast<int>(
          std::count_if(areas_k.begin(), areas_k.end(), [&](double A) { return A > 0.05 * best_area; }));
      if (sizeable > 1) {
        SliceIssue issue;
        issue.axial_position_m = offsets(k) - a;
        issue.point = X_mesh_box_.translation() + issue.axial_position_m * ez;
        issue.num_contours = sizeable;
        issues_.push_back(issue);
      }
      const Points3& C = cuts[k][best].points;
      ResampledContour r = resample_contour(C, ex, ey, X_mesh_box_.translation(), slices_->samples);
      mean_thickness_ += r.thickness / K;
      mean_crossing_ += r.crossing / K;
      Points3 out = std::move(r.points);
      Poly2 out_xy = std::move(r.xy);
      slices_->contour.push_back(std::move(out));
      slices_->contour_xy.push_back(std::move(out_xy));
    }
  }
  for (const Poly2& xy : slices_->contour_xy) {
    double area2 = 0.0;
    for (Eigen::Index i = 0, j = xy.rows() - 1; i < xy.rows(); j = i++)
      area2 += xy(j, 0) * xy(i, 1) - xy(i, 0) * xy(j, 1);
    mean_section_area_ += 0.5 * std::abs(area2) / K;
    slices_->section_area.push_back(0.5 * std::abs(area2));
  }
  {
    // Mean mapped area of the start square's cells (two triangles per cell), over the slices.
    constexpr int G = 16;
    constexpr double inset = 0.02;  // as make_template_fibres
    std::vector<Points3> node(K, Points3((G + 1) * (G + 1), 3));
    for (int i = 0; i <= G; ++i)
      for (int j = 0; j <= G; ++j) {
        const Vec2 uv(inset + (1.0 - 2.0 * inset) * i / G, inset + (1.0 - 2.0 * inset) * j / G);
        const VecX lambda = calc_mean_value_coordinates(slices_->square, uv);
        for (int k = 0; k < K; ++k)
          node[k].row(i * (G + 1) + j) = (slices_->contour[k].transpose() * lambda).transpose();
      }
    const auto id = [](int i, int j) { return i * (G + 1) + j; };
    for (int i = 0; i < G; ++i)
      for (int j = 0; j < G; ++j)
        for (int half = 0; half < 2; ++half) {
          const std::array<int, 3> n = half == 0
                                           ? std::array<int, 3>{id(i, j), id(i + 1, j), id(i + 1, j + 1)}
                                           : std::array<int, 3>{id(i, j), id(i + 1, j + 1), id(i, j + 1)};
          detail::WeightedTriangle cell;
          for (int c = 0; c < 3; ++c)
            cell.corner[c] = Vec3(static_cast<double>(n[c] / (G + 1)) / G,
                                  static_cast<double>(n[c] % (G + 1)) / G, 0.0);
          for (int k = 0; k < K; ++k) {
            const Vec3 a = node[k].row(n[0]), b = node[k].row(n[1]), c = node[k].row(n[2]);
            cell.weight += 0.5 * (b - a).cross(c - a).norm() / K;
          }
          slices_->section_cells.push_back(cell);
        }
    // Candidates and their images in four slices (1/8, 3/8, 5/8, 7/8 of the axis), one column
    // of 12 coordinates each; farthest-point order of the first quarter.
    const std::vector<detail::TriangleSample> cand =
        detail::sample_triangles(slices_->section_cells, 1024);
    const Eigen::Index m = static_cast<Eigen::Index>(cand.size());
    Eigen::Matrix<double, 12, Eigen::Dynamic> image(12, m);
    for (Eigen::Index c = 0; c < m; ++c) {
      const Vec2 r(cand[c].point.x(), cand[c].point.y());
      slices_->candidate_r.push_back(r);
      const VecX lambda = calc_mean_value_coordinates(
          slices_->square, Vec2::Constant(inset) + (1.0 - 2.0 * inset) * r);
      for (int j = 0; j < 4; ++j) {
        const int k = std::clamp((2 * j + 1) * K / 8, 0, K - 1);
        image.block<3, 1>(3 * j, c) = slices_->contour[k].transpose() * lambda;
      }
    }
    if (m > 0) {
      VecX d2 = VecX::Constant(m, std::numeric_limits<double>::infinity());
      Eigen::Index pick = 0;
      const Eigen::Matrix<double, 12, 1> mean = image.rowwise().mean();
      (image.colwise() - mean).colwise().squaredNorm().minCoeff(&pick);
      for (Eigen::Index i = 0; i < m / 4; ++i) {
        slices_->farthest_first.push_back(slices_->candidate_r[pick]);
        d2 = d2.cwiseMin((image.colwise() - image.col(pick)).colwise().squaredNorm().transpose());
        d2.maxCoeff(&pick);
      }
    }
  }
  query_ = std::make_unique<MeshQuery>(muscle);
  if (field_slicing_) {
    // About 32k cells over the bounding box.
    Slices& S = *slices_;
    const Vec3 lo = muscle.V.colwise().minCoeff(), hi = muscle.V.colwise().maxCoeff();
    const Vec3 ext = (hi - lo).cwiseMax(1e-9);
    S.cell = std::cbrt(ext.prod() / 32768.0);
    S.n = (ext / S.cell).array().ceil().cast<int>().max(1).matrix();
    S.grid_lo = lo;
    Points3 centres(static_cast<Eigen::Index>(S.n.prod()), 3);
    for (int i = 0; i < S.n.x(); ++i)
      for (int j = 0; j < S.n.y(); ++j)
        for (int k = 0; k < S.n.z(); ++k)
          centres.row((static_cast<Eigen::Index>(i) * S.n.y() + j) * S.n.z() + k) =
              (lo + S.cell * Vec3(i + 0.5, j + 0.5, k + 0.5)).transpose();
    S.grid_distance = query_->calc_signed_distances(centres);
  }
}

std::vector<Vec2> TemplateMapper::calc_section_samples(int count) const {
  const Slices& S = *slices_;
  if (count >= 1 && count <= static_cast<int>(S.farthest_first.size()))
    return {S.farthest_first.begin(), S.farthest_first.begin() + count};
  const std::vector<detail::TriangleSample> samples =
      detail::sample_triangles(slices_->section_cells, count);
  // The stratified sample comes in cell order; put it in farthest-point order (in the unit
  // square, from the sample nearest its centroid), so that every prefix is spread over the
  // section as the first 256 are: the side re-routing's fibre budget matches fibres in bands of
  // that order (reroute_to_side_area).
  const auto n = static_cast<Eigen::Index>(samples.size());
  std::vector<Vec2> out;
  out.reserve(samples.size());
  if (n == 0) return out;
  Eigen::Matrix2Xd r(2, n);
  for (Eigen::Index i = 0; i < n; ++i) r.col(i) = samples[i].point.head<2>();
  Eigen::VectorXd d2 = (r.colwise() - r.rowwise().mean()).colwise().squaredNorm().transpose();
  Eigen::Index pick = 0;
  d2.minCoeff(&pick);
  d2.setConstant(std::numeric_limits<double>::infinity());
  for (Eigen::Index i = 0; i < n; ++i) {
    out.emplace_back(r.col(pick));
    d2 = d2.cwiseMin((r.colwise() - r.col(pick)).colwise().squaredNorm().transpose());
    d2(pick) = -1.0;  // taken
    d2.maxCoeff(&pick);
  }
  return out;
}

namespace {

// Laplacian smoothing of the interior points (ends fixed).
void smooth(Points3& P, int iterations) {
  for (int it = 0; it < iterations; ++it) {
    const Points3 Q = P;
    for (Eigen::Index k = 1; k + 1 < P.rows(); ++k)
      P.row(k) = 0.5 * Q.row(k) + 0.25 * (Q.row(k - 1) + Q.row(k + 1));
  }
}

// Signed 2-D clearance of p from a closed polygon: distance to its nearest edge, positive inside
// (even-odd rule), negative outside.
double calc_clearance(const Poly2& poly, const Vec2& p) {
  const Eigen::Index n = poly.rows();
  bool inside = false;
  double d2 = std::numeric_limits<double>::infinity();
  for (Eigen::Index i = 0, j = n - 1; i < n; j = i++) {
    const Vec2 a = poly.row(j), b = poly.row(i);
    if ((b.y() > p.y()) != (a.y() > p.y()) &&
        p.x() < (a.x() - b.x()) * (p.y() - b.y()) / (a.y() - b.y()) + b.x())
      inside = !inside;
    const Vec2 e = b - a;
    const double t = std::clamp((p - a).dot(e) / std::max(e.squaredNorm(), 1e-300), 0.0, 1.0);
    d2 = std::min(d2, (a + t * e - p).squaredNorm());
  }
  return inside ? std::sqrt(d2) : -std::sqrt(d2);
}

// `count` points of an attachment area for the re-routed fibre ends: with factor > 1, chosen by
// farthest-point order among factor x count stratified area samples (starting with the sample
// nearest the area's centroid), so they are evenly spaced out to the area's rim; else the
// stratified samples themselves.
Points3 select_area_targets(const TriMesh& muscle, const AttachmentArea& area, int count,
                            int factor) {
  if (factor <= 1) return calc_area_samples(muscle, area, count);
  const Points3 C = calc_area_samples(muscle, area, factor * count);
  const Eigen::Index m = C.rows();
  Points3 out(std::min<Eigen::Index>(count, m), 3);
  if (out.rows() == 0) return out;
  std::vector<double> d2(m, std::numeric_limits<double>::infinity());
  Eigen::Index pick = 0;
  double nearest = std::numeric_limits<double>::infinity();
  for (Eigen::Index j = 0; j < m; ++j)
    if (const double d = (Vec3(C.row(j)) - area.centroid).squaredNorm(); d < nearest) {
      nearest = d;
      pick = j;
    }
  for (Eigen::Index i = 0; i < out.rows(); ++i) {
    const Vec3 p = C.row(pick);
    out.row(i) = p.transpose();
    Eigen::Index next = 0;
    for (Eigen::Index j = 0; j < m; ++j) {
      d2[j] = std::min(d2[j], (Vec3(C.row(j)) - p).squaredNorm());
      if (d2[j] > d2[next]) next = j;
    }
    pick = next;
  }
  return out;
}

// Targets on an origin side area with a fibre budget along the axis (TemplateMapOptions::
// side_budget): a fibre re-routed onto the strip crosses only the sections beyond its target, so
// the number of targets up to each slice interval b (counted from slice 0, the origin area's far
// end) is count x (share x R_b + (1 - share) x S_b), R_b the running maximum of the section area
// over the intervals the area reaches up to b, divided by its maximum there, and S_b the fraction
// of the area's samples up to b. Within these quotas the targets are chosen by farthest-point
// order among factor x count stratified samples, as select_area_targets (quota beyond an
// interval's samples passes on to the next, and what is left at the near end back to the
// previous ones).
Points3 select_budget_targets(const TriMesh& muscle, const AttachmentArea& area, int count,
                              int factor, const Vec3& axis, double level0, double spacing,
                              const std::vector<double>& section, double share) {
  const Points3 C = calc_area_samples(muscle, area, std::max(factor, 1) * count);
  const Eigen::Index m = C.rows();
  const int nb = static_cast<int>(section.size()) - 1;
  if (m == 0 || nb < 1) return Points3(0, 3);
  std::vector<int> bin(static_cast<std::size_t>(m));
  std::vector<int> have(static_cast<std::size_t>(nb), 0);
  for (Eigen::Index j = 0; j < m; ++j) {
    const double b = std::floor((Vec3(C.row(j)).dot(axis) - level0) / spacing);
    bin[j] = static_cast<int>(std::clamp(b, 0.0, nb - 1.0));
    ++have[bin[j]];
  }
  double area_max = 0.0;
  for (int b = 0; b < nb; ++b)
    if (have[b] > 0) area_max = std::max(area_max, 0.5 * (section[b] + section[b + 1]));
  std::vector<int> quota(static_cast<std::size_t>(nb), 0);
  double running = 0.0;
  int samples_so_far = 0, given = 0, carry = 0;
  for (int b = 0; b < nb; ++b) {
    if (have[b] > 0) running = std::max(running, 0.5 * (section[b] + section[b + 1]));
    samples_so_far += have[b];
    const double fraction = share * (area_max > 0.0 ? running / area_max : 1.0) +
                            (1.0 - share) * samples_so_far / static_cast<double>(m);
    const int wanted = static_cast<int>(std::lround(count * std::min(1.0, fraction)));
    const int q = std::max(0, wanted - given) + carry;
    given = std::max(given, wanted);
    quota[b] = std::min(q, have[b]);
    carry = q - quota[b];
  }
  for (int b = nb - 1; b >= 0 && carry > 0; --b) {  // left over at the near end: back-fill
    const int extra = std::min(carry, have[b] - quota[b]);
    quota[b] += extra;
    carry -= extra;
  }
  Points3 out(std::min<Eigen::Index>(count, m), 3);
  std::vector<double> d2(static_cast<std::size_t>(m), std::numeric_limits<double>::infinity());
  std::vector<char> taken(static_cast<std::size_t>(m), 0);
  Eigen::Index pick = -1;
  double nearest = std::numeric_limits<double>::infinity();
  for (Eigen::Index j = 0; j < m; ++j)
    if (const double d = (Vec3(C.row(j)) - area.centroid).squaredNorm();
        quota[bin[j]] > 0 && d < nearest) {
      nearest = d;
      pick = j;
    }
  Eigen::Index n = 0;
  while (pick >= 0 && n < out.rows()) {
    const Vec3 p = C.row(pick);
    out.row(n++) = p.transpose();
    taken[pick] = 1;
    --quota[bin[pick]];
    Eigen::Index next = -1;
    for (Eigen::Index j = 0; j < m; ++j) {
      d2[j] = std::min(d2[j], (Vec3(C.row(j)) - p).squaredNorm());
      if (!taken[j] && quota[bin[j]] > 0 && (next < 0 || d2[j] > d2[next])) next = j;
    }
    pick = next;
  }
  return out.topRows(n);
}

// Re-routing onto a side area (an area along the belly; TemplateMapOptions::side_reroute): a
// fibre leaves its mapped path for its target at the point j of its end half that minimises
// turn_j + |P_j - T| / spacing, turn_j the angle between the segment from the target T to P_j
// and the fibre's own direction there (one radian of turn weighs as much as one fibre spacing
// of segment), among the points turning at most max_turn; targets are matched to fibres greedily, globally, by that least cost, and the
// points before P_j are replaced by the segment. So the fibres start along the whole area and
// leave the side at a shallow angle, instead of turning back to it from the end of the box.
struct SideCut {
  double cost = std::numeric_limits<double>::infinity();
  Eigen::Index point = 1;
};

SideCut find_side_cut(const Points3& P, const Vec3& T, bool at_origin, double spacing,
                      double max_turn) {
  const Eigen::Index m = P.rows();
  // Candidates in order of their segment length (the cost is at least length / spacing, so the
  // search stops at the first one that cannot win; ties go to the point nearest the end).
  std::array<std::pair<double, Eigen::Index>, 64> order;
  int n = 0;
  for (Eigen::Index j = 1; j <= m / 2 && j + 1 < m && n < 64; ++j)
    order[n++] = {(Vec3(P.row(at_origin ? j : m - 1 - j)) - T).norm() / spacing, j};
  std::sort(order.begin(), order.begin() + n);
  SideCut best;
  for (int i = 0; i < n; ++i) {
    const auto [reach, j] = order[i];
    if (reach > best.cost) break;
    const Eigen::Index a = at_origin ? j : m - 1 - j, b = at_origin ? j + 1 : m - 2 - j;
    const Vec3 d = Vec3(P.row(a)) - T, tangent = P.row(b) - P.row(a);
    const double turn = reach > 0.0 && tangent.norm() > 0.0
                            ? std::acos(std::clamp(d.normalized().dot(tangent.normalized()), -1.0, 1.0))
                            : 0.0;
    // A point that would turn more than max_turn is taken only when no other is left (10 rad:
    // more than any turn).
    const double cost = turn + reach + (turn > max_turn ? 10.0 : 0.0);
    if (cost < best.cost || (cost == best.cost && j < best.point)) best = {cost, j};
  }
  return best;
}

// bands > 0 (fibre budget, origin side areas): fibre f < n = min(count, targets) is matched
// within band floor(f bands / n) to the targets of the same band in their order from the area's
// far end along `axis` (so the first fibres, spread over the section by the start order, start
// nearest the muscle's end); bands = 0: one global band over all targets.
void reroute_to_side_area(std::vector<Points3>& fibres, const Points3& targets, bool at_origin,
                          double spacing, double max_turn, const Vec3& axis, int bands) {
  const int count = static_cast<int>(fibres.size());
  const int nt = static_cast<int>(targets.rows());
  const int n = std::min(count, nt);
  std::vector<int> order(static_cast<std::size_t>(nt));  // targets from the far end
  std::iota(order.begin(), order.end(), 0);
  if (bands > 0) {
    const double sign = at_origin ? 1.0 : -1.0;
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
      return sign * targets.row(a).dot(axis) < sign * targets.row(b).dot(axis);
    });
  }
  const int num_bands = bands > 0 ? std::min(bands, std::max(n, 1)) : 1;
  std::vector<int> target_of(count, -1);
  std::vector<char> used(nt, 0);
  for (int band = 0; band < num_bands; ++band) {
    // Fibres [f0, f1) and, with bands, the targets of ranks [f0, f1); else all fibres and targets.
    const int f0 = bands > 0 ? band * n / num_bands : 0;
    const int f1 = bands > 0 ? (band + 1) * n / num_bands : count;
    const int r0 = bands > 0 ? f0 : 0, r1 = bands > 0 ? f1 : nt;
    std::vector<std::pair<double, std::int64_t>> pairs;
    pairs.reserve(static_cast<std::size_t>(f1 - f0) * (r1 - r0));
    for (int f = f0; f < f1; ++f)
      for (int r = r0; r < r1; ++r) {
        const int t = order[r];
        pairs.emplace_back(find_side_cut(fibres[f], targets.row(t), at_origin, spacing, max_turn).cost,
                           static_cast<std::int64_t>(f) * nt + t);
      }
    std::sort(pairs.begin(), pairs.end());
    int assigned = 0;
    for (const auto& [cost, ft] : pairs) {
      const int f = static_cast<int>(ft / nt), t = static_cast<int>(ft % nt);
      if (target_of[f] >= 0 || used[t]) continue;
      target_of[f] = t;
      used[t] = 1;
      if (++assigned == std::min(f1 - f0, r1 - r0)) break;
    }
  }
  for (int f = 0; f < count; ++f) {
    if (target_of[f] < 0) continue;
    Points3& P = fibres[f];
    const Eigen::Index m = P.rows();
    const auto idx = [&](Eigen::Index j) { return at_origin ? j : m - 1 - j; };
    const Vec3 T = targets.row(target_of[f]);
    const Eigen::Index cut = find_side_cut(P, T, at_origin, spacing, max_turn).point;
    const Vec3 pk = P.row(idx(cut));
    for (Eigen::Index j = 0; j < cut; ++j) {
      const double w = static_cast<double>(j) / cut;  // 0 at the target, -> 1 at the cut
      P.row(idx(j)) = ((1 - w) * T + w * pk).transpose();
    }
  }
}

}  // namespace

FibreSet TemplateMapper::calc_fibres(const FibreSet& unit_fibres, bool reroute_ends) const {
  const Slices& S = *slices_;
  const int K = static_cast<int>(S.contour.size());
  const int n = S.samples;
  const int q = n / 4;
  FibreSet out;
  out.fibres.resize(unit_fibres.size());
  // Map every template point: MVC weights in the unit square, blended between the two slices.
  for (std::size_t f = 0; f < unit_fibres.size(); ++f) {
    const Points3& T = unit_fibres.fibres[f];
    Points3 P(T.rows(), 3);
    for (Eigen::Index k = 0; k < T.rows(); ++k) {
      const Vec2 uv(std::clamp(T(k, 0), 0.0, 1.0), std::clamp(T(k, 1), 0.0, 1.0));
      const double kappa = std::clamp(T(k, 2), 0.0, 1.0) * (K - 1);
      const int k0 = std::min(static_cast<int>(kappa), K - 2);
      const double beta = kappa - k0;
      const double eps = 1e-9;
      Vec3 p0, p1;
      const bool on_boundary = uv.minCoeff() < eps || uv.maxCoeff() > 1 - eps;
      if (on_boundary) {
        // Perimeter parameter of the square boundary (counter-clockwise from (0,0)), in samples.
        double t;
        if (uv.y() < eps) t = uv.x();
        else if (uv.x() > 1 - eps) t = 1 + uv.y();
        else if (uv.y() > 1 - eps) t = 2 + (1 - uv.x());
        else t = 3 + (1 - uv.y());
        const double idx = t * q;
        const int i0 = static_cast<int>(std::floor(idx)) % n;
        const int i1 = (i0 + 1) % n;
        const double w = idx - std::floor(idx);
        p0 = (1 - w) * S.contour[k0].row(i0) + w * S.contour[k0].row(i1);
        p1 = (1 - w) * S.contour[k0 + 1].row(i0) + w * S.contour[k0 + 1].row(i1);
      } else {
        const VecX lambda = calc_mean_value_coordinates(S.square, uv);
        p0 = S.contour[k0].transpose() * lambda;
        p1 = S.contour[k0 + 1].transpose() * lambda;
      }
      P.row(k) = ((1 - beta) * p0 + beta * p1).transpose();
    }
    out.fibres[f] = std::move(P);
  }
  // Re-route the ends of end-to-end fibres over the whole attachment areas (seed 002, section 3):
  // the part near each end is replaced by a segment to a point of the area; area points are
  // matched to fibres greedily by distance to the fibre's extrapolated end.
  if (reroute_ends && !out.fibres.empty()) {
    const int count = static_cast<int>(out.fibres.size());
    const auto reroute = [&](bool at_origin) {
      const AttachmentArea& area = at_origin ? areas_.origin : areas_.insertion;
      const bool side = side_areas_ && !field_slicing_ && options_.side_reroute;
      const int factor =
          side ? std::max(options_.target_factor, options_.side_target_factor) : options_.target_factor;
      // Fibre budget along an origin side area (TemplateMapOptions::side_budget).
      const bool budget = side && at_origin && origin_side_ && options_.side_budget;
      const Vec3 axis = X_mesh_box_.linear().col(2);
      const Points3 targets =
          budget ? select_budget_targets(muscle_, area, count, factor, axis,
                                         X_mesh_box_.translation().dot(axis), axial_length_ / (K - 1),
                                         S.section_area, std::clamp(options_.side_section_share, 0.0, 1.0))
                 : select_area_targets(muscle_, area, count, factor);
      if (side) {
        // Fibre spacing: sqrt(mean slice area / count).
        reroute_to_side_area(out.fibres, targets, at_origin, std::sqrt(mean_section_area_ / count),
                             options_.side_max_turn_rad, axis,
                             budget ? std::max(options_.side_order_bands, 1) : 0);
        return;
      }
      std::vector<Vec3> guess(count);
      std::vector<Eigen::Index> cut(count);
      for (int f = 0; f < count; ++f) {
        const Points3& P = out.fibres[f];
        const Eigen::Index m = P.rows();
        // Field slices end on the areas: only the end point moves to its target.
        const Eigen::Index c =
            field_slicing_ ? 1
                           : std::clamp<Eigen::Index>(
                                 static_cast<Eigen::Index>(std::lround(options_.reroute_fraction * (m - 1))),
                                 1, m / 2 - 0);
        const Eigen::Index keep = at_origin ? c : m - 1 - c;
        const Eigen::Index inner = at_origin ? keep + 1 : keep - 1;
        const Vec3 pk = P.row(keep), pi = P.row(std::clamp<Eigen::Index>(inner, 0, m - 1));
        const Vec3 end = P.row(at_origin ? 0 : m - 1);
        const Vec3 dir = (pk - pi).norm() > 0 ? Vec3((pk - pi).normalized()) : Vec3::Zero();
        // Field slices: the mapped end already lies at its attachment area (the first and last
        // slices wrap the areas), so it is matched as it is; plane slices end at the centroid
        // levels, and the end is extrapolated along the fibre.
        guess[f] = field_slicing_ ? end : Vec3(pk + dir * (end - pk).norm());
        cut[f] = keep;
      }
      // Greedy global matching by distance.
      std::vector<std::pair<double, std::int64_t>> pairs;
      pairs.reserve(static_cast<std::size_t>(count) * count);
      for (int f = 0; f < count; ++f)
        for (int t = 0; t < count; ++t)
          pairs.emplace_back((guess[f] - Vec3(targets.row(t))).squaredNorm(),
                             static_cast<std::int64_t>(f) * count + t);
      std::sort(pairs.begin(), pairs.end());
      std::vector<int> target_of(count, -1);
      std::vector<char> used(count, 0);
      int assigned = 0;
      for (const auto& [d2, ft] : pairs) {
        const int f = static_cast<int>(ft / count), t = static_cast<int>(ft % count);
        if (target_of[f] >= 0 || used[t]) continue;
        target_of[f] = t;
        used[t] = 1;
        if (++assigned == count) break;
      }
      for (int f = 0; f < count; ++f) {
        Points3& P = out.fibres[f];
        const Eigen::Index m = P.rows();
        const Vec3 end = targets.row(target_of[f]);
        const Vec3 pk = P.row(cut[f]);
        const Eigen::Index c = at_origin ? cut[f] : m - 1 - cut[f];
        // Replace the c removed points by points on the segment to the area.
        for (Eigen::Index j = 0; j < c; ++j) {
          const double t = static_cast<double>(c - j) / c;  // 1 at the end, -> 0 at the cut
          const Eigen::Index row = at_origin ? j : m - 1 - j;
          P.row(row) = (t * end + (1 - t) * pk).transpose();
        }
      }
    };
    reroute(true);
    reroute(false);
  }
  // Smooth, resample, and pull points the map left outside back inside the surface.
  const double inside_margin = 1e-5;
  const Mat3 R = X_mesh_box_.linear();
  const Vec3 o = X_mesh_box_.translation();
  // Points well inside the contours of both neighbouring slices skip the 3-D test.
  // (Between slices the surface departs from the linear blend by about spacing^2 * curvature / 8,
  // a few hundredths of the spacing for muscle shapes.)
  const double spacing = axial_length_ / std::max(K - 1, 1);
  const double clear_enough = 0.1 * spacing;
  for (Points3& P : out.fibres) {
    smooth(P, field_slicing_ ? options_.field_smoothing_iterations : options_.smoothing_iterations);
    P = resample_polyline(P, static_cast<int>(P.rows()));
    for (Eigen::Index k = 0; k < P.rows(); ++k) {
      const Vec3 p = P.row(k);
      const Vec3 p_box = R.transpose() * (p - o);
      const double kappa = p_box.z() / axial_length_ * (K - 1);
      if (field_slicing_) {
        const Eigen::Vector3i c = ((p - S.grid_lo) / S.cell).array().floor().cast<int>().matrix();
        if ((c.array() >= 0).all() && (c.array() < S.n.array()).all() &&
            S.grid_distance((static_cast<Eigen::Index>(c.x()) * S.n.y() + c.y()) * S.n.z() + c.z()) <
                -(0.8660254037844386 * S.cell + inside_margin))  // sqrt(3) / 2
          continue;
      } else if (kappa > 0.0 && kappa < K - 1) {
        const int k0 = std::min(static_cast<int>(kappa), K - 2);
        const Vec2 xy = p_box.head<2>();
        if (calc_clearance(S.contour_xy[k0], xy) > clear_enough &&
            calc_clearance(S.contour_xy[k0 + 1], xy) > clear_enough)
          continue;
      }
      // The search radius only bounds the work (a point farther from the surface is tested
      // for inside instead). Field slices have no 2-D shortcut, so every point comes here and
      // most are deep inside: a short radius (1 mm) settles them by the inside test.
      ClosestPoint c = query_->calc_closest_point(p, field_slicing_ ? std::min(2.0 * spacing, 1e-3)
                                                                    : 2.0 * spacing);
      if (c.triangle < 0) {
        // Far from the surface: deep inside, or far outside a strongly concave contour.
        if (query_->calc_is_inside(p)) continue;
        c = query_->calc_closest_point(p);
      }
      const auto t = muscle_.F.row(c.triangle);
      const Vec3 a = muscle_.V.row(t(0)), b = muscle_.V.row(t(1)), cc = muscle_.V.row(t(2));
      const Vec3 normal = (b - a).cross(cc - a).normalized();
      // Side by the face normal when the closest point is inside the face; otherwise (edge or
      // vertex, where the face normal may mislead) by the robust inside test.
      const bool interior_hit = c.barycentric.minCoeff() > 1e-9;
      const bool inside = interior_hit ? (p - c.point).dot(normal) < 0.0 : query_->calc_is_inside(p);
      if (inside && c.distance >= inside_margin) continue;
      P.row(k) = (c.point - inside_margin * normal).transpose();
    }
  }
  return out;
}

}  // namespace fascicle
