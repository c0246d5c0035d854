// Compilation of a B-spline solid into the dynamics model: quadrature, supports, mass matrix,
// sparsity pattern, springs, attachments and contact samples (seed 000 §4.2, §4.5, §4.7).
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <functional>
#include <map>

namespace fascicle {

namespace {

// Support of a material point: indices, N and ∇_U N of the non-zero tensor-product functions.
struct Support {
  std::vector<int> index;
  std::vector<double> N;
  std::vector<Vec3> dN;
};

Support calc_support(const BSplineSolid& s, const Vec3& uvw) {
  std::array<BasisValues, 3> b;
  for (int d = 0; d < 3; ++d) b[d] = calc_basis(s.basis[d], uvw[d], 1);
  Support out;
  const int pu = s.basis[0].degree, pv = s.basis[1].degree, pw = s.basis[2].degree;
  for (int c = 0; c <= pw; ++c) {
    const int k = control_index(s.basis[2], b[2].first + c);
    for (int bb = 0; bb <= pv; ++bb) {
      const int j = control_index(s.basis[1], b[1].first + bb);
      for (int a = 0; a <= pu; ++a) {
        const int i = control_index(s.basis[0], b[0].first + a);
        out.index.push_back(s.index(i, j, k));
        out.N.push_back(b[0].N[0][a] * b[1].N[0][bb] * b[2].N[0][c]);
        out.dN.emplace_back(b[0].N[1][a] * b[1].N[0][bb] * b[2].N[0][c],
                            b[0].N[0][a] * b[1].N[1][bb] * b[2].N[0][c],
                            b[0].N[0][a] * b[1].N[0][bb] * b[2].N[1][c]);
      }
    }
  }
  return out;
}

void check_spec(const SolidDynamicsSpec& s, int num_points) {
  auto bad = [](const std::string& what, const std::string& fix) {
    throw_bad_input("solid dynamics: " + what, {.object = "solid dynamics options", .suggestion = fix});
  };
  if (!(s.density_kg_m3 > 0.0) || !std::isfinite(s.density_kg_m3))
    bad(fmt::format("density {} kg/m^3 is not positive", s.density_kg_m3), "use e.g. 1060");
  if (!s.gravity_m_s2.allFinite()) bad("gravity is not finite", "give three finite numbers (m/s^2)");
  if (s.rayleigh_alpha_1_s < 0.0 || s.rayleigh_beta_s < 0.0)
    bad("Rayleigh damping coefficients must be >= 0", "set alpha, beta >= 0");
  if (s.volume_stiffness_Pa < 0.0 || s.volume_damping_Pa_s < 0.0 || s.spring_modulus_Pa < 0.0)
    bad("stiffness and damping values must be >= 0", "check the volume and spring options");
  if (s.ground.c1_Pa < 0.0 || s.ground.c2_Pa < 0.0 || s.ground.bulk_modulus_Pa < 0.0)
    bad("Mooney-Rivlin constants must be >= 0", "check c1, c2, bulk modulus");
  if (!(s.fibre.lambda_opt > 0.0) || !(s.fibre.lambda_star > s.fibre.lambda_opt))
    bad("fibre law needs 0 < lambda_opt < lambda_star", "use lambda_opt 1, lambda_star 1.4");
  if (s.tendon_fraction_start < 0.0 || s.tendon_fraction_end < 0.0 ||
      s.tendon_fraction_start + s.tendon_fraction_end >= 1.0)
    bad("tendon fractions must be >= 0 and leave a belly", "use fractions summing to < 1");
  if (s.pennation_towards < 0 || s.pennation_towards > 2)
    bad("pennation direction must be 0, 1 or 2", "name a parametric direction");
  for (std::size_t a = 0; a < s.attachments.size(); ++a) {
    for (int i : s.attachments[a].control_points) {
      if (i < 0 || i >= num_points)
        bad(fmt::format("attachment '{}' names control point {} (the solid has {})",
                        s.attachments[a].name, i, num_points),
            "use indices of the solid's control points");
    }
  }
}

}  // namespace

std::vector<int> find_end_layer(const BSplineSolid& solid, int side) {
  const int f = static_cast<int>(solid.fibre_direction);
  const int layer = side == 0 ? 0 : solid.num_control(f) - 1;
  std::vector<int> out;
  for (int k = 0; k < solid.num_control(2); ++k)
    for (int j = 0; j < solid.num_control(1); ++j)
      for (int i = 0; i < solid.num_control(0); ++i) {
        const int ijk[3] = {i, j, k};
        if (ijk[f] == layer) out.push_back(solid.index(i, j, k));
      }
  return out;
}

SolidDynamicsModel compile_solid_dynamics(const BSplineSolid& rest, const SolidDynamicsSpec& spec) {
  validate_solid(rest);
  const int n = rest.num_control_points();
  for (int d = 0; d < 3; ++d) {
    if (rest.basis[d].degree < 1)
      throw_bad_input("solid dynamics needs a solid of degree >= 1 in all three directions",
                      {.object = rest.name, .suggestion = "fit or build a trivariate solid"});
  }
  check_spec(spec, n);
  SolidDynamicsModel m;
  m.rest = rest;
  m.spec = spec;

  // Quadrature points, supports and rest fibre directions.
  std::array<std::vector<SpanPoint>, 3> g;
  for (int d = 0; d < 3; ++d) {
    const int nq = spec.quadrature_points_per_span > 0 ? spec.quadrature_points_per_span
                                                       : rest.basis[d].degree + 1;
    g[d] = calc_span_quadrature(rest.basis[d], nq);
  }
  const int f = static_cast<int>(rest.fibre_direction);
  const BSplineBasis& fb = rest.basis[f];
  const double f_lo = fb.get_lower(), f_hi = fb.get_upper();
  std::vector<Eigen::Triplet<double>> mass_triplets;
  for (const SpanPoint& qw : g[2])
    for (const SpanPoint& qv : g[1])
      for (const SpanPoint& qu : g[0]) {
        QuadraturePoint q;
        q.material = Vec3(qu.t, qv.t, qw.t);
        const Support sp = calc_support(rest, q.material);
        Mat3 J = Mat3::Zero();
        for (std::size_t a = 0; a < sp.index.size(); ++a)
          J += rest.P.row(sp.index[a]).transpose() * sp.dN[a].transpose();
        const double detJ = J.determinant();
        if (!(detJ > 0.0)) {
          throw_bad_input(
              fmt::format("solid '{}' is inverted or degenerate at material point ({:.4f}, {:.4f}, "
                          "{:.4f}): det J = {:.3e}",
                          rest.name, q.material[0], q.material[1], q.material[2], detJ),
              {.object = rest.name,
               .suggestion = "check the control points near that material location "
                             "(crossed or collapsed layers); refit the solid"});
        }
        q.weight_m3 = qu.weight * qv.weight * qw.weight * detJ;
        const Mat3 JinvT = J.inverse().transpose();
        q.first = static_cast<int>(m.support_index.size());
        q.count = static_cast<int>(sp.index.size());
        for (std::size_t a = 0; a < sp.index.size(); ++a) {
          m.support_index.push_back(sp.index[a]);
          m.support_N.push_back(sp.N[a]);
          m.support_g.push_back(JinvT * sp.dN[a]);
        }
        // Rest fibre: the fibre-parameter tangent tilted in space by the pennation angle towards
        // the tangent of the chosen cross direction (its part orthogonal to the fibre tangent).
        const Vec3 t_f = J.col(f).normalized();
        Vec3 t_c = J.col(spec.pennation_towards);
        t_c -= t_c.dot(t_f) * t_f;
        q.fibre_rest = (spec.pennation_towards != f && t_c.norm() > 0.0)
                           ? Vec3(std::cos(spec.pennation_rad) * t_f +
                                  std::sin(spec.pennation_rad) * t_c.normalized())
                           : t_f;
        const double frac = (q.material[f] - f_lo) / (f_hi - f_lo);
        q.tendon = frac < spec.tendon_fraction_start || frac > 1.0 - spec.tendon_fraction_end;
        for (int a = 0; a < q.count; ++a)
          for (int b = 0; b < q.count; ++b)
            mass_triplets.emplace_back(sp.index[a], sp.index[b],
                                       spec.density_kg_m3 * q.weight_m3 * sp.N[a] * sp.N[b]);
        m.rest_volume_m3 += q.weight_m3;
        m.quadrature.push_back(q);
      }

  // Mass matrix (consistent, or lumped row sums).
  Eigen::SparseMatrix<double> M(n, n);
  M.setFromTriplets(mass_triplets.begin(), mass_triplets.end());
  m.lumped_mass = M * VecX::Ones(n);
  m.mass_kg = m.lumped_mass.sum();
  for (int i = 0; i < n; ++i) {
    if (!(m.lumped_mass[i] > 0.0))
      throw_bad_input(fmt::format("control point {} of solid '{}' carries no mass", i, rest.name),
                      {.object = rest.name, .suggestion = "remove unused control points"});
  }
  if (spec.mass == MassLumping::lumped) {
    std::vector<Eigen::Triplet<double>> t;
    for (int i = 0; i < n; ++i) t.emplace_back(i, i, m.lumped_mass[i]);
    M.setZero();
    M.setFromTriplets(t.begin(), t.end());
  }
  m.mass_matrix = M;

  // Springs between lattice neighbours (all 26 directions, each pair once).
  if (spec.spring_modulus_Pa > 0.0) {
    const int nu = rest.num_control(0), nv = rest.num_control(1), nw = rest.num_control(2);
    for (int k = 0; k < nw; ++k)
      for (int j = 0; j < nv; ++j)
        for (int i = 0; i < nu; ++i)
          for (int dk = -1; dk <= 1; ++dk)
            for (int dj = -1; dj <= 1; ++dj)
              for (int di = -1; di <= 1; ++di) {
                int ii = i + di, jj = j + dj, kk = k + dk;
                const int ij[3] = {ii, jj, kk};
                const int nn[3] = {nu, nv, nw};
                bool ok = true;
                int wrapped[3];
                for (int d = 0; d < 3; ++d) {
                  int x = ij[d];
                  if (rest.basis[d].periodic) x = (x + nn[d]) % nn[d];
                  if (x < 0 || x >= nn[d]) ok = false;
                  wrapped[d] = x;
                }
                if (!ok) continue;
                const int a = rest.index(i, j, k), b = rest.index(wrapped[0], wrapped[1], wrapped[2]);
                if (b <= a) continue;
                const double L = (rest.P.row(b) - rest.P.row(a)).norm();
                if (!(L > 0.0)) continue;  // coincident (collapsed axis) points
                m.springs.push_back({a, b, L, spec.spring_modulus_Pa * L});
              }
  }

  // Node-level lower-triangle pattern (I >= J) from quadrature supports and springs.
  std::vector<std::vector<int>> cols(n);
  for (const QuadraturePoint& q : m.quadrature)
    for (int a = 0; a < q.count; ++a)
      for (int b = 0; b < q.count; ++b) {
        const int I = m.support_index[q.first + a], J = m.support_index[q.first + b];
        if (I >= J) cols[J].push_back(I);
      }
  for (const auto& s : m.springs) cols[std::min(s.a, s.b)].push_back(std::max(s.a, s.b));

  // Contact samples on the boundary (their supports lie within one span: already in the pattern).
  for (const auto& b : spec.contact_bones) {
    try {
      m.bone_queries.push_back(std::make_shared<const MeshQuery>(b.mesh_rest));
    } catch (const Error& e) {
      throw e.with_object("contact bone '" + b.name + "'");
    }
  }
  if (!spec.contact_planes.empty() || !spec.contact_bones.empty()) {
    const BoundaryTessellation t =
        make_boundary_tessellation(rest, std::max(1, spec.contact_samples_per_span));
    // Boundary samples, then the given material points (their supports too lie in one span).
    std::vector<Vec3> material, offset;
    for (Eigen::Index v = 0; v < t.material.rows(); ++v) {
      material.push_back(t.material.row(v).transpose());
      offset.push_back(Vec3::Zero());
    }
    const Vec3 lo = rest.get_lower(), hi = rest.get_upper();
    const auto& extra = spec.contact_material_points;
    const auto& extra_offset = spec.contact_material_offsets;
    if (!extra_offset.empty() && extra_offset.size() != extra.size())
      throw_bad_input(fmt::format("solid dynamics: {} contact material offsets for {} contact material points",
                                  extra_offset.size(), extra.size()),
                      {.object = rest.name, .suggestion = "give one offset per point, or none"});
    for (std::size_t i = 0; i < extra.size(); ++i) {
      const Vec3 dU = extra_offset.empty() ? Vec3::Zero() : extra_offset[i];
      if (!extra[i].allFinite() || !dU.allFinite())
        throw_bad_input("solid dynamics: a contact material point or offset is not finite",
                        {.object = rest.name, .suggestion = "give material points inside the solid's parameter box"});
      material.push_back(extra[i].cwiseMax(lo).cwiseMin(hi));
      offset.push_back(dU);
    }
    for (std::size_t v = 0; v < material.size(); ++v) {
      const Support sp = calc_support(rest, material[v]);
      SolidDynamicsModel::ContactSample cs;
      cs.material = material[v];
      for (std::size_t a = 0; a < sp.index.size(); ++a) {
        const double w = sp.N[a] + sp.dN[a].dot(offset[v]);
        if (w == 0.0) continue;
        cs.index.push_back(sp.index[a]);
        cs.N.push_back(w);
      }
      m.contact_samples.push_back(std::move(cs));
    }
    for (std::size_t b = 0; b < spec.contact_bones.size(); ++b) {
      std::vector<double> depth(m.contact_samples.size(), 0.0);
      if (spec.contact_bones[b].exempt_rest_contact) {
        for (std::size_t s = 0; s < depth.size(); ++s) {
          const auto& cs = m.contact_samples[s];
          Vec3 x = Vec3::Zero();
          for (std::size_t a = 0; a < cs.index.size(); ++a) x += cs.N[a] * rest.P.row(cs.index[a]).transpose();
          if (m.bone_queries[b]->calc_is_inside(x))
            depth[s] = (m.bone_queries[b]->calc_closest_point(x).point - x).norm();
        }
      }
      m.bone_rest_depth.push_back(std::move(depth));
    }
    double k = spec.contact_stiffness_N_m;
    if (k <= 0.0)
      for (const auto& c : spec.contact_planes) k = std::max(k, c.stiffness_N_m);
    if (k <= 0.0) {
      // Automatic: the whole weight (or 10 N, if larger) carried by a tenth of the samples
      // penetrates 0.1 mm.
      const double load = std::max(10.0, m.mass_kg * 9.81);
      k = load / (0.1 * static_cast<double>(m.contact_samples.size()) * 1e-4);
    }
    m.contact_stiffness_N_m = k;
  }
  m.block_ptr.assign(n + 1, 0);
  for (int J = 0; J < n; ++J) {
    auto& c = cols[J];
    std::sort(c.begin(), c.end());
    c.erase(std::unique(c.begin(), c.end()), c.end());
    m.block_ptr[J + 1] = m.block_ptr[J] + static_cast<int>(c.size());
  }
  m.block_row.reserve(m.block_ptr[n]);
  for (int J = 0; J < n; ++J) m.block_row.insert(m.block_row.end(), cols[J].begin(), cols[J].end());
  auto find_block = [&](int I, int J) {
    const auto b = m.block_row.begin() + m.block_ptr[J], e = m.block_row.begin() + m.block_ptr[J + 1];
    return static_cast<int>(std::lower_bound(b, e, I) - m.block_row.begin());
  };
  m.pair_first.reserve(m.quadrature.size() + 1);
  for (const QuadraturePoint& q : m.quadrature) {
    m.pair_first.push_back(static_cast<int>(m.pairs.size()));
    for (int a = 0; a < q.count; ++a)
      for (int b = 0; b < q.count; ++b) {
        const int I = m.support_index[q.first + a], J = m.support_index[q.first + b];
        if (I >= J) m.pairs.push_back({a, b, find_block(I, J)});
      }
  }
  m.pair_first.push_back(static_cast<int>(m.pairs.size()));

  // Quadrature points grouped by identical support (knot spans), in order of first appearance.
  {
    std::map<std::vector<int>, int> group_of;
    std::vector<std::vector<int>> members;
    for (std::size_t qi = 0; qi < m.quadrature.size(); ++qi) {
      const QuadraturePoint& q = m.quadrature[qi];
      std::vector<int> key(m.support_index.begin() + q.first,
                           m.support_index.begin() + q.first + q.count);
      const auto [it, inserted] = group_of.emplace(std::move(key), static_cast<int>(members.size()));
      if (inserted) members.emplace_back();
      members[it->second].push_back(static_cast<int>(qi));
    }
    m.group_ptr.assign(1, 0);
    for (const std::vector<int>& g : members) {
      const QuadraturePoint& q0 = m.quadrature[g.front()];
      Eigen::MatrixXd G(q0.count, 3 * static_cast<int>(g.size()));
      for (std::size_t i = 0; i < g.size(); ++i) {
        const QuadraturePoint& q = m.quadrature[g[i]];
        for (int a = 0; a < q.count; ++a)
          for (int j = 0; j < 3; ++j) G(a, 3 * static_cast<int>(i) + j) = m.support_g[q.first + a][j];
      }
      const auto first = m.support_index.begin() + q0.first;
      const bool increasing =  // strictly: a repeated index would need both (a, b) and (b, a)
          std::adjacent_find(first, first + q0.count, std::greater_equal<int>()) == first + q0.count;
      m.group_ascending.push_back(increasing ? 1 : 0);
      m.group_gt.push_back(G.transpose());
      m.group_g.push_back(std::move(G));
      m.group_points.insert(m.group_points.end(), g.begin(), g.end());
      m.group_ptr.push_back(static_cast<int>(m.group_points.size()));
    }
  }

  // Attachments.
  m.fixed.assign(n, 0);
  for (const auto& a : spec.attachments)
    for (int i : a.control_points) m.fixed[i] = 1;

  // Volume: the boundary form when every non-periodic direction is clamped.
  bool clamped = true;
  for (int d = 0; d < 3; ++d)
    if (!rest.basis[d].periodic && !rest.basis[d].is_clamped()) clamped = false;
  if (clamped) m.volume_integrator = std::make_shared<const BoundaryVolumeIntegrator>(rest);
  return m;
}

VecX flatten_points(const Points3& P) {
  VecX x(3 * P.rows());
  for (Eigen::Index i = 0; i < P.rows(); ++i) x.segment<3>(3 * i) = P.row(i).transpose();
  return x;
}

Points3 unflatten_points(const VecX& x) {
  Points3 P(x.size() / 3, 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i) P.row(i) = x.segment<3>(3 * i).transpose();
  return P;
}

}  // namespace fascicle
