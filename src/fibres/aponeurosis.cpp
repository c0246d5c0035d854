// Aponeurosis attachment areas from the muscle's shape and architecture (docs/fibres.md).
//
// Rule (after the unipennate and bipennate templates of Blemker & Delp 2005, Ann Biomed Eng
// 33:661, and the aponeurosis boundary conditions of Choi & Blemker 2013, PLoS ONE 8:e77576):
// pennate fibres run between two aponeuroses that cover long strips of the muscle's surface (or a
// sheet inside it); a fibre crossing a thickness T_f at the pennation angle a advances
// d = T_f / tan(a) along the line of action, so the origin aponeurosis covers the proximal part
// [0, L - d] and the insertion aponeurosis the distal part [d, L].
#include "fascicle/core/error.hpp"
#include "fascicle/fibres/attachment.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <Eigen/Eigenvalues>
#include <fmt/format.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <utility>

namespace fascicle {

Architecture parse_architecture(std::string_view name) {
  std::string s(name);
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  if (s == "unipennate" || s == "pennate") return Architecture::unipennate;
  if (s == "bipennate") return Architecture::bipennate;
  throw_usage("unknown muscle architecture '" + s + "'",
              {.suggestion = "use unipennate or bipennate"});
}

std::string to_string(Architecture a) {
  return a == Architecture::bipennate ? "bipennate" : "unipennate";
}

namespace {

// Area-weighted vertex normals (unit; zero for isolated vertices).
Points3 calc_vertex_normals(const TriMesh& m) {
  Points3 N = Points3::Zero(m.num_vertices(), 3);
  for (Eigen::Index f = 0; f < m.num_faces(); ++f) {
    const Vec3 a = m.V.row(m.F(f, 0)), b = m.V.row(m.F(f, 1)), c = m.V.row(m.F(f, 2));
    const Vec3 n = (b - a).cross(c - a);  // twice the area times the unit normal
    for (int k = 0; k < 3; ++k) N.row(m.F(f, k)) += n.transpose();
  }
  for (Eigen::Index v = 0; v < N.rows(); ++v) {
    const double len = N.row(v).norm();
    if (len > 0.0) N.row(v) /= len;
  }
  return N;
}

// Box axes of the aponeurosis rule: z the principal axis (origin end towards o.origin_towards),
// x the thickness direction (given, or the least variance of the vertices across z).
std::pair<Vec3, Vec3> calc_box_axes(const TriMesh& muscle, const AponeurosisOptions& o) {
  const Vec3 ez = calc_principal_axis(muscle, o.origin_towards);
  Vec3 ex;
  if (o.thickness_direction.norm() > 0.0) {
    ex = o.thickness_direction - o.thickness_direction.dot(ez) * ez;
    if (!(ex.norm() > 1e-6 * o.thickness_direction.norm()))
      throw_usage("the thickness direction is parallel to the muscle's principal axis");
    ex.normalize();
  } else {
    const Vec3 mean = muscle.V.colwise().mean();
    Points3 D = muscle.V.rowwise() - mean.transpose();
    D -= (D * ez) * ez.transpose();
    const Eigen::SelfAdjointEigenSolver<Mat3> eig(D.transpose() * D);
    ex = eig.eigenvectors().col(1);  // col(0) is ~ez (zero variance after projection)
    ex = (ex - ex.dot(ez) * ez).normalized();
  }
  if (ex.dot(o.insertion_face_towards) < 0.0) ex = -ex;
  return {ez, ex};
}

// Per axial bin: the range of x (box thickness coordinate) and of y of the vertices.
struct BinRanges {
  std::vector<double> x_lo, x_hi, y_lo, y_hi;
  double bin_length = 0.0;
};

// The face test |n·x| ≥ cos(angle) selects the faces only for an angle in (0, 90°): at 90° or more
// every vertex passes, including those with a zero normal.
void require_face_angle(const AponeurosisOptions& o) {
  if (!(o.face_angle_rad > 0.0 && o.face_angle_rad < 0.5 * M_PI))
    throw_usage("the face angle must be in (0, 90) degrees",
                {.suggestion = "give the largest angle between a face's normal and the thickness direction"});
}

}  // namespace

Attachments find_aponeurosis_attachments(const TriMesh& muscle, const AponeurosisOptions& o) {
  if (!(o.pennation_rad > 0.0 && o.pennation_rad < 0.5 * M_PI))
    throw_usage("the pennation angle must be in (0, 90) degrees");
  if (!(o.end_fraction > 0.0 && o.end_fraction < 0.5))
    throw_usage("the end-region fraction must be in (0, 0.5)");
  if (!(o.sheet_spacing_m > 0.0)) throw_usage("the sheet spacing must be positive");
  require_face_angle(o);
  // Box: z principal axis, x thickness (least variance across z), y = z x x.
  const auto [ez, ex] = calc_box_axes(muscle, o);
  const Vec3 ey = ez.cross(ex);
  // Axial position s from the origin end (the +ez end) and the box coordinates.
  const VecX z = muscle.V * ez;
  const double z_hi = z.maxCoeff(), z_lo = z.minCoeff();
  const double L = z_hi - z_lo;
  if (!(L > 0.0)) throw_bad_input("the muscle mesh has no extent along its principal axis");
  const VecX s = (z_hi - z.array()).matrix();
  const VecX x = muscle.V * ex, y = muscle.V * ey;
  // Thickness per axial bin; T = mean over the bins of the middle 80 %.
  const int bins = 24;
  BinRanges r;
  r.bin_length = L / bins;
  r.x_lo.assign(bins, 1e300);
  r.x_hi.assign(bins, -1e300);
  r.y_lo.assign(bins, 1e300);
  r.y_hi.assign(bins, -1e300);
  const auto bin_of = [&](double sv) { return std::clamp(static_cast<int>(sv / r.bin_length), 0, bins - 1); };
  for (Eigen::Index v = 0; v < s.size(); ++v) {
    const int b = bin_of(s(v));
    r.x_lo[b] = std::min(r.x_lo[b], x(v));
    r.x_hi[b] = std::max(r.x_hi[b], x(v));
    r.y_lo[b] = std::min(r.y_lo[b], y(v));
    r.y_hi[b] = std::max(r.y_hi[b], y(v));
  }
  double T = 0.0;
  int used = 0;
  for (int b = bins / 10; b < bins - bins / 10; ++b)
    if (r.x_hi[b] > r.x_lo[b]) {
      T += r.x_hi[b] - r.x_lo[b];
      ++used;
    }
  if (used == 0) throw_bad_input("the muscle mesh has no thickness across its principal axis");
  T /= used;
  const bool bi = o.architecture == Architecture::bipennate;
  const double crossing = bi ? 0.5 * T : T;
  const double d = std::clamp(crossing / std::tan(o.pennation_rad), 0.2 * L, 0.8 * L);
  const Points3 N = calc_vertex_normals(muscle);
  const double c = std::cos(o.face_angle_rad);
  std::vector<int> origin, insertion, face_minus, face_plus;
  for (Eigen::Index v = 0; v < s.size(); ++v) {
    const double nx = N.row(v).dot(ex);
    const bool minus_face = nx <= -c, plus_face = nx >= c;
    const int vi = static_cast<int>(v);
    if (bi) {
      if ((minus_face || plus_face) && s(v) <= L - d) origin.push_back(vi);
      else if (s(v) >= (1.0 - o.end_fraction) * L) insertion.push_back(vi);
    } else {
      if (minus_face && s(v) <= L - d) origin.push_back(vi);
      if (plus_face && s(v) >= d) insertion.push_back(vi);
      if (minus_face) face_minus.push_back(vi);
      if (plus_face) face_plus.push_back(vi);
    }
  }
  if (origin.empty() || insertion.empty())
    throw_bad_input("no muscle surface faces the thickness direction where the aponeuroses "
                    "should be",
                    {.suggestion = "give the thickness direction, or a smaller pennation angle"});
  Attachments a{make_attachment_area(muscle, origin, "origin"),
                make_attachment_area(muscle, insertion, "insertion")};
  a.face_minus = std::move(face_minus);
  a.face_plus = std::move(face_plus);
  a.thickness_direction = ex;
  if (bi) {
    // Central sheet at mid-thickness over [d, L], sampled on a grid and kept inside the muscle.
    const MeshQuery query(muscle);
    std::vector<Vec3> pts;
    const double h = o.sheet_spacing_m;
    // Bound the grid (a mesh read in the wrong units would ask for billions of inside tests).
    double widest = 0.0;
    for (std::size_t b = 0; b < r.y_lo.size(); ++b) widest = std::max(widest, r.y_hi[b] - r.y_lo[b]);
    if ((L - d) / h * (widest / h) > 4e6)
      throw_bad_input(fmt::format("the central aponeurosis sheet would need more than 4 million samples "
                                  "({:.3g} m long, {:.3g} m wide, spacing {:.3g} m)",
                                  L - d, widest, h),
                      {.suggestion = "check the mesh units (--units mm for millimetre meshes) or raise "
                                     "the sheet spacing"});
    for (double sv = d; sv <= L; sv += h) {
      const int b = bin_of(sv);
      if (!(r.x_hi[b] > r.x_lo[b])) continue;
      const double xm = 0.5 * (r.x_lo[b] + r.x_hi[b]);
      for (double yv = r.y_lo[b]; yv <= r.y_hi[b]; yv += h) {
        const Vec3 p = xm * ex + yv * ey + (z_hi - sv) * ez;
        if (query.calc_is_inside(p)) pts.push_back(p);
      }
    }
    if (pts.empty()) throw_bad_input("the central aponeurosis sheet misses the muscle");
    a.insertion_interior.resize(static_cast<Eigen::Index>(pts.size()), 3);
    for (std::size_t i = 0; i < pts.size(); ++i) a.insertion_interior.row(i) = pts[i].transpose();
  }
  check_attachments(muscle, a);
  return a;
}

double calc_face_thickness(const TriMesh& muscle, const AponeurosisOptions& o) {
  require_face_angle(o);
  const auto [ez, ex] = calc_box_axes(muscle, o);
  const VecX z = muscle.V * ez;
  const double z_hi = z.maxCoeff(), L = z_hi - z.minCoeff();
  if (!(L > 0.0)) throw_bad_input("the muscle mesh has no extent along its principal axis");
  const Points3 N = calc_vertex_normals(muscle);
  const double c = std::cos(o.face_angle_rad);
  const MeshQuery query(muscle);
  std::vector<double> t;
  for (Eigen::Index v = 0; v < muscle.num_vertices(); ++v) {
    const double s = (z_hi - z(v)) / L;
    const Vec3 n = N.row(v);
    if (s < 0.1 || s > 0.9 || std::abs(n.dot(ex)) < c) continue;
    // Start a hair inside so the ray does not hit the vertex's own faces.
    const double eps = 1e-6 * L;
    if (const auto hit = query.cast_ray(Vec3(muscle.V.row(v)) - eps * n, -n, 0.0))
      t.push_back(hit->t + eps);
  }
  if (t.empty())
    throw_bad_input("no muscle surface faces the thickness direction",
                    {.suggestion = "give the thickness direction (e.g. an aponeurosis normal)"});
  std::nth_element(t.begin(), t.begin() + t.size() / 2, t.end());
  return t[t.size() / 2];
}

Vec3 calc_sheet_normal(const TriMesh& sheet) {
  if (sheet.num_vertices() < 3) throw_bad_input("the aponeurosis mesh has fewer than 3 vertices");
  const Points3 D = sheet.V.rowwise() - sheet.V.colwise().mean();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(D.transpose() * D);
  return eig.eigenvectors().col(0);
}

Points3 find_aponeurosis_border(const TriMesh& muscle, const Points3& sheet,
                                const Vec3& thickness_direction, const Vec3& origin_towards,
                                int bins) {
  if (sheet.rows() < 3) throw_bad_input("the aponeurosis has fewer than 3 points inside the muscle");
  if (bins < 2) throw_usage("the aponeurosis border needs at least 2 bins along the muscle");
  if (!(thickness_direction.norm() > 0.0))
    throw_usage("no thickness direction: the attachment areas are not aponeurosis areas",
                {.suggestion = "find the areas with find_aponeurosis_attachments (--attachments aponeurosis)"});
  const Vec3 ez = calc_principal_axis(muscle, origin_towards);
  Vec3 ex = thickness_direction - thickness_direction.dot(ez) * ez;
  if (!(ex.norm() > 1e-6)) throw_usage("the sheet's normal is parallel to the muscle's principal axis");
  ex.normalize();
  const Vec3 ey = ez.cross(ex);
  // s: distance from the sheet's origin-side end along the axis (the origin end is at +z).
  const VecX z = sheet * ez, y = sheet * ey;
  const double z_hi = z.maxCoeff(), extent = z_hi - z.minCoeff();
  if (!(extent > 0.0)) throw_bad_input("the aponeurosis has no extent along the muscle's axis");
  const auto bin_of = [&](double zv) {
    return std::clamp(static_cast<int>((z_hi - zv) / extent * bins), 0, bins - 1);
  };
  // The side: the distal third's mean y against the whole sheet's; the width per bin for scale.
  double y_all = 0.0, y_distal = 0.0;
  int n_distal = 0;
  std::vector<double> y_lo(bins, 1e300), y_hi(bins, -1e300);
  for (Eigen::Index i = 0; i < sheet.rows(); ++i) {
    y_all += y(i);
    if (z_hi - z(i) >= 2.0 / 3.0 * extent) {
      y_distal += y(i);
      ++n_distal;
    }
    const int b = bin_of(z(i));
    y_lo[b] = std::min(y_lo[b], y(i));
    y_hi[b] = std::max(y_hi[b], y(i));
  }
  y_all /= static_cast<double>(sheet.rows());
  double width = 0.0;
  int used = 0;
  for (int b = 0; b < bins; ++b)
    if (y_hi[b] >= y_lo[b]) {
      width += y_hi[b] - y_lo[b];
      ++used;
    }
  width /= used;
  const double shift = n_distal > 0 ? y_distal / n_distal - y_all : 0.0;
  if (!(std::abs(shift) >= 0.02 * width))
    throw_bad_input(fmt::format("the aponeurosis' distal third does not lean to either side (shift "
                                "{:.3g} m for a mean width of {:.3g} m): no tendon side to turn to",
                                shift, width),
                    {.suggestion = "use the thickness plane (--pennation-plane thickness)"});
  const double side = shift > 0.0 ? 1.0 : -1.0;
  std::vector<int> best(bins, -1);
  for (Eigen::Index i = 0; i < sheet.rows(); ++i) {
    const int b = bin_of(z(i));
    if (best[b] < 0 || side * y(i) > side * y(best[b])) best[b] = static_cast<int>(i);
  }
  std::vector<int> rows;
  for (int b : best)
    if (b >= 0) rows.push_back(b);
  Points3 border(static_cast<Eigen::Index>(rows.size()), 3);
  for (std::size_t i = 0; i < rows.size(); ++i)
    border.row(static_cast<Eigen::Index>(i)) = sheet.row(rows[i]);
  return border;
}

void set_interior_aponeurosis(const TriMesh& muscle, const TriMesh& aponeurosis,
                              Attachments& areas) {
  const MeshQuery query(muscle);
  std::vector<Vec3> pts;
  const auto keep = [&](const Vec3& p) {
    if (query.calc_is_inside(p)) pts.push_back(p);
  };
  for (Eigen::Index v = 0; v < aponeurosis.num_vertices(); ++v) keep(aponeurosis.V.row(v));
  for (Eigen::Index f = 0; f < aponeurosis.num_faces(); ++f)
    keep((aponeurosis.V.row(aponeurosis.F(f, 0)) + aponeurosis.V.row(aponeurosis.F(f, 1)) +
          aponeurosis.V.row(aponeurosis.F(f, 2))) / 3.0);
  if (pts.empty())
    throw_bad_input("no point of the aponeurosis mesh lies inside the muscle",
                    {.suggestion = "check the aponeurosis belongs to this muscle and uses the "
                                   "same units and frame"});
  areas.insertion_interior.resize(static_cast<Eigen::Index>(pts.size()), 3);
  for (std::size_t i = 0; i < pts.size(); ++i) areas.insertion_interior.row(i) = pts[i].transpose();
}

}  // namespace fascicle
