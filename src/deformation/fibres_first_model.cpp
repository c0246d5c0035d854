// Fibres-first model: particles along the rest fibres, the spring network, bone attachments and
// the display surface (see fibres_first.hpp and docs/representations.md).
#include "fascicle/deformation/fibres_first.hpp"
#include "point_tree.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/deformation/mesh_operators.hpp"
#include "fascicle/geometry/slicing.hpp"

#include <Eigen/Eigenvalues>


#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include <map>
#include <numeric>
#include <set>
#include <utility>

namespace fascicle {

namespace {

ErrorContext muscle_context(const std::string& name, std::string suggestion = {}) {
  return {.object = name, .suggestion = std::move(suggestion)};
}

// `count` points equally spaced in arc length along a polyline (ends kept).
Points3 resample_uniform(const Points3& line, int count) {
  const Eigen::Index n = line.rows();
  VecX s(n);
  s[0] = 0.0;
  for (Eigen::Index i = 1; i < n; ++i) s[i] = s[i - 1] + (line.row(i) - line.row(i - 1)).norm();
  Points3 out(count, 3);
  Eigen::Index seg = 0;
  for (int k = 0; k < count; ++k) {
    const double target = s[n - 1] * k / (count - 1);
    while (seg + 2 < n && s[seg + 1] < target) ++seg;
    const double len = s[seg + 1] - s[seg];
    const double u = len > 0.0 ? std::clamp((target - s[seg]) / len, 0.0, 1.0) : 0.0;
    out.row(k) = (1.0 - u) * line.row(seg) + u * line.row(seg + 1);
  }
  out.row(0) = line.row(0);
  out.row(count - 1) = line.row(n - 1);
  return out;
}

using detail::PointCloud;
using detail::PointTree;

// Symmetrised k-nearest-neighbour graph of the fibres, measured between their middle particles
// (the rest cross-section). Returns unordered pairs (f < g).
std::vector<std::pair<int, int>> calc_fibre_neighbours(const Points3& mid, int k) {
  const int n = static_cast<int>(mid.rows());
  std::set<std::pair<int, int>> pairs;
  if (n < 2 || k < 1) return {};
  const PointCloud cloud{mid};
  PointTree tree(3, cloud, nanoflann::KDTreeSingleIndexAdaptorParams(10));
  tree.buildIndex();
  const std::size_t want = static_cast<std::size_t>(std::min(k + 1, n));
  std::vector<std::size_t> idx(want);
  std::vector<double> d2(want);
  for (int f = 0; f < n; ++f) {
    const Vec3 q = mid.row(f);
    const std::size_t found = tree.knnSearch(q.data(), want, idx.data(), d2.data());
    for (std::size_t j = 0; j < found; ++j) {
      const int g = static_cast<int>(idx[j]);
      if (g != f) pairs.emplace(std::min(f, g), std::max(f, g));
    }
  }
  return {pairs.begin(), pairs.end()};
}

// Convex hull of 2-D points (Andrew's monotone chain), counter-clockwise, keeping points on its
// edges (the boundary fibres of a grid include its sides). Empty when the points span no area.
std::vector<int> calc_convex_hull(const std::vector<Vec2>& p) {
  std::vector<int> order(p.size());
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](int a, int b) {
    return p[a].x() < p[b].x() || (p[a].x() == p[b].x() && p[a].y() < p[b].y());
  });
  if (order.size() < 3) return {};
  auto cross = [&](int o, int a, int b) {
    return (p[a] - p[o]).x() * (p[b] - p[o]).y() - (p[a] - p[o]).y() * (p[b] - p[o]).x();
  };
  // area test first: collinear input would make both chains contain every point
  double extent = 0.0, twice_area = 0.0;
  for (int i : order) extent = std::max(extent, (p[i] - p[order[0]]).norm());
  for (int i : order) twice_area = std::max(twice_area, std::abs(cross(order[0], order.back(), i)));
  if (!(twice_area > 1e-9 * extent * extent)) return {};
  std::vector<int> hull(2 * order.size());
  std::size_t k = 0;
  for (int i : order) {
    while (k >= 2 && cross(hull[k - 2], hull[k - 1], i) < 0.0) --k;
    hull[k++] = i;
  }
  for (std::size_t j = order.size() - 1, t = k + 1; j-- > 0;) {
    const int i = order[j];
    while (k >= t && cross(hull[k - 2], hull[k - 1], i) < 0.0) --k;
    hull[k++] = i;
  }
  hull.resize(k - 1);
  return hull;
}

