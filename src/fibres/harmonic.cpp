// Harmonic fibre field: linear FEM Laplace solve (CHOLMOD) and RK4 streamlines with tet walking.
#include "fascicle/fibres/harmonic.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/fibres/attachment.hpp"
#include "point_index.hpp"
#include "sampling.hpp"

#include <Eigen/CholmodSupport>
#include <fmt/format.h>
#include <Eigen/LU>
#include <Eigen/SparseCore>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>

namespace fascicle {

namespace {

// Gradients of the four barycentric basis functions of tet t (rows), and its volume.
Eigen::Matrix<double, 4, 3> calc_basis_gradients(const TetMesh& m, Eigen::Index t, double& volume) {
  const Vec3 x0 = m.V.row(m.T(t, 0));
  Mat3 D;
  for (int k = 0; k < 3; ++k) D.col(k) = Vec3(m.V.row(m.T(t, k + 1))) - x0;
  volume = D.determinant() / 6.0;
  Eigen::Matrix<double, 4, 3> G;
  const Mat3 Dinv = D.inverse();
  G.bottomRows<3>() = Dinv;  // row k of D^-1 is grad(phi_{k+1})
  G.row(0) = -(Dinv.row(0) + Dinv.row(1) + Dinv.row(2));
  return G;
}

double calc_mean_tet_edge(const TetMesh& m) {
  double sum = 0.0;
  const Eigen::Index n = std::min<Eigen::Index>(m.num_tets(), 20000);
  for (Eigen::Index t = 0; t < n; ++t)
    for (int a = 0; a < 4; ++a)
      for (int b = a + 1; b < 4; ++b) sum += (m.V.row(m.T(t, a)) - m.V.row(m.T(t, b))).norm();
  return sum / (6.0 * std::max<Eigen::Index>(n, 1));
}


// Per-tet gradient of the piecewise-linear field u, and per-vertex volume-weighted means.
void calc_field_gradients(const TetMesh& m, const VecX& u, Points3& tet_gradient,
                          Points3& vertex_gradient) {
  tet_gradient.resize(m.num_tets(), 3);
  vertex_gradient = Points3::Zero(m.num_vertices(), 3);
  VecX weight = VecX::Zero(m.num_vertices());
  for (Eigen::Index t = 0; t < m.num_tets(); ++t) {
    double vol = 0.0;
    const auto G = calc_basis_gradients(m, t, vol);
    Vec3 g = Vec3::Zero();
    for (int k = 0; k < 4; ++k) g += u(m.T(t, k)) * G.row(k).transpose();
    if (!g.allFinite()) g.setZero();
    tet_gradient.row(t) = g.transpose();
    const double w = std::max(vol, 0.0);
    for (int k = 0; k < 4; ++k) {
      vertex_gradient.row(m.T(t, k)) += w * g.transpose();
      weight(m.T(t, k)) += w;
    }
  }
  for (Eigen::Index v = 0; v < m.num_vertices(); ++v)
    if (weight(v) > 0.0) vertex_gradient.row(v) /= weight(v);
}
}  // namespace

Eigen::SparseMatrix<double> calc_stiffness_matrix(const TetMesh& mesh) {
  std::vector<Eigen::Triplet<double>> trips;
  trips.reserve(16 * mesh.num_tets());
  for (Eigen::Index t = 0; t < mesh.num_tets(); ++t) {
    double vol = 0.0;
    const auto G = calc_basis_gradients(mesh, t, vol);
    if (!(vol > 0.0)) continue;  // degenerate (sliver of zero volume): no stiffness
    const Eigen::Matrix4d Ke = vol * G * G.transpose();
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) trips.emplace_back(mesh.T(t, i), mesh.T(t, j), Ke(i, j));
  }
  Eigen::SparseMatrix<double> K(mesh.num_vertices(), mesh.num_vertices());
  K.setFromTriplets(trips.begin(), trips.end());
  return K;
}

