// Cached-basis tessellation of B-spline solids (seed 000 §3.1.4).
#include "fascicle/bspline/tessellation.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <map>

namespace fascicle {

std::vector<double> make_parameter_grid(const BSplineBasis& b, int per_span) {
  per_span = std::max(1, per_span);
  std::vector<double> t;
  for (int s = b.degree; s < b.num_functions(); ++s) {
    const double a = b.knots[s], c = b.knots[s + 1];
    if (!(c > a)) continue;
    for (int q = 0; q < per_span; ++q) t.push_back(a + (c - a) * q / per_span);
  }
  if (!b.periodic) t.push_back(b.get_upper());
  if (t.empty()) t.push_back(b.get_lower());
  return t;
}

void append_basis_row(const BSplineSolid& s, const Vec3& uvw, const std::array<int, 3>& order,
                      int row, std::vector<Eigen::Triplet<double>>& triplets) {
  const BasisValues bu = calc_basis(s.basis[0], uvw[0], order[0]);
  const BasisValues bv = calc_basis(s.basis[1], uvw[1], order[1]);
  const BasisValues bw = calc_basis(s.basis[2], uvw[2], order[2]);
  for (int c = 0; c <= s.basis[2].degree; ++c)
    for (int b = 0; b <= s.basis[1].degree; ++b)
      for (int a = 0; a <= s.basis[0].degree; ++a) {
        const double w = bu.N[order[0]][a] * bv.N[order[1]][b] * bw.N[order[2]][c];
        if (w == 0.0) continue;
        triplets.emplace_back(row,
                              s.index(control_index(s.basis[0], bu.first + a),
                                      control_index(s.basis[1], bv.first + b),
                                      control_index(s.basis[2], bw.first + c)),
                              w);
      }
}

namespace {

SparseRowMatrix make_matrix(int rows, int cols, std::vector<Eigen::Triplet<double>>& t) {
  SparseRowMatrix m(rows, cols);
  m.setFromTriplets(t.begin(), t.end());
  return m;
}

// A face collapses (to a curve or a point: axis, pole) when along one of its in-plane directions
// all its control points coincide, for every index of the other direction.
std::array<bool, 2> find_collapsed_directions(const BSplineSolid& s, int d, int side) {
  const int a = (d + 1) % 3, b = (d + 2) % 3;
  const int id = side == 0 ? 0 : s.num_control(d) - 1;
  const double size = (s.P.colwise().maxCoeff() - s.P.colwise().minCoeff()).norm();
  const double eps = 1e-12 * size;
  const auto at = [&](int ia, int ib) {
    int ijk[3];
    ijk[d] = id;
    ijk[a] = ia;
    ijk[b] = ib;
    return Vec3(s.P.row(s.index(ijk[0], ijk[1], ijk[2])).transpose());
  };
  const auto collapsed_along = [&](int na, int nb, bool swap) {
    for (int j = 0; j < nb; ++j)
      for (int i = 1; i < na; ++i) {
        const Vec3 p = swap ? at(j, i) : at(i, j), q = swap ? at(j, 0) : at(0, j);
        if ((p - q).norm() > eps) return false;
      }
    return true;
  };
  return {collapsed_along(s.num_control(a), s.num_control(b), false),
          collapsed_along(s.num_control(b), s.num_control(a), true)};
}

}  // namespace

BoundaryTessellation make_boundary_tessellation(const BSplineSolid& s, int per_span) {
  std::array<std::vector<double>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = make_parameter_grid(s.basis[d], per_span);
  const int n[3] = {static_cast<int>(g[0].size()), static_cast<int>(g[1].size()),
                    static_cast<int>(g[2].size())};
  // Collapsed faces: grid nodes on them that differ only along a collapsed direction are one
  // vertex (canonical key: index 0 along that direction).
  struct Collapse {
    int d, fixed, along;
  };
  std::vector<Collapse> collapses;
  std::array<std::array<bool, 2>, 6> collapsed{};
  for (int d = 0; d < 3; ++d) {
    if (s.basis[d].periodic) continue;
    for (int side = 0; side < 2; ++side) {
      collapsed[2 * d + side] = find_collapsed_directions(s, d, side);
      for (int e = 0; e < 2; ++e)
        if (collapsed[2 * d + side][e]) collapses.push_back({d, side == 0 ? 0 : n[d] - 1, (d + 1 + e) % 3});
    }
  }
  const auto canonical = [&](std::array<int, 3> key) {
    for (int pass = 0; pass < 2; ++pass)
      for (const Collapse& c : collapses)
        if (key[c.d] == c.fixed) key[c.along] = 0;
    return key;
  };
  // vertices are grid nodes on kept faces; keyed by grid index so faces share their edges
  std::map<std::array<int, 3>, int> vertex_of;
  std::vector<std::array<int, 3>> nodes;
  std::vector<int> face_of;  // which face (2d + side) owns a vertex's normal
  std::vector<Eigen::Vector3i> tris;
  const auto node = [&](int i, int j, int k, int face) {
    const std::array<int, 3> key = canonical({i, j, k});
    auto [it, fresh] = vertex_of.emplace(key, static_cast<int>(nodes.size()));
    if (fresh) {
      nodes.push_back(key);
      face_of.push_back(face);
    }
    return it->second;
  };
  for (int d = 0; d < 3; ++d) {
    if (s.basis[d].periodic) continue;
    const int a = (d + 1) % 3, b = (d + 2) % 3;
    for (int side = 0; side < 2; ++side) {
      if (collapsed[2 * d + side][0] || collapsed[2 * d + side][1]) continue;
      const int fixed = side == 0 ? 0 : n[d] - 1;
      const int na = n[a], nb = n[b];
      const int ea = s.basis[a].periodic ? na : na - 1;  // cells along a
      const int eb = s.basis[b].periodic ? nb : nb - 1;
      const auto at = [&](int ia, int ib) {
        int ijk[3];
        ijk[d] = fixed;
        ijk[a] = ia % na;
        ijk[b] = ib % nb;
        return node(ijk[0], ijk[1], ijk[2], 2 * d + side);
      };
      for (int ib = 0; ib < eb; ++ib)
        for (int ia = 0; ia < ea; ++ia) {
          const int v00 = at(ia, ib), v10 = at(ia + 1, ib), v11 = at(ia + 1, ib + 1),
                    v01 = at(ia, ib + 1);
          // (a, b) is counter-clockwise seen from outside on the upper side
          if (side == 1) {
            tris.emplace_back(v00, v10, v11);
            tris.emplace_back(v00, v11, v01);
          } else {
            tris.emplace_back(v00, v11, v10);
            tris.emplace_back(v00, v01, v11);
          }
        }
    }
  }
  BoundaryTessellation t;
  const int nv = static_cast<int>(nodes.size());
  t.material.resize(nv, 3);
  std::vector<Eigen::Triplet<double>> w, ta, tb;
  for (int v = 0; v < nv; ++v) {
    const Vec3 uvw(g[0][nodes[v][0]], g[1][nodes[v][1]], g[2][nodes[v][2]]);
    t.material.row(v) = uvw.transpose();
    const int d = face_of[v] / 2, side = face_of[v] % 2;
    const int a = (d + 1) % 3, b = (d + 2) % 3;
    std::array<int, 3> oa{0, 0, 0}, ob{0, 0, 0};
    oa[a] = 1;
    ob[b] = 1;
    append_basis_row(s, uvw, {0, 0, 0}, v, w);
    // the lower side's outward normal is -(x_a x x_b): swap the tangents
    append_basis_row(s, uvw, side == 1 ? oa : ob, v, ta);
    append_basis_row(s, uvw, side == 1 ? ob : oa, v, tb);
  }
  const int np = s.num_control_points();
  t.weights = make_matrix(nv, np, w);
  t.tangent_a = make_matrix(nv, np, ta);
  t.tangent_b = make_matrix(nv, np, tb);
  // drop triangles made degenerate by merged vertices, and vertices only they used
  std::vector<Eigen::Vector3i> kept;
  for (const auto& m : tris) {
    if (m[0] != m[1] && m[1] != m[2] && m[0] != m[2]) kept.push_back(m);
  }
  // compact the vertex list
  std::vector<int> used(nv, -1);
  std::vector<int> order;
  for (const auto& f : kept)
    for (int c = 0; c < 3; ++c)
      if (used[f[c]] < 0) {
        used[f[c]] = static_cast<int>(order.size());
        order.push_back(f[c]);
      }
  std::sort(order.begin(), order.end());
  for (int i = 0; i < static_cast<int>(order.size()); ++i) used[order[i]] = i;
  const auto select = [&](const SparseRowMatrix& m) {
    std::vector<Eigen::Triplet<double>> tr;
    for (int i = 0; i < static_cast<int>(order.size()); ++i)
      for (SparseRowMatrix::InnerIterator it(m, order[i]); it; ++it) tr.emplace_back(i, it.col(), it.value());
    return make_matrix(static_cast<int>(order.size()), np, tr);
  };
  t.weights = select(t.weights);
  t.tangent_a = select(t.tangent_a);
  t.tangent_b = select(t.tangent_b);
  Points3 mat(order.size(), 3);
  for (int i = 0; i < static_cast<int>(order.size()); ++i) mat.row(i) = t.material.row(order[i]);
  t.material = mat;
  t.mesh.F.resize(static_cast<Eigen::Index>(kept.size()), 3);
  for (int f = 0; f < static_cast<int>(kept.size()); ++f)
    for (int c = 0; c < 3; ++c) t.mesh.F(f, c) = used[kept[f][c]];
  update_tessellation(t, s.P);
  return t;
}

void update_tessellation(BoundaryTessellation& t, const Points3& P) {
  t.mesh.V.noalias() = t.weights * P;
  const Points3 A = t.tangent_a * P;
  const Points3 B = t.tangent_b * P;
  t.normals.resize(t.mesh.V.rows(), 3);
  Points3 face_sum;  // lazily computed fallback for vertices with vanishing tangents
  for (Eigen::Index v = 0; v < t.mesh.V.rows(); ++v) {
    const Vec3 nrm = Vec3(A.row(v)).cross(Vec3(B.row(v)));
    const double len = nrm.norm();
    if (len > 1e-300 && len > 1e-12 * A.row(v).norm() * B.row(v).norm()) {
      t.normals.row(v) = (nrm / len).transpose();
      continue;
    }
    if (face_sum.rows() == 0) {
      face_sum = Points3::Zero(t.mesh.V.rows(), 3);
      for (Eigen::Index f = 0; f < t.mesh.F.rows(); ++f) {
        const Vec3 p0 = t.mesh.V.row(t.mesh.F(f, 0)), p1 = t.mesh.V.row(t.mesh.F(f, 1)),
                   p2 = t.mesh.V.row(t.mesh.F(f, 2));
        const Vec3 an = (p1 - p0).cross(p2 - p0);
        for (int c = 0; c < 3; ++c) face_sum.row(t.mesh.F(f, c)) += an.transpose();
      }
    }
    t.normals.row(v) = face_sum.row(v).normalized();
  }
}

VolumeTessellation make_volume_tessellation(const BSplineSolid& s, int per_span) {
  std::array<std::vector<double>, 3> g;
  for (int d = 0; d < 3; ++d) g[d] = make_parameter_grid(s.basis[d], per_span);
  const int n[3] = {static_cast<int>(g[0].size()), static_cast<int>(g[1].size()),
                    static_cast<int>(g[2].size())};
  VolumeTessellation t;
  const int nv = n[0] * n[1] * n[2];
  t.material.resize(nv, 3);
  std::vector<Eigen::Triplet<double>> w;
  const auto id = [&](int i, int j, int k) {
    return (i % n[0]) + n[0] * ((j % n[1]) + n[1] * (k % n[2]));
  };
  for (int k = 0; k < n[2]; ++k)
    for (int j = 0; j < n[1]; ++j)
      for (int i = 0; i < n[0]; ++i) {
        const Vec3 uvw(g[0][i], g[1][j], g[2][k]);
        t.material.row(id(i, j, k)) = uvw.transpose();
        append_basis_row(s, uvw, {0, 0, 0}, id(i, j, k), w);
      }
  t.weights = make_matrix(nv, s.num_control_points(), w);
  int cells[3];
  for (int d = 0; d < 3; ++d) cells[d] = s.basis[d].periodic ? n[d] : std::max(0, n[d] - 1);
  t.hexes.resize(cells[0] * cells[1] * cells[2], 8);
  int h = 0;
  for (int k = 0; k < cells[2]; ++k)
    for (int j = 0; j < cells[1]; ++j)
      for (int i = 0; i < cells[0]; ++i) {
        t.hexes.row(h++) << id(i, j, k), id(i + 1, j, k), id(i + 1, j + 1, k), id(i, j + 1, k),
            id(i, j, k + 1), id(i + 1, j, k + 1), id(i + 1, j + 1, k + 1), id(i, j + 1, k + 1);
      }
  update_tessellation(t, s.P);
  return t;
}

void update_tessellation(VolumeTessellation& t, const Points3& P) { t.V.noalias() = t.weights * P; }

}  // namespace fascicle