void check_options(const FibresFirstOptions& o) {
  auto positive = [](double v) { return std::isfinite(v) && v > 0.0; };
  if (!positive(o.along_stiffness) || !positive(o.across_stiffness))
    throw_bad_input(fmt::format("spring stiffness must be > 0 N/m (along {}, across {})",
                            o.along_stiffness, o.across_stiffness),
                {.suggestion = "set along_stiffness and across_stiffness to positive values"});
  if (!(o.bending_stiffness >= 0.0) || !std::isfinite(o.bending_stiffness))
    throw_bad_input(fmt::format("bending stiffness must be >= 0 N/m (got {})", o.bending_stiffness));
  if (o.particles_per_fibre < 2 || o.cross_neighbours < 0 || o.max_iterations < 1 ||
      o.max_contact_rounds < 1 || o.max_volume_iterations < 0 || o.anderson_window < 0 ||
      o.surface_rings < 2 || o.surface_ring_points < 3)
    throw_bad_input("invalid fibres-first options (particles_per_fibre >= 2, cross_neighbours >= 0, "
                "max_iterations >= 1, max_contact_rounds >= 1, max_volume_iterations >= 0, "
                "anderson_window >= 0, surface_rings >= 2, surface_ring_points >= 3)");
  if (!positive(o.density_kg_per_m3) || !positive(o.contact_weight) || !positive(o.step_tolerance) ||
      !positive(o.volume_tolerance) || !positive(o.max_volume_error) ||
      !positive(o.default_time_step_s) || !(o.damping_per_s >= 0.0) || !(o.bone_margin_m >= 0.0) ||
      !(o.muscle_margin_m >= 0.0) || !(o.muscle_contact_band >= 0.0) || !(o.pair_list_skin_m >= 0.0) || !(o.end_attachment_distance_m >= 0.0) ||
      !(o.bone_attachment_distance_m >= 0.0) || !(std::abs(o.blend_a) <= 1.0) ||
      !(o.surface_margin_m >= 0.0) ||
      !(o.surface_rest_overlap_resolved_m >= 0.0) || !positive(o.surface_stiffness) ||
      o.surface_anchor_count < 1 || !(o.surface_frame_stiffness >= 0.0) ||
      !std::isfinite(o.surface_frame_stiffness))
    throw_bad_input("invalid fibres-first options (density, weights, tolerances and time step must be "
                "> 0; damping, margins, distances and surface_frame_stiffness >= 0; |blend_a| <= 1)");
}


// Surface vertices from particle positions x (all particles of the model): v = sum_k w_k x_k.
Points3 gather_surface_vertices(const FibreBundle& m, const Points3& x) {
  const int nv = m.num_surface_vertices();
  Points3 S = Points3::Zero(nv, 3);
  for (int v = 0; v < nv; ++v)
    for (int k = m.surface_weight_start[v]; k < m.surface_weight_start[v + 1]; ++k)
      S.row(v) += m.surface_weight[k] * x.row(m.surface_weight_particle[k]);
  return S;
}

// Orients the triangles outward (positive enclosed volume) and sets the rest volume.
void set_rest_volume(FibreBundle& m, const Points3& rest) {
  const Points3 S = gather_surface_vertices(m, rest);
  const Vec3 centre = S.colwise().mean().transpose();
  double volume = calc_enclosed_volume(S, m.surface_triangles, centre);
  if (volume < 0.0) {
    m.surface_triangles.col(1).swap(m.surface_triangles.col(2));
    volume = -volume;
  }
  m.rest_volume_m3 = volume;
}

// Triangles of a closed tube of `rings` x `per_ring` vertices (vertex (r, k) at row
// r * per_ring + k; the rings run along the tube, k around it) with two fan caps to the
// vertices rings * per_ring (first ring) and rings * per_ring + 1 (last ring).
Triangles calc_tube_triangles(int rings, int per_ring) {
  std::vector<Eigen::Vector3i> tris;
  const int cap0 = rings * per_ring, cap1 = cap0 + 1;
  for (int k = 0; k < per_ring; ++k) {
    const int k1 = (k + 1) % per_ring;
    for (int r = 0; r + 1 < rings; ++r) {
      const int a = r * per_ring + k, b = r * per_ring + k1, c = (r + 1) * per_ring + k1,
                d = (r + 1) * per_ring + k;
      tris.emplace_back(a, b, c);
      tris.emplace_back(a, c, d);
    }
    tris.emplace_back(cap0, k1, k);
    tris.emplace_back(cap1, (rings - 1) * per_ring + k, (rings - 1) * per_ring + k1);
  }
  Triangles T(static_cast<Eigen::Index>(tris.size()), 3);
  for (std::size_t t = 0; t < tris.size(); ++t) T.row(static_cast<Eigen::Index>(t)) = tris[t].transpose();
  return T;
}

// Appends the weights of one vertex; cap centres are the mean of a ring's vertices.
void add_cap_centre(FibreBundle& m, int first_vertex, int count) {
  std::vector<std::pair<int, double>> w;
  for (int v = first_vertex; v < first_vertex + count; ++v)
    for (int k = m.surface_weight_start[v]; k < m.surface_weight_start[v + 1]; ++k)
      w.emplace_back(m.surface_weight_particle[k], m.surface_weight[k] / count);
  std::sort(w.begin(), w.end());
  for (std::size_t j = 0; j < w.size(); ++j) {
    if (j > 0 && w[j].first == w[j - 1].first) {
      m.surface_weight.back() += w[j].second;
      continue;
    }
    m.surface_weight_particle.push_back(w[j].first);
    m.surface_weight.push_back(w[j].second);
  }
  m.surface_weight_start.push_back(static_cast<int>(m.surface_weight.size()));
}

// Tube display surface: the boundary fibres' particles (fibre-major in the triangles' ring order:
// ring = fibre position i, around = boundary fibre) closed by two fans.
void build_tube_surface(FibreBundle& m, const Points3& rest, int P, bool need_volume) {
  const int nb = static_cast<int>(m.boundary_fibres.size());
  if (nb < 3) {
    if (need_volume)
      throw_bad_input(fmt::format("muscle '{}' has fewer than 3 fibres off one line in its rest "
                                  "cross-section; its volume is undefined", m.name),
                      muscle_context(m.name, "give more fibres, or set hold_volume = false"));
    return;
  }
  m.surface_weight_start = {0};
  for (int i = 0; i < P; ++i)
    for (int k = 0; k < nb; ++k) {
      m.surface_weight_particle.push_back(m.first_particle + m.boundary_fibres[k] * P + i);
      m.surface_weight.push_back(1.0);
      m.surface_weight_start.push_back(static_cast<int>(m.surface_weight.size()));
    }
  add_cap_centre(m, 0, nb);
  add_cap_centre(m, (P - 1) * nb, nb);
  m.surface_triangles = calc_tube_triangles(P, nb);
  set_rest_volume(m, rest);
}