VecX solve_laplace(const TetMesh& mesh, const std::vector<int>& zero_vertices,
                   const std::vector<int>& one_vertices, std::string_view zero_name,
                   std::string_view one_name) {
  if (zero_vertices.empty() || one_vertices.empty())
    throw_bad_input(fmt::format("the Laplace problem needs vertices with value 0 ({}) and 1 ({}); "
                                "{} has none",
                                zero_name, one_name,
                                zero_vertices.empty() ? zero_name : one_name),
                    {.suggestion = "check that both areas lie on the muscle surface"});
  const Eigen::Index n = mesh.num_vertices();
  VecX u = VecX::Zero(n);
  std::vector<int> role(n, -1);  // -1 free, 0 / 1 fixed value
  for (int v : zero_vertices) role.at(v) = 0;
  for (int v : one_vertices) {
    if (role.at(v) == 0)
      throw_bad_input(fmt::format("a vertex belongs to both {} and {}", zero_name, one_name),
                      {.suggestion = "give disjoint areas"});
    role[v] = 1;
    u(v) = 1.0;
  }
  std::vector<int> free_index(n, -1);
  int nf = 0;
  for (Eigen::Index v = 0; v < n; ++v)
    if (role[v] < 0) free_index[v] = nf++;
  const Eigen::SparseMatrix<double> K = calc_stiffness_matrix(mesh);
  // Split K into the free block and the right-hand side -K_FB u_B.
  std::vector<Eigen::Triplet<double>> trips;
  VecX rhs = VecX::Zero(nf);
  for (int col = 0; col < K.outerSize(); ++col)
    for (Eigen::SparseMatrix<double>::InnerIterator it(K, col); it; ++it) {
      const int r = static_cast<int>(it.row());
      if (free_index[r] < 0) continue;
      if (free_index[col] >= 0)
        trips.emplace_back(free_index[r], free_index[col], it.value());
      else
        rhs(free_index[r]) -= it.value() * u(col);
    }
  if (nf == 0) return u;
  Eigen::SparseMatrix<double> A(nf, nf);
  A.setFromTriplets(trips.begin(), trips.end());
  Eigen::CholmodSupernodalLLT<Eigen::SparseMatrix<double>, Eigen::Lower> solver;
  {
    const std::lock_guard lock(get_ordering_mutex());  // CHOLMOD may order with METIS
    solver.analyzePattern(A);
  }
  solver.factorize(A);
  if (solver.info() != Eigen::Success)
    throw_numerical("sparse Cholesky factorisation of the Laplace system failed",
                    {.suggestion = "the tetrahedral mesh may have a part without an attachment "
                                   "area; check the mesh is one closed piece"});
  const VecX x = solver.solve(rhs);
  if (solver.info() != Eigen::Success || !x.allFinite())
    throw_numerical("the Laplace solve produced non-finite values");
  for (Eigen::Index v = 0; v < n; ++v)
    if (free_index[v] >= 0) u(v) = x(free_index[v]);
  return u;
}

