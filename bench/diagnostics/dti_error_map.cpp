// DTI error map of the pennate harmonic field (issue 6; docs/fibres.md, "DTI error map"): for the
// Bolsterlee MG and TA with the thickness-derived angle, every tract segment's angle to the
// nearest fibre, split by axial tenth (proximal first), depth under the surface and aponeurosis
// potential u, and decomposed in the field's local frame: e_l = grad(u_along) (end to end),
// e_t = the part of grad(u) normal to e_l, e_b = e_l x e_t. A direction is (beta, phi): beta its
// angle to e_l, phi the azimuth of its normal part about e_l from e_t. Two counterfactual errors
// separate the causes: the fibre with the tract's beta (its plane kept), and with the tract's phi
// (its beta kept). Also the mean normal part of the tracts per tenth in the box frame (x the
// thickness direction). Not a benchmark: `build/bin/diag_dti_error_map` prints tables for the
// gradient and the thickness plane (HarmonicOptions::transverse_direction), and for the TA the
// fibres turning towards its aponeurosis' tendon-side border (HarmonicOptions::transverse_targets).
#include "fascicle/fibres/analysis.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/fibres/harmonic.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "../../src/fibres/point_index.hpp"
#include "tet_fields.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

using namespace fascicle;
using namespace fascicle::diagnostics;

