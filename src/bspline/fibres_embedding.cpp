// Fibre curves, streamlines and embedding in B-spline solids.
#include "fascicle/bspline/embedding.hpp"
#include "fascicle/bspline/fibres.hpp"

#include "fascicle/core/error.hpp"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

namespace fascicle {

Vec3 calc_fibre_direction(const BSplineSolid& s, const Vec3& uvw) {
  const Vec3 t = calc_point_and_jacobian(s, uvw).J.col(static_cast<int>(s.fibre_direction));
  const double n = t.norm();
  return n > 0 ? Vec3(t / n) : Vec3::Zero();
}

Points3 calc_fibre_curve(const BSplineSolid& s, const Vec2& seed, int samples) {
  samples = std::max(2, samples);
  const int f = static_cast<int>(s.fibre_direction), a = (f + 1) % 3, b = (f + 2) % 3;
  const BSplineBasis& bf = s.basis[f];
  Points3 out(samples, 3);
  for (int i = 0; i < samples; ++i) {
    Vec3 uvw;
    uvw[f] = bf.get_lower() + (bf.get_upper() - bf.get_lower()) * i / (samples - 1);
    uvw[a] = seed[0];
    uvw[b] = seed[1];
    out.row(i) = calc_point(s, uvw).transpose();
  }
  return out;
}

std::vector<Points3> calc_fibre_curves(const BSplineSolid& s, int na, int nb, int samples) {
  const int f = static_cast<int>(s.fibre_direction), a = (f + 1) % 3, b = (f + 2) % 3;
  const auto spread = [&](int d, int n, int i) {
    const BSplineBasis& bb = s.basis[d];
    return bb.get_lower() + (bb.get_upper() - bb.get_lower()) * (i + 0.5) / n;
  };
  std::vector<Points3> out;
  for (int j = 0; j < nb; ++j)
    for (int i = 0; i < na; ++i) out.push_back(calc_fibre_curve(s, Vec2(spread(a, na, i), spread(b, nb, j)), samples));
  return out;
}

MaterialDirectionField make_pennate_field(FibreDirection fibre, int towards, double angle) {
  const int f = static_cast<int>(fibre);
  if (towards < 0 || towards > 2 || towards == f) {
    throw_usage("pennate field: `towards` must be a direction other than the fibre direction");
  }
  Vec3 d = Vec3::Zero();
  d[f] = std::cos(angle);
  d[towards] = std::sin(angle);
  return [d](const Vec3&) { return d; };
}

MaterialDirectionField make_fanned_field(FibreDirection fibre, int across, double convergence) {
  const int f = static_cast<int>(fibre);
  if (across < 0 || across > 2 || across == f) {
    throw_usage("fanned field: `across` must be a direction other than the fibre direction");
  }
  if (!(convergence >= 0 && convergence < 1)) throw_usage("fanned field: convergence in [0, 1)");
  // lines a(t) = 0.5 + (a0 - 0.5)(1 - c t) through the unit box: da/dt = -c (a - 0.5)/(1 - c t)
  return [f, across, convergence](const Vec3& uvw) {
    Vec3 d = Vec3::Zero();
    d[f] = 1.0;
    d[across] = -convergence * (uvw[across] - 0.5) / (1.0 - convergence * uvw[f]);
    return d;
  };
}

Points3 trace_streamline(const BSplineSolid& s, const MaterialDirectionField& field,
                         const Vec3& seed, const StreamlineOptions& o, Points3* material) {
  const Vec3 lo = s.get_lower(), hi = s.get_upper();
  const auto inside = [&](const Vec3& u) {
    for (int d = 0; d < 3; ++d)
      if (!s.basis[d].periodic && (u[d] < lo[d] - 1e-12 || u[d] > hi[d] + 1e-12)) return false;
    return true;
  };
  const auto dir = [&](const Vec3& u, double sign) {
    const Vec3 v = field(wrap_material_point(s, u));
    const double n = v.norm();
    return n > 0 ? Vec3(sign * v / n) : Vec3::Zero();
  };
  std::vector<Vec3> half[2];
  for (int h = 0; h < 2; ++h) {
    const double sign = h == 0 ? -1.0 : 1.0;
    Vec3 u = seed;
    const auto rk4 = [&](const Vec3& x, double step) {
      const Vec3 k1 = dir(x, sign), k2 = dir(x + 0.5 * step * k1, sign),
                 k3 = dir(x + 0.5 * step * k2, sign), k4 = dir(x + step * k3, sign);
      return Vec3(x + step / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4));
    };
    for (int i = 0; i < o.max_steps; ++i) {
      if (dir(u, sign).isZero()) break;
      Vec3 next = rk4(u, o.step);
      if (!inside(next)) {
        // shorten the last step so that it ends on the boundary (two secant refinements)
        double t = 1.0;
        int hit = -1;
        double bound = 0.0;
        for (int pass = 0; pass < 3; ++pass) {
          double tn = 1.0;
          for (int d = 0; d < 3; ++d) {
            if (s.basis[d].periodic || next[d] == u[d]) continue;
            for (double b : {lo[d], hi[d]}) {
              const double f = (b - u[d]) / (next[d] - u[d]);
              if ((next[d] < lo[d] && b == lo[d]) || (next[d] > hi[d] && b == hi[d]) ||
                  (pass > 0 && d == hit && b == bound)) {
                if (f < tn) tn = f, hit = d, bound = b;
              }
            }
          }
          t *= tn;
          next = rk4(u, t * o.step);
        }
        for (int d = 0; d < 3; ++d)
          if (!s.basis[d].periodic) next[d] = std::clamp(next[d], lo[d], hi[d]);
        if (hit >= 0) next[hit] = bound;  // the coordinate that left lies on its bound
        half[h].push_back(next);
        break;
      }
      half[h].push_back(next);
      u = next;
    }
  }
  std::vector<Vec3> all(half[0].rbegin(), half[0].rend());
  all.push_back(seed);
  all.insert(all.end(), half[1].begin(), half[1].end());
  Points3 out(static_cast<Eigen::Index>(all.size()), 3);
  if (material) material->resize(out.rows(), 3);
  for (std::size_t i = 0; i < all.size(); ++i) {
    const Vec3 u = wrap_material_point(s, all[i]);
    out.row(i) = calc_point(s, u).transpose();
    if (material) material->row(i) = u.transpose();
  }
  return out;
}