HarmonicField calc_harmonic_field(const TriMesh& muscle, const Attachments& areas,
                                  const HarmonicOptions& options) {
  // Options first, before the tetrahedralisation and the solves.
  if (options.pennation_rad > 0.0 && !(options.pennation_rad < 0.5 * M_PI))
    throw_usage("the pennation angle must be in (0, 90) degrees");
  if (options.fibre_length_m < 0.0) throw_usage("the fibre length must not be negative");
  if (!options.transverse_direction.allFinite())
    throw_usage("the transverse direction of the pennate field must be finite");
  if (!options.transverse_targets.allFinite())
    throw_usage("the pennate field's transverse targets must be finite");
  HarmonicField field;
  field.surface = muscle;
  field.tets = calc_tet_mesh(muscle, options.tets);
  std::vector<int> ones = areas.insertion.vertices;
  if (areas.insertion_interior.rows() > 0) {
    // Interior aponeurosis: tet vertices within 0.6 mean tet edges of its sample points (a layer
    // about one element thick, so the potential's level set u = 1 is a closed wall there).
    const detail::PointIndex sheet(areas.insertion_interior);
    const double reach = 0.6 * calc_mean_tet_edge(field.tets);
    std::vector<char> is_origin(field.tets.num_vertices(), 0);
    for (int v : areas.origin.vertices) is_origin[v] = 1;
    for (Eigen::Index v = 0; v < field.tets.num_vertices(); ++v)
      if (!is_origin[v] && sheet.find_nearest(field.tets.V.row(v)).second <= reach * reach)
        ones.push_back(static_cast<int>(v));
    std::sort(ones.begin(), ones.end());
    ones.erase(std::unique(ones.begin(), ones.end()), ones.end());
  }
  field.u = solve_laplace(field.tets, areas.origin.vertices, ones);
  calc_field_gradients(field.tets, field.u, field.tet_gradient, field.vertex_gradient);
  if (options.pennation_rad > 0.0) {
    // Laplace-Dirichlet rule-based directions (Bayer et al. 2012, Ann Biomed Eng 40:2243, for
    // myocardium): e_l = grad(u_along) / |.| follows the muscle from end to end, e_t = the part of
    // grad(u) normal to e_l points from the origin to the insertion aponeurosis; the fibre runs
    // at the pennation angle a between them: d = cos(a) e_l + sin(a) e_t.
    const Vec3 towards_origin = areas.origin.centroid - areas.insertion.centroid;
    const Attachments ends = find_end_attachments(muscle, options.end_fraction,
                                                  towards_origin.norm() > 0.0
                                                      ? Vec3(towards_origin.normalized())
                                                      : Vec3::UnitZ());
    field.u_along = solve_laplace(field.tets, ends.origin.vertices, ends.insertion.vertices,
                                  "the origin end region", "the insertion end region");
    Points3 tet_along, vertex_along;
    calc_field_gradients(field.tets, field.u_along, tet_along, vertex_along);
    const double ca_fixed = std::cos(options.pennation_rad);
    const double sa_fixed = std::sin(options.pennation_rad);
    const bool to_aponeurosis =
        options.pennation_reference == HarmonicOptions::PennationReference::aponeurosis;
    // Transmural direction for the aponeurosis reference: with both faces of a unipennate muscle
    // known, the gradient of their potential (0 on -x, 1 on +x; level sets parallel to both
    // aponeuroses, as the transmural potential of Bayer et al. 2012); otherwise grad(u).
    Points3 tet_across = field.tet_gradient, vertex_across = field.vertex_gradient;
    // The crossing potential for a local angle (fibre_length_m): the faces' potential when both
    // faces are known (unipennate), else u itself (0 on the faces, 1 on a central sheet).
    Points3 tet_crossing = field.tet_gradient, vertex_crossing = field.vertex_gradient;
    const bool faces_known = !areas.face_minus.empty() && !areas.face_plus.empty();
    if ((to_aponeurosis || options.fibre_length_m > 0.0) && faces_known) {
      const VecX u_t = solve_laplace(field.tets, areas.face_minus, areas.face_plus,
                                     "the -x aponeurosis face", "the +x aponeurosis face");
      calc_field_gradients(field.tets, u_t, tet_crossing, vertex_crossing);
      if (to_aponeurosis) {
        tet_across = tet_crossing;
        vertex_across = vertex_crossing;
      }
    }
    const bool fixed_plane = options.transverse_direction.norm() > 0.0;
    const Vec3 plane_dir =
        fixed_plane ? Vec3(options.transverse_direction.normalized()) : Vec3::Zero();
    // The transverse direction: grad(u) (or the faces' potential), or the given plane direction:
    // as given when both faces are known (unipennate areas: from the origin face towards the
    // insertion face everywhere), else signed the way grad(u) points (towards a central sheet
    // from either side).
    const bool targets = options.transverse_targets.rows() > 0;
    const auto target_index =
        targets ? std::make_unique<detail::PointIndex>(options.transverse_targets) : nullptr;
    const auto transverse = [&](const Vec3& g_across, const Vec3& g_u, const Vec3& p) -> Vec3 {
      if (targets)
        return Vec3(options.transverse_targets.row(target_index->find_nearest(p).first)) - p;
      if (!fixed_plane) return g_across;
      if (faces_known) return plane_dir;
      return g_u.dot(plane_dir) < 0.0 ? Vec3(-plane_dir) : plane_dir;
    };
    const auto blend = [&](Points3& out, const Points3& across, const Points3& along,
                           const Points3& crossing, const Points3& grad_u, const Points3& at) {
      for (Eigen::Index i = 0; i < out.rows(); ++i) {
        const Vec3 gl = along.row(i);
        const Vec3 gt = transverse(across.row(i), grad_u.row(i), at.row(i));
        double ca = ca_fixed, sa = sa_fixed;
        if (options.fibre_length_m > 0.0) {
          // Planimetric model with one fibre length L: a fibre crossing the local distance t
          // between its aponeuroses makes sin(a) = t / L; t = 1 / |grad of the crossing
          // potential| (exact between parallel faces).
          const double g = Vec3(crossing.row(i)).norm();
          if (g > 0.0) {
            sa = std::min(1.0, 1.0 / (g * options.fibre_length_m));
            ca = std::sqrt(std::max(0.0, 1.0 - sa * sa));
          }
        }
        if (to_aponeurosis) {
          // The angle to the level set of u: e_n = grad(u) / |.|, e_a = grad(u_along) within it.
          if (!(gt.norm() > 0.0)) continue;
          const Vec3 en = gt.normalized();
          const Vec3 a = gl - gl.dot(en) * en;
          const Vec3 d = a.norm() > 1e-6 * gl.norm() && a.norm() > 0.0
                             ? Vec3(ca * a.normalized() + sa * en)
                             : en;
          out.row(i) = d.transpose();
          continue;
        }
        if (!(gl.norm() > 0.0)) continue;  // keep the across direction
        const Vec3 el = gl.normalized();
        const Vec3 t = gt - gt.dot(el) * el;
        const Vec3 d = t.norm() > 1e-6 * gt.norm() && t.norm() > 0.0
                           ? Vec3(ca * el + sa * t.normalized())
                           : el;
        out.row(i) = d.transpose();
      }
    };
    const Points3 tet_u = field.tet_gradient, vertex_u = field.vertex_gradient;
    Points3 centroids = Points3::Zero(field.tets.num_tets(), 3);  // read by transverse() per row
    if (targets)
      for (Eigen::Index t = 0; t < field.tets.num_tets(); ++t)
        for (int k = 0; k < 4; ++k) centroids.row(t) += 0.25 * field.tets.V.row(field.tets.T(t, k));
    blend(field.tet_gradient, tet_across, tet_along, tet_crossing, tet_u, centroids);
    blend(field.vertex_gradient, vertex_across, vertex_along, vertex_crossing, vertex_u, field.tets.V);
  }
  return field;
}