// The minimum-norm weights (scaled by 1/omega_k) that reproduce affine maps: sum_k lambda_k = 1
// and sum_k lambda_k x_k = p, minimising sum_k lambda_k^2 / omega_k. Empty when the points do
// not span 3-D.
std::vector<double> calc_affine_weights(const std::vector<Vec3>& x, const std::vector<double>& omega,
                                        const Vec3& p) {
  const int n = static_cast<int>(x.size());
  Eigen::MatrixXd A(4, n);
  for (int k = 0; k < n; ++k) A.col(k) << x[k] - p, 1.0;  // relative to p: better conditioned
  Eigen::MatrixXd AD = A;
  for (int k = 0; k < n; ++k) AD.col(k) *= omega[k];
  const Eigen::Matrix4d G = AD * A.transpose();
  const Eigen::LDLT<Eigen::Matrix4d> ldlt(G);
  const Eigen::Vector4d mu = ldlt.solve(Eigen::Vector4d(0, 0, 0, 1));
  const Eigen::VectorXd lambda = AD.transpose() * mu;
  if (!lambda.allFinite() || (A * lambda - Eigen::Vector4d(0, 0, 0, 1)).norm() > 1e-9) return {};
  return {lambda.data(), lambda.data() + n};
}

// Triangulation of a simple counter-clockwise polygon by ear clipping (Meisters 1975): triangles
// (indices into p) counter-clockwise; empty when no ear is found (a degenerate polygon).
std::vector<Eigen::Vector3i> calc_ear_triangles(const std::vector<Vec2>& p) {
  auto cross = [](const Vec2& a, const Vec2& b, const Vec2& c) {
    return (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
  };
  std::vector<int> left(p.size());
  std::iota(left.begin(), left.end(), 0);
  std::vector<Eigen::Vector3i> out;
  while (left.size() > 3) {
    const std::size_t n = left.size();
    bool clipped = false;
    for (std::size_t k = 0; k < n && !clipped; ++k) {
      const int a = left[(k + n - 1) % n], b = left[k], c = left[(k + 1) % n];
      if (!(cross(p[a], p[b], p[c]) > 0.0)) continue;  // reflex or flat corner
      bool empty = true;
      for (int q : left)
        if (q != a && q != b && q != c && cross(p[a], p[b], p[q]) >= 0.0 &&
            cross(p[b], p[c], p[q]) >= 0.0 && cross(p[c], p[a], p[q]) >= 0.0)
          empty = false;
      if (!empty) continue;
      out.emplace_back(a, b, c);
      left.erase(left.begin() + static_cast<std::ptrdiff_t>(k));
      clipped = true;
    }
    if (!clipped) return {};
  }
  out.emplace_back(left[0], left[1], left[2]);
  return out;
}

// Loft display surface from the spec's rest surface (see FibreBundleSpec::rest_surface): slices
// normal to the surface's principal axis at `rings` levels between 3 % and 97 % of its extent,
// the largest closed contour of each resampled to `per_ring` points equally spaced in arc length
// (counter-clockwise about the axis, starting at the point farthest along a fixed normal
// direction), the two end rings closed by ear-clipped caps (a fan would fold over a concave
// ring). Each vertex is carried by the particles of its
// nearest particle's fibre and of that fibre's cross neighbours, at the fibre positions i-1, i,
// i+1, with calc_affine_weights (omega = 1/(d^2 + s^2), s the mean spring length): a rigid or
// affine motion of those particles moves the vertex the same way. Returns false (nothing set) when
// a slice has no closed contour or a vertex gets no weights.
bool build_loft_surface(FibreBundle& m, const TriMesh& surface, const Points3& rest, int P,
                        const std::vector<std::vector<int>>& neighbours, int rings, int per_ring) {
  if (surface.F.rows() < 4 || surface.V.rows() < 4 || rings < 2 || per_ring < 3) return false;
  const Vec3 c = surface.V.colwise().mean().transpose();
  const Points3 centred = surface.V.rowwise() - c.transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(centred.transpose() * centred);
  const Vec3 axis = eig.eigenvectors().col(2).normalized();
  const Vec3 u = axis.unitOrthogonal();
  const VecX along = centred * axis;
  const double lo = along.minCoeff(), hi = along.maxCoeff();
  Points3 V(rings * per_ring, 3);
  for (int r = 0; r < rings; ++r) {
    const double s = lo + (0.03 + 0.94 * r / (rings - 1)) * (hi - lo);
    const std::vector<Contour> contours = slice_mesh(surface, c + s * axis, axis);
    const Contour* best = nullptr;
    double best_area = 0.0;
    for (const Contour& k : contours)
      if (k.closed && k.points.rows() >= 3 && std::abs(compute_contour_area(k, axis)) > best_area) {
        best_area = std::abs(compute_contour_area(k, axis));
        best = &k;
      }
    if (!best) return false;
    Points3 ring = best->points;
    if (compute_contour_area(*best, axis) < 0.0) ring = ring.colwise().reverse().eval();
    const Eigen::Index n = ring.rows();
    Eigen::Index start = 0;
    for (Eigen::Index j = 1; j < n; ++j)
      if (ring.row(j).dot(u) > ring.row(start).dot(u)) start = j;
    VecX arc(n + 1);
    arc[0] = 0.0;
    for (Eigen::Index j = 0; j < n; ++j)
      arc[j + 1] = arc[j] + (ring.row((start + j + 1) % n) - ring.row((start + j) % n)).norm();
    Eigen::Index seg = 0;
    for (int k = 0; k < per_ring; ++k) {
      const double target = arc[n] * k / per_ring;
      while (seg + 1 < n && arc[seg + 1] < target) ++seg;
      const double len = arc[seg + 1] - arc[seg];
      const double t = len > 0.0 ? std::clamp((target - arc[seg]) / len, 0.0, 1.0) : 0.0;
      V.row(r * per_ring + k) = (1.0 - t) * ring.row((start + seg) % n) + t * ring.row((start + seg + 1) % n);
    }
  }
  // weights
  const int base = m.first_particle;
  const double s2 = m.mean_spring_length_m * m.mean_spring_length_m;
  std::vector<int> start_of = {0}, particle;
  std::vector<double> weight;
  std::vector<char> boundary(m.num_fibres, 0);
  std::vector<int> nearest_particles;
  for (Eigen::Index v = 0; v < V.rows(); ++v) {
    const Vec3 p = V.row(v).transpose();
    int nearest = base;
    for (int q = base; q < base + m.num_particles; ++q)
      if ((rest.row(q) - p.transpose()).squaredNorm() < (rest.row(nearest) - p.transpose()).squaredNorm()) nearest = q;
    const int f = (nearest - base) / P, i = (nearest - base) % P;
    boundary[f] = 1;
    nearest_particles.push_back(nearest);
    std::vector<int> ids;
    std::vector<Vec3> x;
    std::vector<double> omega;
    std::vector<int> fibres = {f};
    fibres.insert(fibres.end(), neighbours[f].begin(), neighbours[f].end());
    for (int g : fibres)
      for (int j = std::max(0, i - 1); j <= std::min(P - 1, i + 1); ++j) {
        ids.push_back(base + g * P + j);
        x.push_back(rest.row(ids.back()).transpose());
        omega.push_back(1.0 / ((x.back() - p).squaredNorm() + s2));
      }
    const std::vector<double> w = calc_affine_weights(x, omega, p);
    if (w.empty()) return false;
    for (std::size_t k = 0; k < ids.size(); ++k) {
      particle.push_back(ids[k]);
      weight.push_back(w[k]);
    }
    start_of.push_back(static_cast<int>(weight.size()));
  }
  // caps: the end rings (planar at rest) triangulated by ear clipping, facing out of the ends
  const Vec3 w = axis.cross(u);
  std::vector<Eigen::Vector3i> tris;
  for (int end = 0; end < 2; ++end) {
    const int first = end == 0 ? 0 : (rings - 1) * per_ring;
    std::vector<Vec2> ring(per_ring);
    for (int k = 0; k < per_ring; ++k) ring[k] = Vec2(V.row(first + k).dot(u), V.row(first + k).dot(w));
    const std::vector<Eigen::Vector3i> cap = calc_ear_triangles(ring);
    if (cap.empty()) return false;
    for (const Eigen::Vector3i& t : cap)
      tris.push_back(end == 0 ? Eigen::Vector3i(first + t[0], first + t[2], first + t[1])
                              : Eigen::Vector3i(first + t[0], first + t[1], first + t[2]));
  }
  const Triangles walls = calc_tube_triangles(rings, per_ring);
  m.surface_triangles.resize(static_cast<Eigen::Index>(tris.size()) + 2 * rings * per_ring - 2 * per_ring, 3);
  Eigen::Index row = 0;
  for (Eigen::Index t = 0; t < walls.rows(); ++t)
    if (walls.row(t).maxCoeff() < rings * per_ring) m.surface_triangles.row(row++) = walls.row(t);
  for (const Eigen::Vector3i& t : tris) m.surface_triangles.row(row++) = t.transpose();
  m.surface_weight_start = std::move(start_of);
  m.surface_weight_particle = std::move(particle);
  m.surface_weight = std::move(weight);
  m.boundary_fibres.clear();
  for (int g = 0; g < m.num_fibres; ++g)
    if (boundary[g]) m.boundary_fibres.push_back(g);
  m.surface_from_rest_mesh = true;
  std::sort(nearest_particles.begin(), nearest_particles.end());
  nearest_particles.erase(std::unique(nearest_particles.begin(), nearest_particles.end()), nearest_particles.end());
  m.contact_particles = std::move(nearest_particles);
  set_rest_volume(m, rest);
  return true;
}

// Rest distances of every particle to the bones (clearance outside, depth inside), inside decided
// by the solver's own rule (detail::calc_is_behind_bone) so that rest contacts are measured as in
// every frame.
void set_rest_bone_distances(FibresFirstModel& model) {
  const int total = model.num_particles();
  model.rest_bone_clearance.clear();
  model.rest_bone_depth.clear();
  for (const MeshQuery* bone : model.bones) {
    const std::vector<ClosestPoint> closest = bone->calc_closest_points(model.rest);
    VecX clearance(total);
    VecX depth = VecX::Zero(total);
    for (int p = 0; p < total; ++p) {
      clearance[p] = closest[p].distance;
      if (closest[p].triangle >= 0 &&
          detail::calc_is_behind_bone(*bone, model.rest.row(p).transpose(), closest[p])) {
        depth[p] = closest[p].distance;
        clearance[p] = 0.0;
      }
    }
    model.rest_bone_clearance.push_back(std::move(clearance));
    model.rest_bone_depth.push_back(std::move(depth));
  }
}

// Bending springs of a closed surface (FibresFirstOptions::surface_bending): for every edge shared
// by two triangles, a spring between the two vertices opposite it (unless they already share an
// edge), the usual cheap bending spring of cloth models: folding the surface along the edge
// changes that distance, a rigid motion does not. `edges`: the surface's edges (a < b); `first`:
// the particle index of vertex 0; `add_spring(a, b)` adds one at its rest length.
template <class AddSpring>
void add_surface_bending_springs(const Triangles& triangles, const std::set<std::pair<int, int>>& edges,
                                 int first, AddSpring&& add_spring) {
  std::map<std::pair<int, int>, std::vector<int>> opposite;
  for (Eigen::Index t = 0; t < triangles.rows(); ++t)
    for (int e = 0; e < 3; ++e) {
      const int a = triangles(t, e), b = triangles(t, (e + 1) % 3), c = triangles(t, (e + 2) % 3);
      opposite[{std::min(a, b), std::max(a, b)}].push_back(c);
    }
  std::set<std::pair<int, int>> bend;
  for (const auto& [edge, across] : opposite) {
    if (across.size() != 2) continue;
    const std::pair<int, int> pair{std::min(across[0], across[1]), std::max(across[0], across[1])};
    if (pair.first != pair.second && !edges.count(pair)) bend.insert(pair);
  }
  for (const auto& [a, b] : bend) add_spring(first + a, first + b);
}

// The second largest principal spread (standard deviation, m) of a set of rest points: 0 for
// points on a line or at one point, where a best-fit rotation is undetermined.
double calc_second_spread(const std::set<int>& points, const Points3& rest) {
  Vec3 c = Vec3::Zero();
  for (int p : points) c += rest.row(p).transpose();
  c /= static_cast<double>(points.size());
  Mat3 H = Mat3::Zero();
  for (int p : points) {
    const Vec3 d = rest.row(p).transpose() - c;
    H += d * d.transpose();
  }
  const Vec3 e = Eigen::SelfAdjointEigenSolver<Mat3>(H, Eigen::EigenvaluesOnly).eigenvalues();
  return std::sqrt(std::max(0.0, e[1]) / static_cast<double>(points.size()));
}

// Ring frames (FibresFirstOptions::surface_frame_stiffness): the fibre particles whose best-fit
// rigid motion moves each loft ring (vertices first_vertex + r * per_ring + k), from
// `ring_anchors` (per ring, the anchors of its vertices). The end rings of a belly whose fibres
// converge to a tendon are often anchored by one cluster of particles (on gait2392, 6 particles
// at one point for some muscles), and a strap's by one line across it, whose rotations are
// undetermined: while a ring's set spreads less than a fifth of the ring's own RMS radius in its
// second principal direction, the anchors of the next rings on both sides are added.
void set_ring_frames(FibreBundle& m, const std::vector<std::set<int>>& ring_anchors, const Points3& rest,
                     int first_vertex, int per_ring) {
  const int rings = static_cast<int>(ring_anchors.size());
  m.ring_frame_start = {0};
  m.ring_frame_particle.clear();
  for (int r = 0; r < rings; ++r) {
    const auto ring = rest.middleRows(first_vertex + r * per_ring, per_ring);
    const double radius = std::sqrt((ring.rowwise() - ring.colwise().mean()).squaredNorm() / per_ring);
    std::set<int> set = ring_anchors[r];
    for (int d = 1; d < rings && calc_second_spread(set, rest) < 0.2 * radius; ++d) {
      if (r - d >= 0) set.insert(ring_anchors[r - d].begin(), ring_anchors[r - d].end());
      if (r + d < rings) set.insert(ring_anchors[r + d].begin(), ring_anchors[r + d].end());
    }
    m.ring_frame_particle.insert(m.ring_frame_particle.end(), set.begin(), set.end());
    m.ring_frame_start.push_back(static_cast<int>(m.ring_frame_particle.size()));
  }
}

// Surface particles (FibresFirstOptions::surface_particles): every muscle with a loft surface gets
// its loft vertices as free particles after its fibre particles (all particle indices after it
// shift), each tied by springs at rest length to its surface_anchor_count nearest fibre particles
// and along the loft's triangle edges; its surface weights become the identity on them.
void add_surface_particles(FibresFirstModel& model) {
  const FibresFirstOptions& o = model.options;
  const int P = o.particles_per_fibre;
  const int nm = static_cast<int>(model.muscles.size());
  std::vector<int> extra(nm, 0), shift(nm, 0);
  int added = 0;
  for (int mi = 0; mi < nm; ++mi) {
    shift[mi] = added;
    if (model.muscles[mi].surface_from_rest_mesh) extra[mi] = model.muscles[mi].num_surface_vertices();
    added += extra[mi];
  }
  if (added == 0) return;
  const int old_total = model.num_particles(), total = old_total + added;
  auto remap = [&](int p) { return p + shift[model.muscle_of[p]]; };
  Points3 rest(total, 3);
  std::vector<int> muscle_of(total), fixed_bone(total, -1), anchor(total, -1);
  std::vector<double> fibre_t(total), line_fraction(total, std::numeric_limits<double>::quiet_NaN());
  std::vector<ParticleRole> role(total, ParticleRole::free);
  for (int p = 0; p < old_total; ++p) {
    const int q = remap(p);
    rest.row(q) = model.rest.row(p);
    muscle_of[q] = model.muscle_of[p];
    fibre_t[q] = model.fibre_t[p];
    role[q] = model.role[p];
    fixed_bone[q] = model.fixed_bone[p];
    line_fraction[q] = model.line_fraction[p];
  }
  std::vector<Spring> springs;
  std::vector<int> first_spring = {0};
  for (int mi = 0; mi < nm; ++mi) {
    FibreBundle& m = model.muscles[mi];
    const int first = m.first_particle + shift[mi];
    const int nfp = m.num_fibres * P;
    for (int s = model.first_spring[mi]; s < model.first_spring[mi + 1]; ++s) {
      Spring sp = model.springs[s];
      sp.a = remap(sp.a);
      sp.b = remap(sp.b);
      springs.push_back(sp);
    }
    for (int& p : m.free) p = remap(p);
    for (int& p : m.contact_particles) p = remap(p);
    if (extra[mi] == 0) {
      for (int& p : m.surface_weight_particle) p = remap(p);
    } else {
      const Points3 S = gather_surface_vertices(m, model.rest);
      const int s0 = first + nfp;
      auto add_spring = [&](int a, int b) {
        springs.push_back({a, b, (rest.row(a) - rest.row(b)).norm(), o.surface_stiffness});
      };
      const int k = std::clamp(o.surface_anchor_count, 1, nfp);
      std::vector<std::pair<double, int>> near(nfp);
      const int per_ring = o.surface_ring_points;
      std::vector<std::set<int>> ring_anchors(extra[mi] / per_ring);
      for (int v = 0; v < extra[mi]; ++v) {
        const int q = s0 + v;
        rest.row(q) = S.row(v);
        muscle_of[q] = mi;
        for (int j = 0; j < nfp; ++j)
          near[j] = {(model.rest.row(m.first_particle + j) - S.row(v)).squaredNorm(), first + j};
        std::partial_sort(near.begin(), near.begin() + k, near.end());
        anchor[q] = near[0].second;
        fibre_t[q] = fibre_t[near[0].second];
        for (int j = 0; j < k; ++j) add_spring(q, near[j].second);
        for (int j = 0; j < k; ++j) ring_anchors[v / per_ring].insert(near[j].second);
      }
      set_ring_frames(m, ring_anchors, rest, s0, per_ring);
      std::set<std::pair<int, int>> edges;
      for (Eigen::Index t = 0; t < m.surface_triangles.rows(); ++t)
        for (int e = 0; e < 3; ++e) {
          const int a = m.surface_triangles(t, e), b = m.surface_triangles(t, (e + 1) % 3);
          edges.emplace(std::min(a, b), std::max(a, b));
        }
      for (const auto& [a, b] : edges) add_spring(s0 + a, s0 + b);
      if (o.surface_bending) add_surface_bending_springs(m.surface_triangles, edges, s0, add_spring);
      m.surface_weight_start.resize(extra[mi] + 1);
      m.surface_weight_particle.resize(extra[mi]);
      m.surface_weight.assign(extra[mi], 1.0);
      for (int v = 0; v < extra[mi]; ++v) {
        m.surface_weight_start[v] = v;
        m.surface_weight_particle[v] = s0 + v;
        m.free.push_back(s0 + v);
      }
      m.surface_weight_start[extra[mi]] = extra[mi];
    }
    m.first_particle = first;
    m.num_particles = nfp + extra[mi];
    m.num_surface_particles = extra[mi];
    m.free_index.assign(m.num_particles, -1);
    for (std::size_t j = 0; j < m.free.size(); ++j) m.free_index[m.free[j] - first] = static_cast<int>(j);
    first_spring.push_back(static_cast<int>(springs.size()));
  }
  model.rest = std::move(rest);
  model.muscle_of = std::move(muscle_of);
  model.fibre_t = std::move(fibre_t);
  model.role = std::move(role);
  model.fixed_bone = std::move(fixed_bone);
  model.line_fraction = std::move(line_fraction);
  model.surface_anchor = std::move(anchor);
  model.springs = std::move(springs);
  model.first_spring = std::move(first_spring);
  for (FibreBundle& m : model.muscles)
    if (m.num_surface_particles > 0) set_rest_volume(m, model.rest);
  set_rest_bone_distances(model);
}

}  // namespace

