// Energies and per-frame metrics of a solid state.
#include "fascicle/bspline/fibres.hpp"
#include "internal.hpp"

#include <cmath>

namespace fascicle {

namespace {

struct ContactSummary {
  double energy_J = 0.0;
  Vec3 reaction_N = Vec3::Zero();  // force of the solid on the planes
};

ContactSummary calc_contact_summary(const SolidDynamicsModel& m, const Points3& P,
                                    const std::vector<Transform>& X) {
  ContactSummary out;
  const double k = m.contact_stiffness_N_m;
  for (const auto& c : dynamics_detail::find_active_contacts(m, P, X)) {
    out.energy_J += 0.5 * k * c.depth * c.depth;
    out.reaction_N -= k * c.depth * c.normal;  // the bone pushes +n, the solid pushes −n
  }
  return out;
}

}  // namespace

SolidEnergies calc_energies(const SolidDynamicsModel& m, const SolidState& s,
                            const std::vector<Transform>& X) {
  SolidEnergies e;
  const VecX v = flatten_points(s.V);
  const Eigen::Index n = s.P.rows();
  Eigen::Map<const Eigen::Matrix<double, 3, Eigen::Dynamic>> Vm(v.data(), 3, n);
  e.kinetic_J = 0.5 * (Vm * m.mass_matrix).cwiseProduct(Vm).sum();
  e.gravity_J = 0.0;
  for (Eigen::Index i = 0; i < n; ++i)
    e.gravity_J -= m.lumped_mass[i] * m.spec.gravity_m_s2.dot(s.P.row(i).transpose());
  const ForceEvaluation fe = calc_forces(m, s.P, s.V, s.activation, false, X);
  const ContactSummary c = calc_contact_summary(m, s.P, X);
  e.contact_J = c.energy_J;
  e.elastic_J = fe.energy_J - e.gravity_J - e.contact_J;
  return e;
}

SolidMetrics calc_metrics(const SolidDynamicsModel& m, const SolidState& s,
                          const std::vector<Transform>& X) {
  SolidMetrics out;
  out.time_s = s.time_s;
  out.activation = s.activation;
  out.volume_m3 = dynamics_detail::calc_volume_and_flat_gradient(m, s.P, nullptr);
  out.volume_error = (out.volume_m3 - m.rest_volume_m3) / m.rest_volume_m3;
  out.energies = calc_energies(m, s, X);
  out.contact_reaction_N = calc_contact_summary(m, s.P, X).reaction_N;
  out.centre_of_mass_m = (m.lumped_mass.transpose() * s.P).transpose() / m.mass_kg;

  // Line of action: centroid of the fibre-start layer to that of the fibre-end layer.
  Vec3 c0 = Vec3::Zero(), c1 = Vec3::Zero();
  const auto l0 = find_end_layer(m.rest, 0), l1 = find_end_layer(m.rest, 1);
  for (int i : l0) c0 += s.P.row(i).transpose();
  for (int i : l1) c1 += s.P.row(i).transpose();
  Vec3 axis = c1 / static_cast<double>(l1.size()) - c0 / static_cast<double>(l0.size());
  axis.normalize();
  double wsum = 0.0, stretch = 0.0, pennation = 0.0, min_det = INFINITY;
  for (const QuadraturePoint& q : m.quadrature) {
    Mat3 F = Mat3::Zero();
    for (int a = 0; a < q.count; ++a)
      F += s.P.row(m.support_index[q.first + a]).transpose() * m.support_g[q.first + a].transpose();
    min_det = std::min(min_det, F.determinant());
    if (q.tendon) continue;
    const Vec3 Fa = F * q.fibre_rest;
    const double l = Fa.norm();
    stretch += q.weight_m3 * l;
    pennation += q.weight_m3 * std::acos(std::min(1.0, std::abs(Fa.dot(axis)) / l));
    wsum += q.weight_m3;
  }
  out.mean_fibre_stretch = stretch / wsum;
  out.mean_pennation_rad = pennation / wsum;
  out.min_jacobian_ratio = min_det;
  BSplineSolid cur = m.rest;
  cur.P = s.P;
  const auto curves = calc_fibre_curves(cur, 3, 3, 24);
  double len = 0.0;
  for (const Points3& c : curves)
    for (Eigen::Index i = 1; i < c.rows(); ++i) len += (c.row(i) - c.row(i - 1)).norm();
  out.mean_fibre_length_m = len / static_cast<double>(curves.size());
  return out;
}

}  // namespace fascicle