namespace {

// Barycentric coordinates of p in tet t.
Vec4 calc_barycentric(const TetMesh& m, int t, const Vec3& p) {
  const Vec3 x0 = m.V.row(m.T(t, 0));
  Mat3 D;
  for (int k = 0; k < 3; ++k) D.col(k) = Vec3(m.V.row(m.T(t, k + 1))) - x0;
  const Vec3 l = D.partialPivLu().solve(p - x0);
  return {1.0 - l.sum(), l(0), l(1), l(2)};
}

struct Location {
  int tet = -1;           // containing tet, or -1 when p is outside the mesh
  int last_tet = -1;      // the tet where the walk stopped
  Vec4 bary = Vec4::Zero();
};

// Visibility walk from `start` towards p (Devillers, Pion and Teillaud 2002).
Location locate(const TetMesh& m, int start, const Vec3& p) {
  int t = start;
  const int max_steps = 2000;
  for (int step = 0; step < max_steps; ++step) {
    const Vec4 b = calc_barycentric(m, t, p);
    int worst = 0;
    for (int k = 1; k < 4; ++k)
      if (b(k) < b(worst)) worst = k;
    if (b(worst) >= -1e-12) return {t, t, b};
    const int next = m.neighbours(t, worst);
    if (next < 0) return {-1, t, b};
    t = next;
  }
  return {-1, t, Vec4::Zero()};
}

struct Tracer {
  const HarmonicField& f;
  double h;
  int max_steps;
  double u_stop;  // a fibre ends where the potential reaches this value
  bool end_on_boundary;  // a fibre ends where it first leaves the mesh (else it slides on)
  double direction = 1.0;  // +1: towards the insertion (u increasing); -1: back to the origin

  // The potential measured in the tracing direction: u forwards, 1 - u backwards.
  double progress(double u) const { return direction > 0.0 ? u : 1.0 - u; }

  Vec3 velocity(const Location& loc) const {
    Vec3 g = Vec3::Zero();
    for (int k = 0; k < 4; ++k) g += loc.bary(k) * f.vertex_gradient.row(f.tets.T(loc.tet, k)).transpose();
    const double n = g.norm();
    if (n > 0.0) return direction * g / n;
    const Vec3 gt = f.tet_gradient.row(loc.tet);
    return gt.norm() > 0.0 ? Vec3(direction * gt.normalized()) : Vec3::Zero();
  }
  double potential(const Location& loc) const {
    double u = 0.0;
    for (int k = 0; k < 4; ++k) u += loc.bary(k) * f.u(f.tets.T(loc.tet, k));
    return u;
  }

  // Last inside point on the segment a (inside, in tet ta) -> b (outside), by bisection.
  std::pair<Vec3, Location> find_exit(const Vec3& a, const Location& la, const Vec3& b) const {
    double lo = 0.0, hi = 1.0;
    Location best = la;
    for (int it = 0; it < 40; ++it) {
      const double mid = 0.5 * (lo + hi);
      const Location l = locate(f.tets, best.tet, a + mid * (b - a));
      if (l.tet >= 0) {
        lo = mid;
        best = l;
      } else {
        hi = mid;
      }
    }
    return {a + lo * (b - a), best};
  }

