// Sheet-based direction fields for the DTI comparison (issue 6; docs/fibres.md, "Session 10").
// For the Bolsterlee MG and TA with the thickness-derived angle alpha = asin(t_f / L_Ward) (as
// diag_dti_error_map), candidate fibre directions are evaluated AT the tract segments' midpoints
// (no tracing) and compared with the segments; per axial tenth (proximal first) and overall. Each
// candidate is d = cos(b) e_a + sin(b) n with e_l = grad(u_along) (end to end) and:
//   C0 thickness plane (the default since session 9): e_a = e_l, n = the box's thickness direction
//      x (towards the insertion face; TA: towards TA_apo), b = alpha;
//   C1 towards the sheet: n = the direction to the nearest point of the insertion sheet (MG: the
//      deep +x face's vertices; TA: TA_apo inside the muscle), b = alpha;
//   C2 crossing level sets: n = grad(u_c), e_a = e_l within its level set, b = alpha; u_c = 0 / 1 on
//      the -x / +x faces (MG), the plain potential u (TA: 0 on the faces, 1 on the sheet);
//   C3 sheets' normals: n = (1 - u_c) n_origin + u_c n_insertion (inward normal of the nearest
//      origin-face point, smoothed over 5 mm, and the insertion sheet's normal x), e_a as C2;
//   C4 origin-face convergence: e_a = e_l, n = x, b = alpha + g, g the angle by which the origin
//      face (smoothed outward normal over 5 mm, nearest face point on the fibre's side) converges
//      on the insertion side along e_l (the taper: fibres keep their angle to the face they arise
//      from).
//   C5 sheet border (TA only; session 10's option): n = the direction to the nearest point of
//      find_aponeurosis_border (the sheet's edge on its tendon side), b = alpha; printed with the
//      field's own sideways component next to the tracts'.
// Also per tenth: the tracts' mean unit-direction components along x_n (x made normal to e_l,
// signed towards the insertion) and along the box's y made normal to e_l (sideways; for the TA, +y
// points away from the MG), and C0 with alpha scaled by 0.7, 1.3, 1.45 (overall). The traced
// default field's figure is printed for calibration: evaluated at the tracts, a field scores
// 0.2-1.2 deg worse than its traced fibres (tract points the fibres do not reach are matched to
// farther fibres). Not a benchmark: `build/bin/diag_dti_sheet_fields`.
#include "fascicle/fibres/analysis.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "../../src/fibres/point_index.hpp"
#include "tet_fields.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <memory>
#include <vector>

using namespace fascicle;
using namespace fascicle::diagnostics;

