// Least-squares fitting of B-spline solids to samples and to closed muscle meshes (seed 000 §3.1.2).
#include "fascicle/bspline/fitting.hpp"

#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/obb.hpp"
#include "fascicle/geometry/slicing.hpp"

#include <Eigen/SparseCholesky>
#include <nanoflann.hpp>
#include <fmt/format.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <numbers>

namespace fascicle {

namespace {

// Second differences of the control lattice along each direction with >= 3 control points.
Eigen::SparseMatrix<double> make_smoothing_operator(const BSplineSolid& s) {
  std::vector<Eigen::Triplet<double>> t;
  int row = 0;
  const int n[3] = {s.num_control(0), s.num_control(1), s.num_control(2)};
  for (int d = 0; d < 3; ++d) {
    if (n[d] < 3) continue;
    const bool periodic = s.basis[d].periodic;
    for (int k = 0; k < n[2]; ++k)
      for (int j = 0; j < n[1]; ++j)
        for (int i = 0; i < n[0]; ++i) {
          int ijk[3] = {i, j, k};
          const int c = ijk[d];
          if (!periodic && (c == 0 || c == n[d] - 1)) continue;
          int lo[3] = {i, j, k}, hi[3] = {i, j, k};
          lo[d] = (c - 1 + n[d]) % n[d];
          hi[d] = (c + 1) % n[d];
          t.emplace_back(row, s.index(lo[0], lo[1], lo[2]), 1.0);
          t.emplace_back(row, s.index(i, j, k), -2.0);
          t.emplace_back(row, s.index(hi[0], hi[1], hi[2]), 1.0);
          ++row;
        }
  }
  Eigen::SparseMatrix<double> D(row, s.num_control_points());
  D.setFromTriplets(t.begin(), t.end());
  return D;
}

}  // namespace

Points3 fit_control_points(const BSplineSolid& s, const LatticeConstraints& c,
                           const Points3& material, const Points3& X, const VecX& weights,
                           double smoothing) {
  if (material.rows() != X.rows() || (weights.size() && weights.size() != X.rows())) {
    throw_usage("fit_control_points: material points, positions and weights differ in count");
  }
  std::vector<Eigen::Triplet<double>> t;
  for (Eigen::Index r = 0; r < material.rows(); ++r) {
    Vec3 u = material.row(r).transpose();
    append_basis_row(s, wrap_material_point(s, u), {0, 0, 0}, static_cast<int>(r), t);
  }
  if (weights.size()) {
    for (auto& e : t) e = Eigen::Triplet<double>(e.row(), e.col(), e.value() * std::sqrt(weights[e.row()]));
  }
  Eigen::SparseMatrix<double> A(material.rows(), s.num_control_points());
  A.setFromTriplets(t.begin(), t.end());
  const Eigen::SparseMatrix<double> E = make_constraint_expansion(c);
  const Eigen::SparseMatrix<double> AE = A * E;
  const Eigen::SparseMatrix<double> DE = make_smoothing_operator(s) * E;
  Eigen::SparseMatrix<double> N = Eigen::SparseMatrix<double>(AE.transpose()) * AE;
  Eigen::SparseMatrix<double> R = Eigen::SparseMatrix<double>(DE.transpose()) * DE;
  const double trN = N.diagonal().sum(), trR = R.diagonal().sum();
  if (smoothing > 0 && trR > 0) N += (smoothing * trN / trR) * R;
  Points3 rhs = AE.transpose() * (weights.size() ? Points3(X.array().colwise() * weights.array().sqrt()) : X);
  Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> ldlt(N);
  if (ldlt.info() != Eigen::Success) {
    throw_bad_input("the samples do not determine the control points (singular normal equations)",
                    ErrorContext{.object = s.name,
                                 .suggestion = "add samples in every knot span or raise smoothing"});
  }
  const Points3 free = ldlt.solve(rhs);
  if (!free.allFinite() || (ldlt.vectorD().array() <= 0).any()) {
    throw_bad_input("the samples do not determine the control points (rank deficient)",
                    ErrorContext{.object = s.name,
                                 .suggestion = "add samples in every knot span or raise smoothing"});
  }
  return E * free;
}

namespace {

// A closed contour resampled by arc length from its seam: where it crosses the half-line from its
// centroid along e1 (the crossing farthest from the centroid).
Points3 resample_contour(const Points3& pts, const Vec3& centre, const Vec3& e1, const Vec3& e2,
                         int samples) {
  const int n = static_cast<int>(pts.rows());
  int seam = -1;
  double seam_t = 0.0, seam_r = -1.0;
  for (int i = 0; i < n; ++i) {
    const Vec3 a = pts.row(i).transpose() - centre, b = pts.row((i + 1) % n).transpose() - centre;
    const double ya = a.dot(e2), yb = b.dot(e2);
    if ((ya < 0 && yb >= 0) || (ya > 0 && yb <= 0)) {
      const double t = ya / (ya - yb);
      const double x = (a + t * (b - a)).dot(e1);
      if (x > 0 && x > seam_r) seam = i, seam_t = t, seam_r = x;
    }
  }
  if (seam < 0) seam = 0, seam_t = 0.0;
  // the contour from the seam point, closed
  std::vector<Vec3> poly;
  const Vec3 s0 = pts.row(seam).transpose() + seam_t * (pts.row((seam + 1) % n) - pts.row(seam)).transpose();
  poly.push_back(s0);
  for (int k = 1; k <= n; ++k) poly.push_back(pts.row((seam + k) % n).transpose());
  poly.push_back(s0);
  std::vector<double> len(poly.size(), 0.0);
  for (std::size_t i = 1; i < poly.size(); ++i) len[i] = len[i - 1] + (poly[i] - poly[i - 1]).norm();
  Points3 out(samples, 3);
  std::size_t seg = 1;
  for (int m = 0; m < samples; ++m) {
    const double L = len.back() * m / samples;
    while (seg + 1 < len.size() && len[seg] < L) ++seg;
    const double dl = len[seg] - len[seg - 1];
    const double f = dl > 0 ? (L - len[seg - 1]) / dl : 0.0;
    out.row(m) = (poly[seg - 1] + f * (poly[seg] - poly[seg - 1])).transpose();
  }
  return out;
}

// nanoflann adaptor over the slice boundary samples (rows of X).
struct BoundarySamples {
  const Points3* X = nullptr;
  std::vector<int> rows;
  std::size_t kdtree_get_point_count() const { return rows.size(); }
  double kdtree_get_pt(std::size_t i, std::size_t d) const {
    return (*X)(rows[i], static_cast<Eigen::Index>(d));
  }
  template <class Box>
  bool kdtree_get_bbox(Box&) const { return false; }
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<
      nanoflann::L2_Simple_Adaptor<double, BoundarySamples>, BoundarySamples, 3>;
};

// det J of a fitted solid at the Gauss points solid dynamics integrates with (degree + 1 per span)
// and at a finer rule, so that a fold between the coarse points is caught as well.
JacobianMinimum find_fit_jacobian_minimum(const BSplineSolid& s) {
  const JacobianMinimum a = find_min_jacobian_determinant(s);
  const int finer = 2 + std::max({s.basis[0].degree, s.basis[1].degree, s.basis[2].degree});
  const JacobianMinimum b = find_min_jacobian_determinant(s, finer);
  return std::isnan(a.det_J) || a.det_J <= b.det_J ? a : b;
}

// Foot of the perpendicular from X onto the boundary surface u = 1 of a cylindrical lattice
// (v periodic, w clamped to [0, 1]): Gauss–Newton on |x(1, v, w) - X|^2 from (v, w), steps
// halved until the distance does not grow. Returns the improved (v, w).
std::array<double, 2> project_onto_boundary(const BSplineSolid& s, const Vec3& X, double v,
                                            double w) {
  SolidPoint sp = calc_point_and_jacobian(s, Vec3(1.0, v, w));
  double d2 = (sp.x - X).squaredNorm();
  for (int it = 0; it < 8; ++it) {
    const Vec3 r = sp.x - X;
    const Vec3 xv = sp.J.col(1), xw = sp.J.col(2);
    const double a = xv.dot(xv), b = xv.dot(xw), c = xw.dot(xw);
    const double det = a * c - b * b;
    if (!(det > 0)) break;
    const double gv = xv.dot(r), gw = xw.dot(r);
    double dv = -(c * gv - b * gw) / det, dw = -(a * gw - b * gv) / det;
    // at most a tenth of the parameter range per step: stay on the same side of the muscle
    const double m = std::max(std::abs(dv), std::abs(dw));
    if (m > 0.1) dv *= 0.1 / m, dw *= 0.1 / m;
    bool improved = false;
    for (int h = 0; h < 6; ++h) {
      const double vn = v + dv, wn = std::clamp(w + dw, 0.0, 1.0);
      const SolidPoint tn = calc_point_and_jacobian(s, Vec3(1.0, vn, wn));
      const double dn = (tn.x - X).squaredNorm();
      if (dn < d2) {
        v = vn - std::floor(vn), w = wn, sp = tn, d2 = dn;
        improved = true;
        break;
      }
      dv *= 0.5, dw *= 0.5;
    }
    if (!improved || std::max(std::abs(dv), std::abs(dw)) < 1e-10) break;
  }
  return {v, w};
}

}  // namespace

MeshFitResult fit_solid_to_mesh(const TriMesh& mesh, const MeshFitOptions& o) {
  if (!o.lattice_candidates.empty()) {
    // lattice choice: every candidate (and `count`) is fitted; the smallest max distance wins
    MeshFitOptions one = o;
    one.lattice_candidates.clear();
    MeshFitResult best = fit_solid_to_mesh(mesh, one);
    for (const auto& c : o.lattice_candidates) {
      one.count = c;
      MeshFitResult r = fit_solid_to_mesh(mesh, one);
      const bool r_ok = r.min_jacobian_det > 0.0, best_ok = best.min_jacobian_det > 0.0;
      if (r_ok != best_ok ? r_ok : r.max_distance_m < best.max_distance_m) best = std::move(r);
    }
    return best;
  }
  if (mesh.V.rows() == 0 || mesh.F.rows() == 0) throw_bad_input("the muscle mesh is empty");
  if (o.origin.has_value() != o.insertion.has_value()) {
    throw_usage("give both origin and insertion, or neither (automatic axis)");
  }
  // muscle axis and its extent
  Vec3 axis;
  if (o.origin) {
    axis = *o.insertion - *o.origin;
    if (!(axis.norm() > 0)) throw_bad_input("origin and insertion coincide");
  } else {
    axis = compute_oriented_box(mesh).axes.col(0);
  }
  axis.normalize();
  const VecX along = mesh.V * axis;
  double t0 = along.minCoeff(), t1 = along.maxCoeff();
  if (o.origin && o.origin->dot(axis) > o.insertion->dot(axis)) std::swap(t0, t1);  // never: axis points to insertion
  const Vec3 e1 = (std::abs(axis.x()) < 0.9 ? Vec3::UnitX() : Vec3::UnitY()).cross(axis).normalized();
  const Vec3 e2 = axis.cross(e1);
  // slice levels: denser near the ends (cosine spacing) between the insets
  const int K = std::max(4, o.num_slices);
  VecX offsets(K), wlev(K);
  for (int k = 0; k < K; ++k) {
    const double s = 0.5 * (1.0 - std::cos(std::numbers::pi * k / (K - 1)));
    wlev[k] = s;
    offsets[k] = t0 + (t1 - t0) * (o.end_inset + (1.0 - 2.0 * o.end_inset) * s);
  }
  const auto slices = slice_mesh_parallel(mesh, axis, offsets);
  const int M = std::max(8, o.contour_samples), Rr = std::max(1, o.radial_samples);
  Points3 U(K * M * (Rr + 1), 3), X(K * M * (Rr + 1), 3);
  Eigen::Index row = 0;
  MeshFitResult out;
  for (int k = 0; k < K; ++k) {
    // the largest closed contour; others must be negligible
    int best = -1;
    double best_area = 0.0, other_area = 0.0;
    for (std::size_t c = 0; c < slices[k].size(); ++c) {
      const Contour& ct = slices[k][c];
      if (!ct.closed) {
        throw_bad_input(fmt::format("slice {} (at {:.4g} m along the axis) has an open contour", k, offsets[k]),
                        ErrorContext{.object = o.name, .suggestion = "repair the mesh: it must be closed"});
      }
      const double a = std::abs(compute_contour_area(ct, axis));
      if (a > best_area) {
        other_area += best_area;
        best_area = a, best = static_cast<int>(c);
      } else {
        other_area += a;
      }
    }
    if (best < 0) {
      throw_bad_input(fmt::format("slice {} (at {:.4g} m along the axis) misses the mesh", k, offsets[k]),
                      ErrorContext{.object = o.name});
    }
    if (other_area > 0.02 * best_area) {
      throw_bad_input(
          fmt::format("slice {} (at {:.4g} m along the axis) is not a single closed contour: {} "
                      "contours", k, offsets[k], slices[k].size()),
          ErrorContext{.object = o.name,
                       .suggestion = "give origin/insertion points so the axis follows the muscle, "
                                     "or split the muscle into heads"});
    }
    const Points3& pts = slices[k][best].points;
    // area centroid of the contour polygon (in-plane), on the slice plane
    Vec3 centre = Vec3::Zero();
    double area2 = 0.0;
    const Vec3 q0 = pts.row(0).transpose();
    for (Eigen::Index i = 1; i + 1 < pts.rows(); ++i) {
      const Vec3 a = pts.row(i).transpose(), b = pts.row(i + 1).transpose();
      const double w = (a - q0).cross(b - q0).dot(axis);
      centre += w * (q0 + a + b) / 3.0;
      area2 += w;
    }
    centre = std::abs(area2) > 0 ? Vec3(centre / area2) : Vec3(pts.colwise().mean().transpose());
    if (k == 0) out.axis_start = centre;
    if (k == K - 1) out.axis_end = centre;
    const Points3 ring = resample_contour(pts, centre, e1, e2, M);
    for (int m = 0; m < M; ++m) {
      const Vec3 b = ring.row(m).transpose();
      for (int r = 0; r <= Rr; ++r) {
        const double u = static_cast<double>(r) / Rr;
        U.row(row) << u, static_cast<double>(m) / M, wlev[k];
        X.row(row) = (centre + u * (b - centre)).transpose();
        ++row;
      }
    }
  }
  // boundary samples weigh more than interior ones (the interior placement is a guess)
  VecX weights(row);
  for (Eigen::Index r = 0; r < row; ++r) weights[r] = U(r, 0) == 1.0 ? 4.0 : 1.0;
  LatticeDesign design = make_cylindrical_lattice(1.0, 1.0, o.degree, o.count);
  design.solid.name = o.name;
  design.solid.fibre_direction = FibreDirection::w;
  design.solid.P = fit_control_points(design.solid, design.constraints, U, X, weights, o.smoothing);
  // Parameter correction (vertex samples, then closest-point rounds) lowers the boundary distance
  // but can fold the interior of a coarse lattice. Every step is checked, and a step that turns a
  // non-inverted fit into an inverted one is dropped, so the last non-inverted fit is returned:
  // dropped vertex samples leave the closest-point rounds to the slice samples alone; a dropped
  // round ends the rounds. Steps from an inverted fit are kept (nothing to lose).
  JacobianMinimum jmin = find_fit_jacobian_minimum(design.solid);
  Eigen::Index kept_rows = row;
  // true: the step's fit (design.solid.P) is kept; false: P restored to the previous fit
  auto accept_step = [&](const Points3& previous) {
    const JacobianMinimum j = find_fit_jacobian_minimum(design.solid);
    if (jmin.det_J > 0.0 && !(j.det_J > 0.0)) {
      spdlog::debug("fit '{}': parameter-correction step inverts the solid at ({:.3f}, {:.3f}, {:.3f}) "
                    "(det J {:.3e}); kept the previous fit", o.name, j.material[0], j.material[1],
                    j.material[2], j.det_J);
      design.solid.P = previous;
      out.correction_backed_off = true;
      return false;
    }
    jmin = j;
    kept_rows = row;
    return true;
  };
  if (o.mesh_vertex_samples) {
    // start each vertex's projection from the nearest slice boundary sample
    BoundarySamples bs;
    for (Eigen::Index r = 0; r < row; ++r)
      if (U(r, 0) == 1.0) bs.rows.push_back(static_cast<int>(r));
    bs.X = &X;
    const BoundarySamples::Tree tree(3, bs, nanoflann::KDTreeSingleIndexAdaptorParams(16));
    const int nv = static_cast<int>(mesh.V.rows());
    std::vector<std::array<double, 2>> vw(nv);
    parallel_for(static_cast<std::size_t>(nv), [&](std::size_t i) {
      const Vec3 p = mesh.V.row(static_cast<Eigen::Index>(i)).transpose();
      std::size_t nearest = 0;
      double d2 = 0.0;
      nanoflann::KNNResultSet<double> result(1);
      result.init(&nearest, &d2);
      tree.findNeighbors(result, p.data(), nanoflann::SearchParams());
      const int r = bs.rows[nearest];
      vw[i] = project_onto_boundary(design.solid, p, U(r, 1), U(r, 2));
    });
    // vertices whose foot is on the end rims (clamped w) belong to the end caps: left out
    std::vector<int> keep;
    for (int i = 0; i < nv; ++i)
      if (vw[i][1] > 0.0 && vw[i][1] < 1.0) keep.push_back(i);
    const Eigen::Index n0 = row, n1 = row + static_cast<Eigen::Index>(keep.size());
    U.conservativeResize(n1, 3);
    X.conservativeResize(n1, 3);
    weights.conservativeResize(n1);
    for (std::size_t k = 0; k < keep.size(); ++k) {
      const Eigen::Index r = n0 + static_cast<Eigen::Index>(k);
      U.row(r) << 1.0, vw[keep[k]][0], vw[keep[k]][1];
      X.row(r) = mesh.V.row(keep[k]);
      weights[r] = 4.0;
    }
    row = n1;
    const Points3 previous = design.solid.P;
    design.solid.P = fit_control_points(design.solid, design.constraints, U, X, weights, o.smoothing);
    out.mesh_vertex_samples_used = accept_step(previous);
    if (!out.mesh_vertex_samples_used) {
      row = n0;
      U.conservativeResize(n0, 3);
      X.conservativeResize(n0, 3);
      weights.conservativeResize(n0);
    }
  }
  for (int it = 0; it < o.reparametrise_iterations; ++it) {
    parallel_for(static_cast<std::size_t>(row), [&](std::size_t r) {
      if (U(r, 0) != 1.0) return;
      const auto vw = project_onto_boundary(design.solid, X.row(r).transpose(), U(r, 1), U(r, 2));
      U(r, 1) = vw[0];
      U(r, 2) = vw[1];
    });
    const Points3 previous = design.solid.P;
    design.solid.P = fit_control_points(design.solid, design.constraints, U, X, weights, o.smoothing);
    if (!accept_step(previous)) break;
    ++out.reparametrise_rounds;
  }
  validate_solid(design.solid);
  out.min_jacobian_det = jmin.det_J;
  out.min_jacobian_material = jmin.material;
  out.solid = std::move(design.solid);
  out.constraints = std::move(design.constraints);
  out.num_samples = static_cast<int>(kept_rows);
  // quality: fitted boundary -> mesh distances, and volumes
  const BoundaryTessellation tess = make_boundary_tessellation(out.solid, 6);
  const MeshQuery query(mesh);
  double sum = 0.0, worst = 0.0;
  for (Eigen::Index v = 0; v < tess.mesh.V.rows(); ++v) {
    const double d = query.calc_closest_point(tess.mesh.V.row(v).transpose()).distance;
    sum += d;
    worst = std::max(worst, d);
  }
  out.mean_distance_m = sum / std::max<Eigen::Index>(1, tess.mesh.V.rows());
  out.max_distance_m = worst;
  out.mesh_volume_m3 = calc_mass_properties(mesh).volume_m3;
  out.solid_volume_m3 = calc_boundary_volume(out.solid);
  out.volume_difference = (out.solid_volume_m3 - out.mesh_volume_m3) / out.mesh_volume_m3;
  return out;
}

}  // namespace fascicle