Embedding embed_points(const SolidLocator& parent, const Points3& X) {
  const BSplineSolid& s = parent.get_solid();
  Embedding e;
  e.material.resize(X.rows(), 3);
  e.offset = Points3::Zero(X.rows(), 3);
  std::vector<Eigen::Triplet<double>> t;
  for (Eigen::Index r = 0; r < X.rows(); ++r) {
    const PointLocation loc = parent.locate(X.row(r).transpose());
    e.material.row(r) = loc.material.transpose();
    if (!loc.inside) {
      e.offset.row(r) = X.row(r) - loc.closest.transpose();
      ++e.num_outside;
    } else {
      e.offset.row(r) = X.row(r) - loc.closest.transpose();  // rounding-level residual
    }
    append_basis_row(s, loc.material, {0, 0, 0}, static_cast<int>(r), t);
  }
  e.weights.resize(X.rows(), s.num_control_points());
  e.weights.setFromTriplets(t.begin(), t.end());
  return e;
}

Points3 calc_embedded_positions(const Embedding& e, const Points3& P) {
  if (P.rows() != e.weights.cols()) {
    throw_usage(fmt::format("embedding: {} parent control points given, {} expected", P.rows(),
                            e.weights.cols()));
  }
  return e.weights * P + e.offset;
}

TriMesh calc_embedded_mesh(const Embedding& e, const TriMesh& rest, const Points3& P) {
  if (rest.V.rows() != e.material.rows()) throw_usage("embedding: mesh and embedding differ in size");
  return TriMesh{calc_embedded_positions(e, P), rest.F};
}

BSplineSolid calc_embedded_child(const Embedding& e, const BSplineSolid& child_rest,
                                 const Points3& P) {
  if (child_rest.P.rows() != e.material.rows()) {
    throw_usage("embedding: the child's control points were not the embedded points");
  }
  BSplineSolid c = child_rest;
  c.P = calc_embedded_positions(e, P);
  return c;
}

}  // namespace fascicle