namespace {

const std::filesystem::path data = FASCICLE_DEFAULT_DATA_DIR;
constexpr double deg = 180.0 / M_PI;
constexpr int candidates = 6;
const char* const candidate_names[candidates] = {"C0 thickness plane", "C1 towards the sheet",
                                                 "C2 crossing level sets", "C3 sheets' normals",
                                                 "C4 origin-face convergence",
                                                 "C5 sheet border"};

// Surface faces (centroids, area-weighted normals) for smoothed normals.
struct Faces {
  Points3 centroid, normal;
};

Faces calc_faces(const TriMesh& m) {
  Faces f{Points3(m.num_faces(), 3), Points3(m.num_faces(), 3)};
  for (Eigen::Index i = 0; i < m.num_faces(); ++i) {
    const Vec3 a = m.V.row(m.F(i, 0)), b = m.V.row(m.F(i, 1)), c = m.V.row(m.F(i, 2));
    f.normal.row(i) = (b - a).cross(c - a).transpose();
    f.centroid.row(i) = ((a + b + c) / 3.0).transpose();
  }
  return f;
}

Points3 select_rows(const Points3& P, const std::vector<int>& rows) {
  Points3 out(static_cast<Eigen::Index>(rows.size()), 3);
  for (std::size_t i = 0; i < rows.size(); ++i) out.row(static_cast<Eigen::Index>(i)) = P.row(rows[i]);
  return out;
}

void run(bool mg) {
  const TriMesh muscle = read_mesh(data / (mg ? "bolsterlee_dti/MG.stl" : "bolsterlee_dti/TA.stl"),
                                   LengthUnit::millimetre);
  AponeurosisOptions ao;
  ao.architecture = mg ? Architecture::unipennate : Architecture::bipennate;
  TriMesh apo;
  if (mg) {
    const TriMesh ta = read_mesh(data / "bolsterlee_dti/TA.stl", LengthUnit::millimetre);
    ao.insertion_face_towards = Vec3(ta.V.colwise().mean()) - Vec3(muscle.V.colwise().mean());
  } else {
    apo = read_mesh(data / "bolsterlee_dti/TA_apo.stl", LengthUnit::millimetre);
    ao.thickness_direction = calc_sheet_normal(apo);
  }
  const double t = calc_face_thickness(muscle, ao);
  const double alpha = std::asin((mg ? t : 0.5 * t) / (mg ? 0.0510 : 0.0683));
  ao.pennation_rad = alpha;
  Attachments areas = find_aponeurosis_attachments(muscle, ao);
  if (!mg) set_interior_aponeurosis(muscle, apo, areas);
  const FibreSet tracts = read_tracts(
      data / (mg ? "bolsterlee_dti/tracts_MG.txt" : "bolsterlee_dti/tracts_TA.txt"), 1e-3);

  // The traced default (thickness plane), for calibration.
  DecomposeOptions opt;
  opt.method = FibreMethod::harmonic;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = alpha;
  opt.harmonic.pennation_rad = alpha;
  opt.harmonic.transverse_direction = areas.thickness_direction;
  const Decomposition traced = decompose_muscle(muscle, areas, opt);
  fmt::print("\n== {}: alpha {:.1f} deg; traced default fibres (thickness plane): mean {:.2f} deg\n",
             mg ? "MG" : "TA", alpha * deg, compare_directions(traced.fibres, tracts).mean_rad * deg);

  const HarmonicField field = calc_harmonic_field(muscle, areas, opt.harmonic);
  const Points3 grad_along = calc_tet_gradients(field.tets, field.u_along);
  const VecX u_c = mg ? solve_laplace(field.tets, areas.face_minus, areas.face_plus) : field.u;
  const Points3 grad_c = calc_tet_gradients(field.tets, u_c);
  const detail::PointIndex tets(calc_tet_centroids(field.tets));
  const Vec3 ez = calc_principal_axis(muscle);
  const VecX z = muscle.V * ez;
  const double z_hi = z.maxCoeff(), extent = z_hi - z.minCoeff();
  const Vec3 ex = areas.thickness_direction;
  const Vec3 ey = ez.cross(ex).normalized();  // the box's y (ez towards the origin end)
  // Insertion sheet points: the MG's deep face vertices, the TA's interior aponeurosis.
  const Points3 sheet = mg ? select_rows(muscle.V, areas.face_plus) : areas.insertion_interior;
  const detail::PointIndex sheet_index(sheet);
  // Box faces (normals within 60 deg of -x / +x) and smoothed outward normals over 5 mm.
  const Faces faces = calc_faces(muscle);
  const detail::PointIndex face_index(faces.centroid);
  std::vector<int> minus_rows, plus_rows;
  for (Eigen::Index i = 0; i < faces.normal.rows(); ++i) {
    const double nx = Vec3(faces.normal.row(i)).normalized().dot(ex);
    if (nx < -0.5) minus_rows.push_back(static_cast<int>(i));
    else if (nx > 0.5) plus_rows.push_back(static_cast<int>(i));
  }
  const Points3 minus_pts = select_rows(faces.centroid, minus_rows);
  const Points3 plus_pts = select_rows(faces.centroid, plus_rows);
  const detail::PointIndex minus_index(minus_pts), plus_index(plus_pts);
  const auto smooth_normal = [&](const Vec3& q) {
    Vec3 n = Vec3::Zero();
    for (int i : face_index.find_within(q, 5e-3)) n += faces.normal.row(i).transpose();
    return Vec3(n.normalized());
  };

  // Columns: the candidates, the face convergence g, the tract's components along x_n and sideways,
  // C0 with alpha x 0.7, 1.3, 1.45.
  constexpr int columns = candidates + 7;
  // C5: the TA's sheet border (the MG has no interior aponeurosis: column left at C0's value).
  const Points3 border =
      mg ? Points3(0, 3) : find_aponeurosis_border(muscle, areas.insertion_interior, ex);
  const auto border_index = mg ? nullptr : std::make_unique<detail::PointIndex>(border);
  const double scales[3] = {0.7, 1.3, 1.45};
  std::array<std::array<double, columns>, 11> sum{};
  std::array<int, 11> n{};
  for (const Points3& T : tracts.fibres)
    for (Eigen::Index k = 1; k < T.rows(); ++k) {
      if (!((T.row(k) - T.row(k - 1)).norm() > 0.0)) continue;  // a repeated tract point
      const Vec3 p = 0.5 * (T.row(k) + T.row(k - 1)).transpose();
      const Vec3 tv = (T.row(k) - T.row(k - 1)).transpose();
      const int ti = tets.find_nearest(p).first;
      if (!(grad_along.row(ti).norm() > 0.0)) continue;
      const Vec3 el = Vec3(grad_along.row(ti)).normalized();
      const Vec3 q = sheet.row(sheet_index.find_nearest(p).first);
      // x towards the insertion: +x (MG), towards the sheet (TA).
      const Vec3 xs = mg || (q - p).dot(ex) > 0.0 ? ex : Vec3(-ex);
      const auto with_e_l = [&](const Vec3& across, double b) {
        Vec3 m = across - across.dot(el) * el;
        if (!(m.norm() > 0.0)) return el;
        return Vec3(std::cos(b) * el + std::sin(b) * m.normalized());
      };
      const auto with_level_set = [&](Vec3 nn) {
        if (nn.dot(xs) < 0.0) nn = -nn;
        nn.normalize();
        const Vec3 a = (el - el.dot(nn) * nn).normalized();
        return Vec3(std::cos(alpha) * a + std::sin(alpha) * nn);
      };
      double uc = 0.0;
      for (int j = 0; j < 4; ++j) uc += 0.25 * u_c(field.tets.T(ti, j));
      // The origin face on this side: -x for the MG and for TA points on the -x side of the sheet.
      const bool minus = mg || xs.dot(ex) > 0.0;
      const Vec3 c = minus ? Vec3(minus_pts.row(minus_index.find_nearest(p).first))
                           : Vec3(plus_pts.row(plus_index.find_nearest(p).first));
      const Vec3 no = smooth_normal(c);  // outward
      Vec3 blended = (1.0 - uc) * Vec3(-no) + uc * xs;
      if (blended.dot(xs) < 0.0) blended = xs;
      const Vec3 xp = (xs - xs.dot(el) * el).normalized();
      const double g = std::atan2(no.dot(el), -no.dot(xp));
      const double b4 = std::clamp(alpha + g, 0.0, 0.5 * M_PI);
      Vec3 tu = tv.normalized();
      if (tu.dot(el) < 0.0) tu = -tu;
      const Vec3 sideways = (ey - ey.dot(el) * el).normalized();
      const Vec3 d5 = mg ? with_e_l(xs, alpha)
                         : with_e_l(Vec3(border.row(border_index->find_nearest(p).first)) - p, alpha);
      const std::array<double, columns> e = {
          calc_line_angle(tv, with_e_l(xs, alpha)),
          calc_line_angle(tv, with_e_l(q - p, alpha)),
          calc_line_angle(tv, with_level_set(grad_c.row(ti))),
          calc_line_angle(tv, with_level_set(blended)),
          calc_line_angle(tv, with_e_l(xs, b4)),
          calc_line_angle(tv, d5),
          g,
          tu.dot(xp),
          tu.dot(sideways),
          calc_line_angle(tv, with_e_l(xs, scales[0] * alpha)),
          calc_line_angle(tv, with_e_l(xs, scales[1] * alpha)),
          calc_line_angle(tv, with_e_l(xs, scales[2] * alpha)),
          d5.dot(sideways)};
      const int tenth = std::clamp(static_cast<int>((z_hi - p.dot(ez)) / extent * 10), 0, 9);
      for (int b : {tenth, 10}) {
        for (int j = 0; j < columns; ++j) sum[b][j] += e[j];
        ++n[b];
      }
    }
  fmt::print("  {:<9} {:>6}", "", "n");
  for (const char* name : candidate_names) fmt::print(" | {:>26}", name);
  fmt::print(" | face convergence g | tract along x_n, sideways | C0 alpha x 0.7 / 1.3 / 1.45 | "
             "C5 sideways\n");
  for (int b = 0; b < 11; ++b) {
    if (n[b] == 0) continue;
    const auto mean = [&](int j) { return sum[b][j] / n[b]; };
    fmt::print("  {:<9} {:6d}", b == 10 ? "all" : fmt::format("tenth {}", b + 1), n[b]);
    for (int j = 0; j < candidates; ++j) fmt::print(" | {:26.1f}", mean(j) * deg);
    fmt::print(" | {:+18.1f} | {:+14.3f} {:+9.3f} | {:5.1f} / {:4.1f} / {:4.1f} | {:+11.3f}\n",
               mean(candidates) * deg, mean(candidates + 1), mean(candidates + 2),
               mean(candidates + 3) * deg, mean(candidates + 4) * deg, mean(candidates + 5) * deg,
               mean(candidates + 6));
  }
  fmt::print("  sin(alpha) = {:.3f}\n", std::sin(alpha));
}

}  // namespace

int main() {
  run(true);
  run(false);
}