FibresFirstModel build_fibres_first_model(const std::vector<FibreBundleSpec>& specs,
                                          const std::vector<const MeshQuery*>& bones,
                                          const FibresFirstOptions& options) {
  check_options(options);
  FibresFirstModel model;
  model.options = options;
  model.bones = bones;
  for (const MeshQuery* b : bones)
    if (!b) throw_usage("null bone query given to the fibres-first model");
  const int P = options.particles_per_fibre;
  const int nbones = static_cast<int>(bones.size());

  // particles
  int total = 0;
  for (const FibreBundleSpec& s : specs) {
    if (s.fibres.empty())
      throw_bad_input(fmt::format("muscle '{}' has no fibres", s.name), muscle_context(s.name));
    for (int bone : {s.origin_bone, s.insertion_bone})
      if (bone < -1 || bone >= nbones)
        throw_bad_input(fmt::format("muscle '{}' refers to bone {} but the model has {} bones",
                                    s.name, bone, nbones),
                        muscle_context(s.name));
    if (s.origin_bone < 0 && s.insertion_bone < 0)
      throw_bad_input(fmt::format("muscle '{}' has neither an origin nor an insertion bone: its "
                                  "fibres cannot be attached or carried",
                                  s.name),
                      muscle_context(s.name, "give the muscle at least one bone"));
    if (s.action_line.rows() > 0) {
      double length = 0.0;
      for (Eigen::Index i = 1; i < s.action_line.rows(); ++i)
        length += (s.action_line.row(i) - s.action_line.row(i - 1)).norm();
      if (s.action_line.rows() < 2 || !s.action_line.allFinite() || !(length > 0.0))
        throw_bad_input(fmt::format("the action line of muscle '{}' needs >= 2 finite points and a "
                                    "positive length", s.name),
                        muscle_context(s.name, "give the rest action line from origin to insertion, "
                                               "or none"));
    }
    total += static_cast<int>(s.fibres.size()) * P;
  }
  model.rest.resize(total, 3);
  model.muscle_of.resize(total);
  model.fibre_t.resize(total);
  model.role.assign(total, ParticleRole::free);
  model.fixed_bone.assign(total, -1);
  model.line_fraction.assign(total, std::numeric_limits<double>::quiet_NaN());
  int offset = 0;
  for (std::size_t mi = 0; mi < specs.size(); ++mi) {
    const FibreBundleSpec& s = specs[mi];
    FibreBundle m;
    m.name = s.name;
    m.origin_bone = s.origin_bone;
    m.insertion_bone = s.insertion_bone;
    m.first_particle = offset;
    m.num_fibres = static_cast<int>(s.fibres.size());
    m.num_particles = m.num_fibres * P;
    m.rest_action_line = s.action_line;
    for (int f = 0; f < m.num_fibres; ++f) {
      const Points3& line = s.fibres[f];
      if (line.rows() < 2 || !line.allFinite())
        throw_bad_input(fmt::format("fibre {} of muscle '{}' has fewer than 2 points or a "
                                    "non-finite coordinate", f, s.name),
                        muscle_context(s.name));
      double length = 0.0;
      for (Eigen::Index i = 1; i < line.rows(); ++i) length += (line.row(i) - line.row(i - 1)).norm();
      if (!(length > 0.0))
        throw_bad_input(fmt::format("fibre {} of muscle '{}' has zero length", f, s.name),
                        muscle_context(s.name));
      model.rest.middleRows(offset + f * P, P) = resample_uniform(line, P);
      for (int i = 0; i < P; ++i) {
        model.muscle_of[offset + f * P + i] = static_cast<int>(mi);
        model.fibre_t[offset + f * P + i] = static_cast<double>(i) / (P - 1);
      }
    }
    offset += m.num_particles;
    model.muscles.push_back(std::move(m));
  }

  set_rest_bone_distances(model);
  model.surface_anchor.assign(total, -1);
  auto distance_to = [&](int bone, int p) {
    return model.rest_bone_clearance[bone][p];  // 0 inside
  };

  // per muscle: springs, fixed particles, surface, mass
  model.first_spring.push_back(0);
  for (FibreBundle& m : model.muscles) {
    const int base = m.first_particle;
    auto id = [&](int f, int i) { return base + f * P + i; };
    auto add_spring = [&](int a, int b, double k) {
      const double L = (model.rest.row(a) - model.rest.row(b)).norm();
      model.springs.push_back({a, b, L, k});
    };
    for (int f = 0; f < m.num_fibres; ++f) {
      for (int i = 0; i + 1 < P; ++i) add_spring(id(f, i), id(f, i + 1), options.along_stiffness);
      if (options.bending_stiffness > 0.0)
        for (int i = 0; i + 2 < P; ++i) add_spring(id(f, i), id(f, i + 2), options.bending_stiffness);
    }
    Points3 mid(m.num_fibres, 3);
    for (int f = 0; f < m.num_fibres; ++f) mid.row(f) = model.rest.row(id(f, P / 2));
    std::vector<std::vector<int>> fibre_neighbours(m.num_fibres);
    for (const auto& [f, g] : calc_fibre_neighbours(mid, options.cross_neighbours)) {
      for (int i = 0; i < P; ++i) add_spring(id(f, i), id(g, i), options.across_stiffness);
      fibre_neighbours[f].push_back(g);
      fibre_neighbours[g].push_back(f);
    }
    model.first_spring.push_back(static_cast<int>(model.springs.size()));
    double mean = 0.0;
    int count = 0;
    for (int s = model.first_spring[model.first_spring.size() - 2]; s < model.first_spring.back(); ++s) {
      mean += model.springs[s].rest_length_m;
      ++count;
    }
    m.mean_spring_length_m = count > 0 ? mean / count : 0.0;

    // fixed particles: fibre ends on their bones (farther ends carried along the action line
    // when there is one), then any particle close to the muscle's bones
    for (int f = 0; f < m.num_fibres; ++f)
      for (auto [i, bone] : {std::pair{0, m.origin_bone}, std::pair{P - 1, m.insertion_bone}}) {
        if (bone >= 0 && distance_to(bone, id(f, i)) <= options.end_attachment_distance_m) {
          model.role[id(f, i)] = ParticleRole::fixed;
          model.fixed_bone[id(f, i)] = bone;
        } else if (m.rest_action_line.rows() >= 2) {
          model.role[id(f, i)] = ParticleRole::carried;
          model.line_fraction[id(f, i)] =
              detail::calc_line_fraction(m.rest_action_line, model.rest.row(id(f, i)).transpose());
        }
      }
    if (options.bone_attachment_distance_m > 0.0)
      for (int p = base; p < base + m.num_particles; ++p) {
        if (model.role[p] != ParticleRole::free) continue;
        int best = -1;
        double best_d = options.bone_attachment_distance_m;
        for (int bone : {m.origin_bone, m.insertion_bone})
          if (bone >= 0 && distance_to(bone, p) <= best_d) {
            best = bone;
            best_d = distance_to(bone, p);
          }
        if (best >= 0) {
          model.role[p] = ParticleRole::fixed;
          model.fixed_bone[p] = best;
        }
      }

    // every particle must be connected to a fixed one (otherwise the system is singular)
    std::vector<std::vector<int>> adjacency(m.num_particles);
    for (int s = model.first_spring[model.first_spring.size() - 2]; s < model.first_spring.back(); ++s) {
      adjacency[model.springs[s].a - base].push_back(model.springs[s].b - base);
      adjacency[model.springs[s].b - base].push_back(model.springs[s].a - base);
    }
    std::vector<char> reached(m.num_particles, 0);
    std::vector<int> queue;
    for (int p = 0; p < m.num_particles; ++p)
      if (model.role[base + p] != ParticleRole::free) {
        reached[p] = 1;
        queue.push_back(p);
      }
    if (queue.empty())
      throw_bad_input(fmt::format("no particle of muscle '{}' is fixed to a bone: its fibres reach "
                                  "neither the origin bone ({}) nor the insertion bone ({}), and it "
                                  "has no action line to carry them",
                                  m.name, m.origin_bone, m.insertion_bone),
                      muscle_context(m.name, "check the muscle's bones, raise "
                                             "end_attachment_distance_m, or give its action line"));
    for (std::size_t q = 0; q < queue.size(); ++q)
      for (int r : adjacency[queue[q]])
        if (!reached[r]) {
          reached[r] = 1;
          queue.push_back(r);
        }
    for (int p = 0; p < m.num_particles; ++p)
      if (!reached[p])
        throw_bad_input(fmt::format("fibre {} of muscle '{}' is connected to no particle fixed to a "
                                    "bone or carried by the action line", p / P, m.name),
                        muscle_context(m.name, "raise cross_neighbours or end_attachment_distance_m"));
    m.free_index.assign(m.num_particles, -1);
    for (int p = 0; p < m.num_particles; ++p)
      if (model.role[base + p] == ParticleRole::free) {
        m.free_index[p] = static_cast<int>(m.free.size());
        m.free.push_back(base + p);
      }

    // display surface: the loft of the rest surface when the spec gives one, else the tube
    // through the convex hull of the middle cross-section (projected on the plane normal to the
    // mean fibre direction)
    const FibreBundleSpec& spec = specs[static_cast<std::size_t>(&m - model.muscles.data())];
    const bool loft = spec.rest_surface.F.rows() > 0 &&
                      build_loft_surface(m, spec.rest_surface, model.rest, P, fibre_neighbours,
                                         options.surface_rings, options.surface_ring_points);
    Vec3 axis = Vec3::Zero();
    for (int f = 0; f < m.num_fibres; ++f)
      axis += (model.rest.row(id(f, P - 1)) - model.rest.row(id(f, 0))).transpose();
    if (axis.norm() > 0.0 && !loft) {
      axis.normalize();
      const Vec3 u = axis.unitOrthogonal(), v = axis.cross(u);
      std::vector<Vec2> section(m.num_fibres);
      for (int f = 0; f < m.num_fibres; ++f) section[f] = Vec2(mid.row(f).dot(u), mid.row(f).dot(v));
      m.boundary_fibres = calc_convex_hull(section);
      // contact fibres (tube surface; a loft sets its own in build_loft_surface): the boundary
      // fibres, and those within muscle_contact_band x the mean nearest-fibre spacing of the
      // hull's edges
      std::vector<char> near(m.num_fibres, 0);
      for (int f : m.boundary_fibres) near[f] = 1;
      const int nb = static_cast<int>(m.boundary_fibres.size());
      if (nb >= 3 && options.muscle_contact_band > 0.0) {
        double spacing = 0.0;
        for (int f = 0; f < m.num_fibres; ++f) {
          double nearest = std::numeric_limits<double>::infinity();
          for (int g = 0; g < m.num_fibres; ++g)
            if (g != f) nearest = std::min(nearest, (section[f] - section[g]).norm());
          spacing += nearest / m.num_fibres;
        }
        for (int f = 0; f < m.num_fibres; ++f)
          for (int k = 0; k < nb && !near[f]; ++k) {
            const Vec2 a = section[m.boundary_fibres[k]];
            const Vec2 b = section[m.boundary_fibres[(k + 1) % nb]];
            const double t = std::clamp((section[f] - a).dot(b - a) / std::max((b - a).squaredNorm(), 1e-300), 0.0, 1.0);
            if ((section[f] - (a + t * (b - a))).norm() <= options.muscle_contact_band * spacing)
              near[f] = 1;
          }
      }
      for (int f = 0; f < m.num_fibres; ++f)
        if (near[f])
          for (int i = 0; i < P; ++i) m.contact_particles.push_back(id(f, i));
    }
    if (!loft) build_tube_surface(m, model.rest, P, options.hold_volume);
  }

  if (options.surface_particles) add_surface_particles(model);

  // masses (density x volume share)
  for (std::size_t mi = 0; mi < model.muscles.size(); ++mi) {
    FibreBundle& m = model.muscles[mi];
    const double volume = specs[mi].volume_m3 > 0.0 ? specs[mi].volume_m3 : m.rest_volume_m3;
    if (options.dynamic && !(volume > 0.0))
      throw_bad_input(fmt::format("muscle '{}' has no volume for its particle masses", m.name),
                      muscle_context(m.name, "give volume_m3 in its specification"));
    m.particle_mass_kg = options.density_kg_per_m3 * volume / m.num_particles;
  }
  return model;
}

}  // namespace fascicle