  // `reached` (optional): set to whether the fibre ended on its target (the area's value or, with
  // end_on_boundary, the surface past the middle of the potential) rather than by running out of
  // steps or slides.
  Points3 trace(const Vec3& seed, int seed_tet, bool* reached = nullptr) const {
    if (reached) *reached = false;
    std::vector<Vec3> pts{seed};
    Location loc = locate(f.tets, seed_tet, seed);
    if (loc.tet < 0) return Points3();
    Vec3 p = seed;
    int slides = 0;
    // Surface areas (plain fields): a fibre ends on the surface only on a face of the area itself
    // (all three vertices at the end value); elsewhere it slides on towards the area.
    const bool strict = !end_on_boundary && u_stop > 0.999;
    bool stopped_inside = false;
    for (int step = 0; step < max_steps; ++step) {
      if (progress(potential(loc)) >= u_stop) {
        stopped_inside = true;
        if (reached) *reached = true;
        break;
      }
      // RK4 on the unit direction field; stages that leave the mesh fall back to an Euler step.
      const Vec3 k1 = velocity(loc);
      if (k1.squaredNorm() == 0.0) break;
      Vec3 next = p + h * k1;
      bool rk4 = true;
      Vec3 k2, k3, k4;
      const Location l2 = locate(f.tets, loc.tet, p + 0.5 * h * k1);
      if (l2.tet >= 0) {
        k2 = velocity(l2);
        const Location l3 = locate(f.tets, l2.tet, p + 0.5 * h * k2);
        if (l3.tet >= 0) {
          k3 = velocity(l3);
          const Location l4 = locate(f.tets, l3.tet, p + h * k3);
          if (l4.tet >= 0) {
            k4 = velocity(l4);
          } else {
            rk4 = false;
          }
        } else {
          rk4 = false;
        }
      } else {
        rk4 = false;
      }
      if (rk4) next = p + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4);
      const Location ln = locate(f.tets, loc.tet, next);
      if (ln.tet >= 0) {
        p = next;
        loc = ln;
        pts.push_back(p);
        continue;
      }
      // The step leaves the muscle. On the insertion area (u near 1) the fibre ends there;
      // elsewhere (a zero-flux side, left by interpolation error) it slides along the boundary.
      auto [exit, lexit] = find_exit(p, loc, next);
      if ((exit - p).norm() > 1e-3 * h) pts.push_back(exit);
      // A pennate fibre that reaches the surface past the middle of the potential has crossed
      // to the insertion side and ends there.
      const double u_exit = progress(potential(lexit));
      const Location out = locate(f.tets, lexit.tet, next);
      int face = 0;
      for (int k = 1; k < 4; ++k)
        if (out.bary(k) < out.bary(face)) face = k;
      const int bt = out.last_tet;
      bool on_area = u_exit >= std::min(u_stop, 0.999);
      if (strict && on_area)
        for (int k = 1; k < 4; ++k)
          on_area = on_area && progress(f.u(f.tets.T(bt, (face + k) % 4))) >= 1.0 - 1e-9;
      if ((end_on_boundary && u_exit >= 0.5) || on_area) {
        if (reached) *reached = true;
        break;
      }
      if (++slides > max_steps / 2) break;
      const Vec3 a = f.tets.V.row(f.tets.T(bt, (face + 1) % 4));
      const Vec3 b = f.tets.V.row(f.tets.T(bt, (face + 2) % 4));
      const Vec3 c = f.tets.V.row(f.tets.T(bt, (face + 3) % 4));
      Vec3 normal = (b - a).cross(c - a).normalized();
      if (normal.dot(Vec3(f.tets.V.row(f.tets.T(bt, face))) - a) > 0) normal = -normal;  // outward
      const Vec3 along = (next - exit) - (next - exit).dot(normal) * normal;
      Vec3 slid = exit + along - 0.02 * h * normal;
      Location ls = locate(f.tets, lexit.tet, slid);
      if (ls.tet < 0) {
        slid = exit - 0.02 * h * normal;
        ls = locate(f.tets, lexit.tet, slid);
      }
      if (ls.tet < 0) break;
      p = slid;
      loc = ls;
      pts.push_back(p);
    }
    if (strict && stopped_inside && pts.size() >= 2) {
      // Stopped where u reached its end value inside the mesh (tets with all four vertices on
      // the area, at thin tips): go on straight to the surface, which is the area there.
      const Vec3 dir = (pts.back() - pts[pts.size() - 2]).normalized();
      for (int step = 0; step < 200 && dir.allFinite(); ++step) {
        const Vec3 next = p + h * dir;
        const Location ln = locate(f.tets, loc.tet, next);
        if (ln.tet < 0) {
          pts.push_back(find_exit(p, loc, next).first);
          break;
        }
        p = next;
        loc = ln;
        pts.push_back(p);
      }
    }
    Points3 P(pts.size(), 3);
    for (std::size_t k = 0; k < pts.size(); ++k) P.row(k) = pts[k].transpose();
    return P;
  }
};


}  // namespace

namespace {

// Pieces of the level set u = level: per tet straddling it, the cut triangle (or the quad's two
// triangles), tagged with the tet; weight = area (by_flux: area x |grad u|, the flux through it).
std::vector<detail::WeightedTriangle> calc_level_set_pieces(const HarmonicField& field,
                                                            double level, bool by_flux) {
  const TetMesh& m = field.tets;
  std::vector<detail::WeightedTriangle> pieces;
  for (Eigen::Index t = 0; t < m.num_tets(); ++t) {
    std::array<int, 4> below{}, above{};
    int nb = 0, na = 0;
    for (int k = 0; k < 4; ++k) {
      if (field.u(m.T(t, k)) < level) below[nb++] = m.T(t, k);
      else above[na++] = m.T(t, k);
    }
    if (nb == 0 || na == 0) continue;
    const auto cut = [&](int va, int vb) {
      const double ua = field.u(va), ub = field.u(vb);
      const double w = std::clamp((level - ua) / (ub - ua), 0.0, 1.0);
      return Vec3((1.0 - w) * m.V.row(va) + w * m.V.row(vb));
    };
    std::vector<std::array<Vec3, 3>> tris;
    if (nb == 1 || na == 1) {
      const int lone = nb == 1 ? below[0] : above[0];
      const std::array<int, 4>& others = nb == 1 ? above : below;
      tris.push_back({cut(lone, others[0]), cut(lone, others[1]), cut(lone, others[2])});
    } else {
      const Vec3 p0 = cut(below[0], above[0]), p1 = cut(below[0], above[1]),
                 p2 = cut(below[1], above[1]), p3 = cut(below[1], above[0]);
      tris.push_back({p0, p1, p2});
      tris.push_back({p0, p2, p3});
    }
    const double scale = by_flux ? Vec3(field.tet_gradient.row(t)).norm() : 1.0;
    for (const auto& c : tris) {
      detail::WeightedTriangle piece;
      piece.corner = c;
      piece.weight = scale * 0.5 * (c[1] - c[0]).cross(c[2] - c[0]).norm();
      piece.tag = static_cast<int>(t);
      pieces.push_back(piece);
    }
  }
  return pieces;
}

using FaceKeys = std::vector<std::pair<std::array<int, 3>, int>>;

// Boundary faces of the tet mesh (sorted vertex triples) with their tets, sorted.
FaceKeys calc_boundary_faces(const TetMesh& m) {
  FaceKeys boundary;
  for (Eigen::Index t = 0; t < m.num_tets(); ++t)
    for (int c = 0; c < 4; ++c)
      if (m.neighbours(t, c) < 0) {
        std::array<int, 3> k{m.T(t, (c + 1) % 4), m.T(t, (c + 2) % 4), m.T(t, (c + 3) % 4)};
        std::sort(k.begin(), k.end());
        boundary.emplace_back(k, static_cast<int>(t));
      }
  std::sort(boundary.begin(), boundary.end());
  return boundary;
}

// The tet behind surface triangle f, or -1.
int find_boundary_tet(const FaceKeys& boundary, const TriMesh& S, int f) {
  std::array<int, 3> key{S.F(f, 0), S.F(f, 1), S.F(f, 2)};
  std::sort(key.begin(), key.end());
  const auto it = std::lower_bound(
      boundary.begin(), boundary.end(), key,
      [](const std::pair<std::array<int, 3>, int>& e, const std::array<int, 3>& k2) {
        return e.first < k2;
      });
  return it == boundary.end() || it->first != key ? -1 : it->second;
}

}  // namespace

