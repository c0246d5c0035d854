// Lattice designs (seed 000 §3.0.1) and their control-point equality constraints.
#include "fascicle/bspline/lattice.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <cmath>
#include <numbers>

namespace fascicle {

namespace {

void require_positive(double value, const char* what) {
  if (!(value > 0) || !std::isfinite(value)) {
    throw_bad_input(fmt::format("{} must be positive and finite, got {}", what, value));
  }
}

// Cylinder-like layouts: basis u clamped (radial), v periodic, w clamped or periodic.
std::array<BSplineBasis, 3> make_radial_bases(const std::array<int, 3>& degree,
                                              const std::array<int, 3>& count, bool w_periodic) {
  return {make_clamped_uniform_basis(degree[0], count[0]),
          make_periodic_uniform_basis(degree[1], count[1]),
          w_periodic ? make_periodic_uniform_basis(degree[2], count[2])
                     : make_clamped_uniform_basis(degree[2], count[2])};
}

// Ties every ring (i = 0, all j) to its j = 0 point.
void constrain_axis(const BSplineSolid& s, LatticeConstraints& c) {
  for (int k = 0; k < s.num_control(2); ++k)
    for (int j = 0; j < s.num_control(1); ++j) c.representative[s.index(0, j, k)] = s.index(0, 0, k);
}

}  // namespace

LatticeConstraints make_free_constraints(int n) {
  LatticeConstraints c;
  c.representative.resize(n);
  for (int i = 0; i < n; ++i) c.representative[i] = i;
  return c;
}

LatticeDesign make_cubical_lattice(const Vec3& lower, const Vec3& upper,
                                   const std::array<int, 3>& degree,
                                   const std::array<int, 3>& count) {
  std::array<BSplineBasis, 3> b;
  for (int d = 0; d < 3; ++d) b[d] = make_clamped_uniform_basis(degree[d], count[d]);
  std::array<std::vector<double>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = calc_greville_abscissae(b[d]);
  Points3 P(count[0] * count[1] * count[2], 3);
  for (int k = 0; k < count[2]; ++k)
    for (int j = 0; j < count[1]; ++j)
      for (int i = 0; i < count[0]; ++i) {
        const Vec3 t(g[0][i], g[1][j], g[2][k]);
        P.row(i + count[0] * (j + count[1] * k)) =
            (lower + (upper - lower).cwiseProduct(t)).transpose();
      }
  LatticeDesign out{make_solid(std::move(b), std::move(P)), {}};
  out.constraints = make_free_constraints(out.solid.num_control_points());
  return out;
}

LatticeDesign make_cylindrical_lattice(double radius, double length,
                                       const std::array<int, 3>& degree,
                                       const std::array<int, 3>& count) {
  require_positive(radius, "cylinder radius");
  require_positive(length, "cylinder length");
  auto b = make_radial_bases(degree, count, false);
  const auto gu = calc_greville_abscissae(b[0]);
  const auto gw = calc_greville_abscissae(b[2]);
  Points3 P(count[0] * count[1] * count[2], 3);
  for (int k = 0; k < count[2]; ++k)
    for (int j = 0; j < count[1]; ++j)
      for (int i = 0; i < count[0]; ++i) {
        const double th = 2 * std::numbers::pi * j / count[1];
        const double r = radius * gu[i];
        P.row(i + count[0] * (j + count[1] * k)) << r * std::cos(th), r * std::sin(th),
            length * gw[k];
      }
  LatticeDesign out{make_solid(std::move(b), std::move(P)), {}};
  out.constraints = make_free_constraints(out.solid.num_control_points());
  constrain_axis(out.solid, out.constraints);
  return out;
}

LatticeDesign make_spherical_lattice(double radius, const std::array<int, 3>& degree,
                                     const std::array<int, 3>& count) {
  require_positive(radius, "sphere radius");
  auto b = make_radial_bases(degree, count, false);
  const auto gu = calc_greville_abscissae(b[0]);
  const auto gw = calc_greville_abscissae(b[2]);
  Points3 P(count[0] * count[1] * count[2], 3);
  for (int k = 0; k < count[2]; ++k)
    for (int j = 0; j < count[1]; ++j)
      for (int i = 0; i < count[0]; ++i) {
        const double th = 2 * std::numbers::pi * j / count[1];
        const double ph = std::numbers::pi * gw[k];
        const double r = radius * gu[i];
        P.row(i + count[0] * (j + count[1] * k)) << r * std::sin(ph) * std::cos(th),
            r * std::sin(ph) * std::sin(th), -r * std::cos(ph);
      }
  LatticeDesign out{make_solid(std::move(b), std::move(P)), {}};
  const BSplineSolid& s = out.solid;
  out.constraints = make_free_constraints(s.num_control_points());
  for (int k : {0, count[2] - 1})
    for (int j = 0; j < count[1]; ++j)
      for (int i = 0; i < count[0]; ++i) out.constraints.representative[s.index(i, j, k)] = s.index(i, 0, k);
  // the centre: every point with i = 0 (including the pole layers) is one point
  for (int k = 0; k < count[2]; ++k)
    for (int j = 0; j < count[1]; ++j) out.constraints.representative[s.index(0, j, k)] = 0;
  // make the coincident points bitwise equal (sin(pi) is not 0 in floating point)
  for (int I = 0; I < s.num_control_points(); ++I)
    out.solid.P.row(I) = out.solid.P.row(out.constraints.representative[I]);
  return out;
}

LatticeDesign make_toroidal_lattice(double major_radius, double minor_radius,
                                    const std::array<int, 3>& degree,
                                    const std::array<int, 3>& count) {
  require_positive(major_radius, "torus major radius");
  require_positive(minor_radius, "torus minor radius");
  if (minor_radius >= major_radius) {
    throw_bad_input("torus minor radius must be smaller than the major radius");
  }
  auto b = make_radial_bases(degree, count, true);
  const auto gu = calc_greville_abscissae(b[0]);
  Points3 P(count[0] * count[1] * count[2], 3);
  for (int k = 0; k < count[2]; ++k)
    for (int j = 0; j < count[1]; ++j)
      for (int i = 0; i < count[0]; ++i) {
        const double th = 2 * std::numbers::pi * j / count[1];  // around the tube
        const double ph = -2 * std::numbers::pi * k / count[2];  // around z (right-handed u,v,w)
        const double r = minor_radius * gu[i];
        const double rho = major_radius + r * std::cos(th);
        P.row(i + count[0] * (j + count[1] * k)) << rho * std::cos(ph), rho * std::sin(ph),
            r * std::sin(th);
      }
  LatticeDesign out{make_solid(std::move(b), std::move(P)), {}};
  out.constraints = make_free_constraints(out.solid.num_control_points());
  constrain_axis(out.solid, out.constraints);
  return out;
}

Points3 enforce_lattice_constraints(const LatticeConstraints& c, const Points3& P) {
  const int n = static_cast<int>(P.rows());
  Points3 sum = Points3::Zero(n, 3);
  std::vector<int> members(n, 0);
  for (int i = 0; i < n; ++i) {
    sum.row(c.representative[i]) += P.row(i);
    ++members[c.representative[i]];
  }
  Points3 out(n, 3);
  for (int i = 0; i < n; ++i) {
    const int r = c.representative[i];
    out.row(i) = sum.row(r) / members[r];
  }
  return out;
}

double calc_constraint_violation(const LatticeConstraints& c, const Points3& P) {
  double worst = 0.0;
  for (int i = 0; i < P.rows(); ++i) {
    worst = std::max(worst, (P.row(i) - P.row(c.representative[i])).norm());
  }
  return worst;
}

Eigen::SparseMatrix<double> make_constraint_expansion(const LatticeConstraints& c) {
  const int n = static_cast<int>(c.representative.size());
  std::vector<int> column(n, -1);
  int m = 0;
  for (int i = 0; i < n; ++i)
    if (c.representative[i] == i) column[i] = m++;
  std::vector<Eigen::Triplet<double>> t;
  for (int i = 0; i < n; ++i) t.emplace_back(i, column[c.representative[i]], 1.0);
  Eigen::SparseMatrix<double> E(n, m);
  E.setFromTriplets(t.begin(), t.end());
  return E;
}

BSplineSolid extract_boundary_surface(const BSplineSolid& s, int d, int side) {
  if (d < 0 || d > 2 || side < 0 || side > 1) throw_usage("boundary face: d in 0..2, side 0 or 1");
  if (s.basis[d].periodic || !s.basis[d].is_clamped()) {
    throw_bad_input(fmt::format("direction {} has no clamped boundary face", "uvw"[d]),
                    ErrorContext{.object = s.name});
  }
  const int a = (d + 1) % 3, b = (d + 2) % 3;
  const int id = side == 0 ? 0 : s.num_control(d) - 1;
  Points3 Q(s.num_control(a) * s.num_control(b), 3);
  for (int jb = 0; jb < s.num_control(b); ++jb)
    for (int ia = 0; ia < s.num_control(a); ++ia) {
      int ijk[3];
      ijk[d] = id;
      ijk[a] = ia;
      ijk[b] = jb;
      Q.row(ia + s.num_control(a) * jb) = s.P.row(s.index(ijk[0], ijk[1], ijk[2]));
    }
  return make_surface_solid(s.basis[a], s.basis[b], std::move(Q));
}

}  // namespace fascicle