namespace {

const std::filesystem::path data = FASCICLE_DEFAULT_DATA_DIR;
constexpr double deg = 180.0 / M_PI;

// Mean angles of one group of tract segments (radians summed, printed in degrees).
struct Bin {
  int n = 0;
  double err = 0, tract_beta = 0, fibre_beta = 0, abs_dphi = 0, err_tract_beta = 0,
         err_tract_phi = 0;
  void print(const std::string& label) const {
    if (n == 0) return;
    const double k = deg / n;
    fmt::print("  {:<12} n={:5d} error {:5.1f} | beta: tract {:5.1f} fibre {:5.1f} | "
               "|dphi| {:5.1f} | error with the tract's beta {:5.1f}, with the tract's phi {:5.1f}\n",
               label, n, err * k, tract_beta * k, fibre_beta * k, abs_dphi * k, err_tract_beta * k,
               err_tract_phi * k);
  }
};

struct Case {
  const char* name;
  const char* mesh;
  Architecture architecture;
  double ward_m;
  const char* tracts;
  const char* aponeurosis = nullptr;  // interior insertion aponeurosis
  const char* deep_side = nullptr;    // unipennate: a mesh on the insertion face's side
};

// The thickness-derived angle set-up of BM_DtiThicknessPennation (bench/fibres.cpp).
struct Setup {
  TriMesh muscle;
  Attachments areas;
  double alpha = 0.0;
};

Setup make_setup(const Case& c) {
  Setup s;
  s.muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  AponeurosisOptions ao;
  ao.architecture = c.architecture;
  if (c.deep_side) {
    const TriMesh other = read_mesh(data / c.deep_side, LengthUnit::millimetre);
    ao.insertion_face_towards = Vec3(other.V.colwise().mean()) - Vec3(s.muscle.V.colwise().mean());
  }
  TriMesh apo;
  if (c.aponeurosis) {
    apo = read_mesh(data / c.aponeurosis, LengthUnit::millimetre);
    ao.thickness_direction = calc_sheet_normal(apo);
  }
  const double t = calc_face_thickness(s.muscle, ao);
  const double crossing = c.architecture == Architecture::bipennate ? 0.5 * t : t;
  s.alpha = std::asin(std::min(1.0, crossing / c.ward_m));
  ao.pennation_rad = s.alpha;
  s.areas = find_aponeurosis_attachments(s.muscle, ao);
  if (c.aponeurosis) set_interior_aponeurosis(s.muscle, apo, s.areas);
  return s;
}

// The plane the fibres turn in: grad(u), the box's thickness direction, or (interior aponeurosis
// only) towards the sheet's tendon-side border (session 10).
enum class Plane { gradient, thickness, sheet_border };

void print_error_map(const Case& c, const Setup& s, Plane plane) {
  const bool thickness_plane = plane == Plane::thickness;
  DecomposeOptions opt;
  opt.method = FibreMethod::harmonic;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = s.alpha;
  opt.harmonic.pennation_rad = s.alpha;
  if (thickness_plane) opt.harmonic.transverse_direction = s.areas.thickness_direction;
  if (plane == Plane::sheet_border)
    opt.harmonic.transverse_targets = find_aponeurosis_border(
        s.muscle, s.areas.insertion_interior, s.areas.thickness_direction);
  const Decomposition d = decompose_muscle(s.muscle, s.areas, opt);
  const FibreSet tracts = read_tracts(data / c.tracts, 1e-3);
  fmt::print("\n== {} pennate field, {} plane, alpha {:.1f} deg: mean {:.2f} deg\n", c.name,
             thickness_plane ? "thickness" : plane == Plane::sheet_border ? "sheet-border" : "gradient",
             s.alpha * deg,
             compare_directions(d.fibres, tracts).mean_rad * deg);
  // The frame fields on the same tets: u (plain) and u_along (from the pennate field).
  const HarmonicField field = calc_harmonic_field(s.muscle, s.areas, opt.harmonic);
  const HarmonicField plain = calc_harmonic_field(s.muscle, s.areas, {});
  const Points3 grad_u = calc_tet_gradients(plain.tets, plain.u);
  const Points3 grad_along = calc_tet_gradients(field.tets, field.u_along);
  const detail::PointIndex tets(calc_tet_centroids(field.tets));
  // Fibre pieces of <= 0.5 mm with their directions (as compare_directions).
  std::vector<Vec3> piece_dir;
  std::vector<Vec3> piece_mid;
  for (const Points3& P : d.fibres.fibres)
    for (Eigen::Index k = 1; k < P.rows(); ++k) {
      const Vec3 a = P.row(k - 1), b = P.row(k);
      const int n = std::max(1, static_cast<int>(std::ceil((b - a).norm() / 5e-4)));
      for (int j = 0; j < n; ++j) {
        piece_mid.push_back(a + (b - a) * ((j + 0.5) / n));
        piece_dir.push_back((b - a).normalized());
      }
    }
  Points3 mids(static_cast<Eigen::Index>(piece_mid.size()), 3);
  for (std::size_t i = 0; i < piece_mid.size(); ++i) mids.row(i) = piece_mid[i].transpose();
  const detail::PointIndex pieces(std::move(mids));
  const MeshQuery query(s.muscle);
  const Vec3 ez = calc_principal_axis(s.muscle);
  const VecX z = s.muscle.V * ez;
  const double z_hi = z.maxCoeff(), extent = z_hi - z.minCoeff();
  const Vec3 ex = s.areas.thickness_direction, ey = ez.cross(ex).normalized();

  std::array<Bin, 10> axial;
  std::array<Bin, 4> depth;
  std::array<Bin, 5> potential;
  Bin all;
  // Mean normal part of the tracts per tenth, split by the side of the insertion (sign of x of
  // grad u): box components x, y.
  std::array<std::array<Vec3, 2>, 10> side_sum;
  for (auto& tenth : side_sum) tenth.fill(Vec3::Zero());
  std::array<std::array<int, 2>, 10> side_n{};
  for (const Points3& T : tracts.fibres)
    for (Eigen::Index k = 1; k < T.rows(); ++k) {
      const Vec3 p = 0.5 * (T.row(k) + T.row(k - 1)).transpose();
      if (!((T.row(k) - T.row(k - 1)).norm() > 0.0)) continue;  // a repeated tract point
      Vec3 tv = (T.row(k) - T.row(k - 1)).transpose().normalized();
      Vec3 fv = piece_dir[pieces.find_nearest(p).first];
      const int ti = tets.find_nearest(p).first;  // the tet of the nearest centroid
      const Vec3 el = Vec3(grad_along.row(ti)).normalized();
      const Vec3 gu = grad_u.row(ti);
      if (!((gu - gu.dot(el) * el).norm() > 0.0) || !(grad_along.row(ti).norm() > 0.0)) continue;  // no frame
      const Vec3 et = (gu - gu.dot(el) * el).normalized(), eb = el.cross(et);
      if (tv.dot(el) < 0) tv = -tv;
      if (fv.dot(el) < 0) fv = -fv;
      const double bt = std::acos(std::min(1.0, tv.dot(el)));
      const double bf = std::acos(std::min(1.0, fv.dot(el)));
      const double pt = std::atan2(tv.dot(eb), tv.dot(et)), pf = std::atan2(fv.dot(eb), fv.dot(et));
      const double dphi = std::remainder(pt - pf, 2 * M_PI);
      const auto direction = [&](double beta, double phi) {
        return Vec3(std::cos(beta) * el +
                    std::sin(beta) * (std::cos(phi) * et + std::sin(phi) * eb));
      };
      const double e = calc_line_angle(tv, fv);
      const double e_beta = calc_line_angle(tv, direction(bt, pf));
      const double e_phi = calc_line_angle(tv, direction(bf, pt));
      double u = 0;
      for (int j = 0; j < 4; ++j) u += 0.25 * plain.u(plain.tets.T(ti, j));
      const int tenth = std::clamp(static_cast<int>((z_hi - p.dot(ez)) / extent * 10), 0, 9);
      const double dp = -query.calc_signed_distances(p.transpose())(0);
      const int di = dp < 2e-3 ? 0 : dp < 4e-3 ? 1 : dp < 7e-3 ? 2 : 3;
      const int ui = std::clamp(static_cast<int>(u * 5), 0, 4);
      for (Bin* b : {&axial[tenth], &depth[di], &potential[ui], &all}) {
        ++b->n;
        b->err += e;
        b->tract_beta += bt;
        b->fibre_beta += bf;
        b->abs_dphi += std::abs(dphi);
        b->err_tract_beta += e_beta;
        b->err_tract_phi += e_phi;
      }
      const int side = gu.dot(ex) > 0 ? 0 : 1;
      side_sum[tenth][side] += tv - tv.dot(el) * el;
      ++side_n[tenth][side];
    }
  all.print("all");
  for (int b = 0; b < 10; ++b) axial[b].print(fmt::format("tenth {}", b + 1));
  const char* depth_label[] = {"depth < 2mm", "depth 2-4mm", "depth 4-7mm", "depth > 7mm"};
  for (int b = 0; b < 4; ++b) depth[b].print(depth_label[b]);
  for (int b = 0; b < 5; ++b)
    potential[b].print(fmt::format("u {:.1f}-{:.1f}", 0.2 * b, 0.2 * b + 0.2));
  fmt::print("  tracts' mean normal part (sin of the angle to e_l) per tenth, box x / y:\n");
  for (int b = 0; b < 10; ++b)
    for (int side = 0; side < 2; ++side)
      if (side_n[b][side] > 0) {
        const Vec3 m = side_sum[b][side] / side_n[b][side];
        fmt::print("  tenth {:2d}, grad u towards {}x: n={:5d} |m|={:.3f} x={:+.3f} y={:+.3f}\n",
                   b + 1, side == 0 ? "+" : "-", side_n[b][side], m.norm(), m.dot(ex), m.dot(ey));
      }
}

}  // namespace

int main() {
  const Case cases[] = {
      {"MG", "bolsterlee_dti/MG.stl", Architecture::unipennate, 0.0510,
       "bolsterlee_dti/tracts_MG.txt", nullptr, "bolsterlee_dti/TA.stl"},
      {"TA", "bolsterlee_dti/TA.stl", Architecture::bipennate, 0.0683,
       "bolsterlee_dti/tracts_TA.txt", "bolsterlee_dti/TA_apo.stl"},
  };
  for (const Case& c : cases) {
    const Setup s = make_setup(c);
    for (const Plane plane : {Plane::gradient, Plane::thickness, Plane::sheet_border})
      if (plane != Plane::sheet_border || c.aponeurosis) print_error_map(c, s, plane);
  }
}
