// Muscle–muscle contact by point membership (seed 000 §4.7).
#include "fascicle/dynamics/contact.hpp"

#include "fascicle/bspline/membership.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/geometry/mesh_query.hpp"

#include <algorithm>

namespace fascicle {

namespace {

// Distributes a force applied at material point U of `solid` onto its control points.
void add_point_force(const BSplineSolid& solid, const Vec3& U, const Vec3& f, Points3& out) {
  std::vector<Eigen::Triplet<double>> row;
  append_basis_row(solid, U, {0, 0, 0}, 0, row);
  for (const auto& t : row) out.row(t.col()) += t.value() * f.transpose();
}

// Pushes samples of `from` that lie inside `into` out along the shortest way to into's boundary.
void push_out(const SolidDynamicsModel& from, const Points3& P_from, const SolidDynamicsModel& into,
              const Points3& P_into, double k, int samples, Points3& f_from, Points3& f_into,
              MuscleContactResult& r, double sign) {
  BSplineSolid s_from = from.rest, s_into = into.rest;
  s_from.P = P_from;
  s_into.P = P_into;
  BoundaryTessellation t_from = make_boundary_tessellation(s_from, samples);
  const BoundaryTessellation t_into = make_boundary_tessellation(s_into, samples * 2);
  // Built for a handful of closest points per call: the cheaper-to-build tree wins here.
  const MeshQuery surface(
      t_into.mesh, MeshQueryOptions{MeshQueryOptions::ClosestPointTree::embree_clusters});
  const SolidLocator locator(s_into);
  // Cheap rejection: samples outside into's control-point box cannot be inside.
  const Vec3 lo = P_into.colwise().minCoeff(), hi = P_into.colwise().maxCoeff();
  for (Eigen::Index v = 0; v < t_from.mesh.V.rows(); ++v) {
    const Vec3 x = t_from.mesh.V.row(v).transpose();
    if ((x.array() < lo.array()).any() || (x.array() > hi.array()).any()) continue;
    const PointLocation loc = locator.locate(x);
    if (!loc.inside) continue;
    const ClosestPoint c = surface.calc_closest_point(x);
    const Vec3 d = c.point - x;
    const double depth = d.norm();
    if (!(depth > 0.0)) continue;
    const Vec3 f = k * d;  // towards into's boundary: a push
    add_point_force(from.rest, t_from.material.row(v).transpose(), f, f_from);
    add_point_force(into.rest, loc.material, -f, f_into);
    ++r.num_contacts;
    r.max_depth_m = std::max(r.max_depth_m, depth);
    r.force_on_a_N += sign * f;
  }
}

}  // namespace

MuscleContactResult calc_muscle_contact(const SolidDynamicsModel& a, const Points3& P_a,
                                        const SolidDynamicsModel& b, const Points3& P_b,
                                        double k, int samples) {
  MuscleContactResult r;
  r.forces_a = Points3::Zero(P_a.rows(), 3);
  r.forces_b = Points3::Zero(P_b.rows(), 3);
  push_out(a, P_a, b, P_b, k, samples, r.forces_a, r.forces_b, r, 1.0);
  push_out(b, P_b, a, P_a, k, samples, r.forces_b, r.forces_a, r, -1.0);
  return r;
}

std::vector<std::pair<int, int>> find_contact_pairs(const std::vector<Points3>& P,
                                                    const std::vector<std::pair<int, int>>& adjacency,
                                                    double margin) {
  std::vector<std::pair<int, int>> out;
  for (const auto& [i, j] : adjacency) {
    const Vec3 lo_i = P[i].colwise().minCoeff().transpose().array() - margin;
    const Vec3 hi_i = P[i].colwise().maxCoeff().transpose().array() + margin;
    const Vec3 lo_j = P[j].colwise().minCoeff().transpose(), hi_j = P[j].colwise().maxCoeff().transpose();
    if ((hi_i.array() >= lo_j.array()).all() && (hi_j.array() >= lo_i.array()).all())
      out.emplace_back(i, j);
  }
  return out;
}

}  // namespace fascicle