namespace {

// `count` columns of X (candidates as columns) in farthest-point order: the first the one nearest
// the mean of `first`, each next the candidate farthest from those chosen; `first` before
// `second` (second is used only when first has fewer than count). Returns the chosen columns
// sorted by index (the seeds' stratified order).
std::vector<int> select_farthest(const Eigen::MatrixXd& X, const std::vector<int>& first,
                                 const std::vector<int>& second, int count) {
  std::vector<int> chosen;
  VecX d2 = VecX::Constant(X.cols(), std::numeric_limits<double>::infinity());
  for (const std::vector<int>* tier : {&first, &second}) {
    if (tier->empty()) continue;
    if (chosen.empty()) {
      VecX mean = VecX::Zero(X.rows());
      for (int i : *tier) mean += X.col(i);
      mean /= static_cast<double>(tier->size());
      int pick = tier->front();
      double best = std::numeric_limits<double>::infinity();
      for (int i : *tier)
        if (const double d = (X.col(i) - mean).squaredNorm(); d < best) {
          best = d;
          pick = i;
        }
      chosen.push_back(pick);
      for (int i = 0; i < X.cols(); ++i) d2(i) = (X.col(i) - X.col(pick)).squaredNorm();
    }
    std::vector<char> taken(X.cols(), 0);
    for (int c : chosen) taken[c] = 1;
    while (static_cast<int>(chosen.size()) < count) {
      int pick = -1;
      double best = -1.0;
      for (int i : *tier)
        if (!taken[i] && d2(i) > best) {
          best = d2(i);
          pick = i;
        }
      if (pick < 0) break;
      chosen.push_back(pick);
      taken[pick] = 1;
      for (int i = 0; i < X.cols(); ++i)
        d2(i) = std::min(d2(i), (X.col(i) - X.col(pick)).squaredNorm());
    }
    if (static_cast<int>(chosen.size()) >= count) break;
  }
  std::sort(chosen.begin(), chosen.end());
  return chosen;
}

}  // namespace

FibreSet trace_harmonic_fibres(const HarmonicField& field, const AttachmentArea& origin,
                               const TraceOptions& options, const AttachmentArea* insertion) {
  if (options.count < 1 || options.resolution < 2)
    throw_usage("fibre count must be >= 1 and resolution >= 2");
  if (origin.triangles.empty())
    throw_bad_input("the origin area has no triangle to seed fibres on", {.object = origin.name});
  const TetMesh& m = field.tets;
  const double edge = calc_mean_tet_edge(m);
  const double diag = (m.V.colwise().maxCoeff() - m.V.colwise().minCoeff()).norm();
  const Tracer forward{field, options.step_scale * edge,
                       static_cast<int>(4.0 * diag / (options.step_scale * edge)) + 10,
                       options.stop_potential, options.end_on_boundary, 1.0};
  Tracer backward = forward;
  backward.direction = -1.0;
  FibreSet set;
  set.fibres.resize(options.count);
  std::vector<char> ok(options.count, 0);
  // Traces both ways from an interior seed: origin end first (the backward trace reversed),
  // resampled; empty when a trace fails. `reached`: both ends on their targets.
  const auto join_both_ways = [&](const Vec3& seed, int tet, bool* reached) {
    bool to_end = false, to_start = false;
    const Points3 to_insertion = forward.trace(seed, tet, &to_end);
    const Points3 to_origin = backward.trace(seed, tet, &to_start);
    if (reached) *reached = to_end && to_start;
    if (to_insertion.rows() < 2 || to_origin.rows() < 2) return Points3();
    Points3 full(to_origin.rows() + to_insertion.rows() - 1, 3);
    full.topRows(to_origin.rows()) = to_origin.colwise().reverse();
    full.bottomRows(to_insertion.rows() - 1) = to_insertion.bottomRows(to_insertion.rows() - 1);
    return resample_polyline(full, options.resolution);
  };
  const auto trace_both_ways = [&](std::size_t i, const Vec3& seed, int tet) {
    Points3 P = join_both_ways(seed, tet, nullptr);
    if (P.rows() < 2) return;
    set.fibres[i] = std::move(P);
    ok[i] = 1;
  };
  // Traces from `per_area` stratified seeds on each area's surface to the other area, every fibre
  // running origin -> insertion: the origin's fibres go to out[first + j], the insertion's to
  // out[first + per_area + j]; flag[.] is 1 when the trace reached its target (always, when
  // `any_end`). Seeds whose surface triangle has no tet behind it, or failed traces, leave their
  // slot untouched.
  const auto trace_from_areas = [&](int per_area, std::size_t first, std::vector<Points3>& out,
                                    std::vector<char>& flag, bool any_end) {
    const FaceKeys boundary = calc_boundary_faces(m);
    const TriMesh& S = field.surface;
    for (const bool at_origin : {true, false}) {
      const AttachmentArea& area = at_origin ? origin : *insertion;
      const std::vector<detail::WeightedTriangle> tris =
          detail::make_area_weighted(S.V, S.F, area.triangles);
      const std::vector<detail::TriangleSample> area_seeds = detail::sample_triangles(tris, per_area);
      const std::size_t base = first + (at_origin ? 0 : static_cast<std::size_t>(per_area));
      parallel_for(area_seeds.size(), [&](std::size_t j) {
        const detail::WeightedTriangle& tri = tris[area_seeds[j].piece];
        const int tet = find_boundary_tet(boundary, S, tri.tag);
        if (tet < 0) return;
        const Vec3 inward =
            -(tri.corner[1] - tri.corner[0]).cross(tri.corner[2] - tri.corner[0]).normalized();
        const Vec3 p_surface = area_seeds[j].point;
        bool r = false;
        const Points3 P =
            (at_origin ? forward : backward).trace(p_surface + 1e-3 * edge * inward, tet, &r);
        if (P.rows() < 2) return;
        Points3 full(P.rows() + 1, 3);
        full.row(0) = p_surface.transpose();
        full.bottomRows(P.rows()) = P;
        if (!at_origin) full = full.colwise().reverse().eval();
        out[base + j] = resample_polyline(full, options.resolution);
        flag[base + j] = any_end || r;
      });
    }
  };
  if (options.seeding == TraceOptions::Seeding::volume && options.candidate_factor > 1) {
    // Oversampled volume seeds, every candidate traced; the fibres are chosen by farthest-point
    // order of their shapes (docs/fibres.md), candidates with both ends on their areas and
    // without a kink first.
    const int n = options.count;
    const std::vector<detail::TetSample> seeds =
        detail::sample_tets(m.V, m.T, n * options.candidate_factor);
    // Optional area candidates: seeds on each area's surface (stratified), traced to the other.
    const int per_area = insertion && !insertion->triangles.empty()
                             ? std::max(0, options.area_candidate_factor) * n
                             : 0;
    const std::size_t nv = seeds.size();
    std::vector<Points3> cand(nv + 2 * static_cast<std::size_t>(per_area));
    std::vector<char> reached(cand.size(), 0);
    parallel_for(nv, [&](std::size_t i) {
      bool r = false;
      cand[i] = join_both_ways(seeds[i].point, seeds[i].tet, &r);
      reached[i] = r;
    });
    if (per_area > 0) trace_from_areas(per_area, nv, cand, reached, false);
    constexpr int kShapePoints = 5;
    Eigen::MatrixXd shape(3 * kShapePoints, static_cast<Eigen::Index>(cand.size()));
    std::vector<int> first_tier, second_tier;
    for (std::size_t i = 0; i < cand.size(); ++i) {
      if (cand[i].rows() < 2) continue;
      const Points3 Q = resample_polyline(cand[i], kShapePoints);
      for (int k = 0; k < kShapePoints; ++k) shape.block<3, 1>(3 * k, i) = Q.row(k).transpose();
      // First tier: both ends on their targets and no kink (a turn over 45 degrees between
      // neighbouring segments is a trace that slid along the surface or doubled back).
      double max_turn_cos = 1.0;
      for (Eigen::Index k = 1; k + 1 < cand[i].rows(); ++k) {
        const Vec3 a = cand[i].row(k) - cand[i].row(k - 1), b = cand[i].row(k + 1) - cand[i].row(k);
        if (a.norm() > 0.0 && b.norm() > 0.0)
          max_turn_cos = std::min(max_turn_cos, a.normalized().dot(b.normalized()));
      }
      const bool smooth = max_turn_cos > std::cos(M_PI / 4);
      (reached[i] && smooth ? first_tier : second_tier).push_back(static_cast<int>(i));
    }
    const std::vector<int> chosen = select_farthest(shape, first_tier, second_tier, n);
    for (std::size_t j = 0; j < chosen.size(); ++j) {
      set.fibres[j] = std::move(cand[chosen[j]]);
      ok[j] = 1;
    }
  } else if (options.seeding == TraceOptions::Seeding::volume) {
    // Optionally a share of the fibres starts on the areas (stratified over each), so that the
    // ends also reach the parts of the areas the flux hardly feeds.
    const int per_area =
        insertion && !insertion->triangles.empty()
            ? std::clamp(static_cast<int>(std::lround(0.5 * options.area_seed_fraction * options.count)),
                         0, options.count / 2)
            : 0;
    const int n_volume = options.count - 2 * per_area;
    const std::vector<detail::TetSample> seeds = detail::sample_tets(m.V, m.T, n_volume);
    parallel_for(seeds.size(),
                 [&](std::size_t i) { trace_both_ways(i, seeds[i].point, seeds[i].tet); });
    if (per_area > 0)
      trace_from_areas(per_area, static_cast<std::size_t>(n_volume), set.fibres, ok, true);
  } else if (options.seeding == TraceOptions::Seeding::level_set) {
    if (!(options.seed_level > 0.0 && options.seed_level < 1.0))
      throw_usage("the seed level of the harmonic potential must be in (0, 1)");
    const std::vector<detail::WeightedTriangle> pieces =
        calc_level_set_pieces(field, options.seed_level, options.seed_by_flux);
    const std::vector<detail::TriangleSample> seeds = detail::sample_triangles(pieces, options.count);
    if (seeds.empty())
      throw_numerical("the harmonic potential has no level set to seed fibres on",
                      {.suggestion = "check the attachment areas and that the mesh is closed"});
    parallel_for(seeds.size(), [&](std::size_t i) {
      trace_both_ways(i, seeds[i].point, pieces[seeds[i].piece].tag);
    });
  } else {
    // The tet behind each origin triangle (its boundary face), found through the face keys.
    const FaceKeys boundary = calc_boundary_faces(m);
    // Seeds: area-weighted R2 samples over the origin triangles in their mesh order (unchanged
    // since the pennate fields' validation; the stratified rule of sampling.hpp moves the VH TA's
    // pennate-field mean length from 0.83 to 0.74 of Ward's).
    const TriMesh& S = field.surface;
    std::vector<double> cumulative;
    double total = 0.0;
    for (int f : origin.triangles) {
      const Vec3 a = S.V.row(S.F(f, 0)), b = S.V.row(S.F(f, 1)), c = S.V.row(S.F(f, 2));
      total += 0.5 * (b - a).cross(c - a).norm();
      cumulative.push_back(total);
    }
    if (!(total > 0.0)) throw_bad_input("the origin area has zero area", {.object = origin.name});
    parallel_for(static_cast<std::size_t>(options.count), [&](std::size_t i) {
      const Vec2 r = get_r2_point(static_cast<int>(i));
      const double target = r.x() * total;
      const auto [k, s] = detail::pick_cumulative(cumulative, target);
      const int f = origin.triangles[k];
      const Vec3 a = S.V.row(S.F(f, 0)), b = S.V.row(S.F(f, 1)), c = S.V.row(S.F(f, 2));
      const double q = std::sqrt(s);
      const Vec3 p_surface = (1.0 - q) * a + q * (1.0 - r.y()) * b + q * r.y() * c;
      const int tet = find_boundary_tet(boundary, S, f);
      if (tet < 0) return;  // not a boundary face (cannot happen with -Y)
      // Start just inside, along the inward normal of the surface triangle.
      const Vec3 inward = -(b - a).cross(c - a).normalized();
      const Vec3 seed = p_surface + 1e-3 * edge * inward;
      Points3 P = forward.trace(seed, tet);
      if (P.rows() < 2) return;
      // Begin exactly on the surface.
      Points3 full(P.rows() + 1, 3);
      full.row(0) = p_surface.transpose();
      full.bottomRows(P.rows()) = P;
      set.fibres[i] = resample_polyline(full, options.resolution);
      ok[i] = 1;
    });
  }
  // Drop seeds that failed to trace (a degenerate start): keep the order of the rest.
  FibreSet out;
  for (int i = 0; i < options.count; ++i)
    if (ok[i]) out.fibres.push_back(std::move(set.fibres[i]));
  if (out.fibres.empty())
    throw_numerical("no fibre could be traced in the harmonic field",
                    {.suggestion = "check the attachment areas and that the mesh is closed"});
  return out;
}

}  // namespace fascicle
