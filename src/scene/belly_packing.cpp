// Packing of generated bellies at the rest pose (docs/opensim-volumes.md, "Packing").
#include "fascicle/scene/belly_packing.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/mesh_validation.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>

namespace fascicle {

Vec3 BellyShape::calc_vertex(Eigen::Index v) const {
  return centres.row(v).transpose() + scale(v) * offsets.row(v).transpose();
}

Points3 BellyShape::calc_vertices() const {
  Points3 V(centres.rows(), 3);
  for (Eigen::Index v = 0; v < V.rows(); ++v)
    for (int c = 0; c < 3; ++c) V(v, c) = centres(v, c) + scale(v) * offsets(v, c);
  return V;
}

BellyShape make_belly_shape(const Points3& centreline, double volume_m3, int rings, int segments, int fibres,
                            double pennation_rad) {
  if (!(volume_m3 > 0.0) || !std::isfinite(volume_m3))
    throw_bad_input("a generated muscle belly needs a positive, finite volume");
  if (segments < 3 || rings < 1) throw_usage("a generated belly needs >= 3 segments and >= 1 ring");
  const int n = rings, s = segments;
  BellyShape b;
  b.rings = n;
  b.segments = s;
  b.fibres = fibres;
  b.pennation_rad = pennation_rad;
  b.volume_m3 = volume_m3;
  b.line = calc_framed_line(centreline, n + 2, calc_default_start_frame(centreline));
  // Unit-radius offsets D and centres C: vertex = C + R D. Vertex 0 and the last are the tips.
  const int nv = n * s + 2;
  Points3 C(nv, 3), D = Points3::Zero(nv, 3);
  C.row(0) = b.line.points.row(0);
  C.row(nv - 1) = b.line.points.row(n + 1);
  for (int k = 1; k <= n; ++k) {
    const double u = static_cast<double>(k) / (n + 1);
    const double r = std::sqrt(std::sin(M_PI * u));
    const Mat3 R = b.line.frames[k].toRotationMatrix();
    for (int j = 0; j < s; ++j) {
      const double phi = 2.0 * M_PI * j / s;
      const int v = 1 + (k - 1) * s + j;
      C.row(v) = b.line.points.row(k);
      D.row(v) = (r * (std::cos(phi) * R.col(1) + std::sin(phi) * R.col(2))).transpose();
    }
  }
  Triangles F(2 * s * n, 3);
  int f = 0;
  for (int j = 0; j < s; ++j) {
    const int j1 = (j + 1) % s;
    F.row(f++) << 0, 1 + j1, 1 + j;
    F.row(f++) << nv - 1, 1 + (n - 1) * s + j, 1 + (n - 1) * s + j1;
    for (int k = 1; k < n; ++k) {
      const int a = 1 + (k - 1) * s, c = 1 + k * s;
      F.row(f++) << a + j, a + j1, c + j1;
      F.row(f++) << a + j, c + j1, c + j;
    }
  }
  const Vec3 centre = C.colwise().mean().transpose();
  const auto volume_at = [&](double R) { return calc_enclosed_volume((C + R * D).eval(), F, centre); };
  // Orientation: frames are right-handed (x tangent), so the fan above winds outward; check anyway.
  if (volume_at(1.0) < 0.0) F.col(1).swap(F.col(2));
  // V(R) is a cubic in R (a quadratic for a straight line): Newton from the straight-line value.
  double R = std::sqrt(volume_m3 / volume_at(1.0));
  for (int it = 0; it < 30; ++it) {
    const double v = volume_at(R);
    if (std::abs(v - volume_m3) <= 1e-12 * volume_m3) break;
    const double h = 1e-6 * R;
    const double dv = (volume_at(R + h) - volume_at(R - h)) / (2.0 * h);
    if (!(dv > 0.0)) throw_numerical("generated belly: the volume does not grow with the radius (line too curved)");
    R -= (v - volume_m3) / dv;
  }
  if (!(R > 0.0) || std::abs(volume_at(R) - volume_m3) > 1e-9 * volume_m3)
    throw_numerical("generated belly: could not reach the requested volume");
  b.centres = std::move(C);
  b.offsets = std::move(D);
  b.scale = VecX::Constant(nv, R);
  b.F = std::move(F);
  b.R = R;
  return b;
}

namespace {

// Radius of ring k's polygonal section (k in 1..rings) in the direction at angle phi of the ring's
// frame: where the ray from the centre meets the edge between the two vertices around phi.
double calc_section_radius(const BellyShape& b, int k, double phi) {
  const int s = b.segments;
  const double step = 2.0 * M_PI / s;
  double a = std::fmod(phi, 2.0 * M_PI);
  if (a < 0.0) a += 2.0 * M_PI;
  const int j = std::min(static_cast<int>(a / step), s - 1);
  const int j1 = (j + 1) % s;
  const int v0 = 1 + (k - 1) * s;
  const double r0 = b.scale(v0 + j) * b.offsets.row(v0 + j).norm();
  const double r1 = b.scale(v0 + j1) * b.offsets.row(v0 + j1).norm();
  const double t0 = step * j, t1 = step * (j + 1);
  const double p1x = r0 * std::cos(t0), p1y = r0 * std::sin(t0), p2x = r1 * std::cos(t1), p2y = r1 * std::sin(t1);
  const double dx = std::cos(a), dy = std::sin(a);
  const double num = p1x * p2y - p1y * p2x;
  const double den = dx * (p2y - p1y) - dy * (p2x - p1x);
  if (!(den > 0.0)) return std::min(r0, r1);
  return num / den;
}

}  // namespace

std::vector<Points3> calc_belly_fibres(const BellyShape& b) {
  const int n = b.rings;
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  const double length = b.line.length_m;
  std::vector<Points3> fibres;
  // A vertex of ring k (0, rings + 1: the tips) and the ring's shift from the path, linear in u.
  const auto ring_vertex = [&](int k) {
    return k == 0 ? 0 : (k == n + 1 ? static_cast<int>(b.centres.rows()) - 1 : 1 + (k - 1) * b.segments);
  };
  const auto shift_at = [&](double u) -> Vec3 {
    const double x = std::clamp(u, 0.0, 1.0) * (n + 1);
    const int k = std::min(static_cast<int>(x), n);
    const double t = x - k;
    const Vec3 s0 = (b.centres.row(ring_vertex(k)) - b.line.points.row(k)).transpose();
    const Vec3 s1 = (b.centres.row(ring_vertex(k + 1)) - b.line.points.row(k + 1)).transpose();
    return (1.0 - t) * s0 + t * s1;
  };
  // The rules above use the sections at the rings and interpolate between them; where the
  // triangulated surface between two very different rings runs inside that interpolation, the
  // point is drawn towards its axis point until it is inside (bisection on the fraction, then 2 %
  // further in).
  const MeshQuery query(TriMesh{b.calc_vertices(), b.F});
  const auto keep_inside = [&](const Vec3& axis, const Vec3& offset) -> Vec3 {
    if (query.calc_is_inside(Vec3(axis + offset))) return axis + offset;
    double lo = 0.0, hi = 1.0;
    for (int it = 0; it < 40; ++it) (query.calc_is_inside(Vec3(axis + 0.5 * (lo + hi) * offset)) ? lo : hi) = 0.5 * (lo + hi);
    return axis + 0.98 * lo * offset;
  };
  // Local radius at normalised arc length u in direction phi: linear between rings, 0 at the tips.
  const auto radius_at = [&](double u, double phi) {
    const double x = std::clamp(u, 0.0, 1.0) * (n + 1);
    const int k = std::min(static_cast<int>(x), n);
    const double t = x - k;
    const double r0 = (k >= 1 && k <= n) ? calc_section_radius(b, k, phi) : 0.0;
    const double r1 = (k + 1 >= 1 && k + 1 <= n) ? calc_section_radius(b, k + 1, phi) : 0.0;
    return (1.0 - t) * r0 + t * r1;
  };
  if (b.pennation_rad > 5.0 * M_PI / 180.0) {
    const double ca = std::cos(b.pennation_rad), sa = std::sin(b.pennation_rad);
    for (int i = 0; i < b.fibres; ++i) {
      const double u0 = 0.2 + 0.75 * (i + 0.5) / b.fibres;
      const double phi = i * golden;
      const auto gap = [&](double tau) { return tau * sa - 0.95 * radius_at(u0 - tau * ca / length, phi); };
      // The first crossing (the radius may dip and rise again along the fibre): scan, then bisect.
      double lo = 0.0, hi = u0 * length / ca;
      const int scan = 8 * (n + 1);
      for (int k = 1; k <= scan; ++k) {
        const double tau = hi * k / scan;
        if (gap(tau) >= 0.0) {
          hi = tau;
          break;
        }
        lo = tau;
      }
      for (int it = 0; it < 60; ++it) (gap(0.5 * (lo + hi)) < 0.0 ? lo : hi) = 0.5 * (lo + hi);
      const int samples = 8;
      Points3 fibre(samples, 3);
      for (int k = 0; k < samples; ++k) {
        const double tau = hi * k / (samples - 1);
        const double u = u0 - tau * ca / length;
        const LinePoint lp = calc_line_point(b.line, u);
        const Mat3 F = lp.frame.toRotationMatrix();
        fibre.row(k) = keep_inside(lp.point + shift_at(u), tau * sa * (std::cos(phi) * F.col(1) + std::sin(phi) * F.col(2))).transpose();
      }
      fibres.push_back(std::move(fibre));
    }
    return fibres;
  }
  for (int i = 0; i < b.fibres; ++i) {
    const double rho = 0.9 * std::sqrt((i + 0.5) / b.fibres);
    const double phi = i * golden;
    Points3 fibre(n + 2, 3);
    for (int k = 0; k < n + 2; ++k) {
      const double r = (k >= 1 && k <= n) ? rho * calc_section_radius(b, k, phi) : 0.0;
      const Mat3 F = b.line.frames[k].toRotationMatrix();
      fibre.row(k) = keep_inside(b.centres.row(ring_vertex(k)).transpose(), r * (std::cos(phi) * F.col(1) + std::sin(phi) * F.col(2))).transpose();
    }
    fibres.push_back(std::move(fibre));
  }
  return fibres;
}

namespace {

Eigen::AlignedBox3d calc_box(const Points3& V) {
  return Eigen::AlignedBox3d(V.colwise().minCoeff().transpose(), V.colwise().maxCoeff().transpose());
}

// A segment of a belly's centreline with a radius that bounds its surface there: every triangle
// between rings k and k+1 has its vertices within max(r_k, r_k+1) of the segment [c_k, c_k+1]
// (r_k: the largest vertex distance of ring k from its centre, 0 at the tips), so, the distance to
// a convex set being convex, the whole triangle does. A point farther than that from every segment
// of a (non-looping) tube lies outside it: the cheap first test before the ray test.
struct Capsule {
  Vec3 a, b;
  double r = 0.0;
};

std::vector<Capsule> make_capsules(const BellyShape& b) {
  const int n = b.rings, s = b.segments;
  const auto nv = b.centres.rows();
  std::vector<Vec3> c(static_cast<size_t>(n + 2));
  std::vector<double> r(static_cast<size_t>(n + 2), 0.0);
  c[0] = b.centres.row(0).transpose();
  c[n + 1] = b.centres.row(nv - 1).transpose();
  for (int k = 1; k <= n; ++k) {
    c[k] = b.centres.row(1 + (k - 1) * s).transpose();
    for (int j = 0; j < s; ++j) {
      const int v = 1 + (k - 1) * s + j;
      r[k] = std::max(r[k], b.scale(v) * b.offsets.row(v).norm());
    }
  }
  std::vector<Capsule> out;
  for (int k = 0; k <= n; ++k) out.push_back({c[k], c[k + 1], std::max(r[k], r[k + 1])});
  return out;
}

bool is_near_capsules(const std::vector<Capsule>& capsules, const Vec3& x, double pad) {
  for (const Capsule& c : capsules) {
    const Vec3 ab = c.b - c.a;
    const double len2 = ab.squaredNorm();
    const double t = len2 > 0.0 ? std::clamp((x - c.a).dot(ab) / len2, 0.0, 1.0) : 0.0;
    const double lim = c.r * (1.0 + 1e-9) + pad;
    if ((x - c.a - t * ab).squaredNorm() <= lim * lim) return true;
  }
  return false;
}

// Inside a closed, outward, manifold mesh: the signed crossing count of one ray (the winding
// number); a ray grazing an edge falls back to the query's vote.
bool is_inside(const MeshQuery& q, const Vec3& x) {
  static const Vec3 dir = Vec3(0.2672612419124244, 0.5345224838248488, 0.8017837257372732);
  if (const auto w = q.calc_crossing_number(x, dir)) return *w > 0;
  return q.calc_is_inside(x);
}

// A snapshot of every solid: belly queries first, then obstacles.
struct Solids {
  std::vector<const MeshQuery*> query;
  std::vector<Eigen::AlignedBox3d> box;
  std::vector<std::vector<Capsule>> capsules;  // bellies only
  std::vector<char> frozen;  // per belly: held fixed (a belly re-packed alone against the others); empty: none
};

// The solids of a snapshot: a query of each belly at its current vertices (kept in V) and of each
// obstacle, their boxes and the bellies' capsules; `owned` keeps the queries alive.
Solids make_solids(const std::vector<BellyShape>& bellies, const std::vector<PackingObstacle>& obstacles,
                   std::vector<Points3>& V, std::vector<std::unique_ptr<MeshQuery>>& owned) {
  const size_t nb = bellies.size(), ns = nb + obstacles.size();
  V.resize(nb);
  owned.resize(ns);
  Solids solids;
  solids.query.resize(ns);
  solids.box.resize(ns);
  solids.capsules.resize(nb);
  parallel_for(ns, [&](size_t i) {
    if (i < nb) {
      V[i] = bellies[i].calc_vertices();
      owned[i] = std::make_unique<MeshQuery>(TriMesh{V[i], bellies[i].F});
      solids.box[i] = calc_box(V[i]);
      solids.capsules[i] = make_capsules(bellies[i]);
    } else {
      owned[i] = std::make_unique<MeshQuery>(obstacles[i - nb].mesh);
      solids.box[i] = calc_box(obstacles[i - nb].mesh.V);
    }
    solids.query[i] = owned[i].get();
  });
  return solids;
}

// What one belly sees in a snapshot: per vertex the radial push (m) it needs, per solid the deepest
// vertex inside it, and whether a tip (which cannot move radially) is inside something.
struct RemotePush {
  int belly = 0;
  int vertex = 0;
  double push_m = 0.0;
};
struct BellyHits {
  VecX push;
  std::vector<double> depth;  // per solid
  std::vector<RemotePush> remote;  // pushes on the vertices of the other bellies' faces
  bool tip_inside = false;
  Vec3 tip_move[2] = {Vec3::Zero(), Vec3::Zero()};  // wanted moves of the origin and insertion tips
};

// What one belly sees of one other solid.
struct PairHit {
  int solid = -1;
  double depth = 0.0;
  std::vector<std::pair<int, double>> push;  // (vertex, radial push)
  std::vector<RemotePush> remote;
  bool tip_inside = false;
  Vec3 tip_move[2] = {Vec3::Zero(), Vec3::Zero()};
};

PairHit calc_pair_hit(const BellyShape& b, const Points3& V, int self, int j, int num_bellies, const Solids& solids,
                      const BellyPackingOptions& o) {
  PairHit h;
  h.solid = j;
  const bool other_is_belly = j < num_bellies;
  // A frozen belly neither moves nor takes a share: what it touches takes all of the push; a frozen
  // belly against an obstacle or another frozen belly is not looked at.
  const bool self_frozen = !solids.frozen.empty() && solids.frozen[self];
  const bool other_frozen = !other_is_belly || (!solids.frozen.empty() && solids.frozen[j]);
  if (self_frozen && other_frozen) return h;
  const bool other_yields = other_is_belly && !other_frozen;
  const MeshQuery& q = *solids.query[j];
  const double lowest = o.min_scale_fraction * b.R;
  for (Eigen::Index v = 0; v < V.rows(); ++v) {
    const Vec3 x = V.row(v).transpose();
    if (!solids.box[j].contains(x)) continue;
    if (other_is_belly && !is_near_capsules(solids.capsules[j], x, 1e-9)) continue;
    if (!is_inside(q, x)) continue;
    const ClosestPoint cp = q.calc_closest_point(x);
    h.depth = std::max(h.depth, cp.distance);
    const double r = b.scale(v) * b.offsets.row(v).norm();
    const bool stuck = !(r > 0.0) || b.scale(v) <= lowest;  // a tip, or squeezed to the minimum
    if (!(r > 0.0)) {
      // A tip cannot move radially: it moves (with the ring shifts) towards the surface.
      h.tip_inside = true;
      if (cp.distance > 0.0) {
        const Vec3 move = (cp.point - x) * (((other_yields ? 0.5 : 1.0) * cp.distance + o.margin_m) / cp.distance);
        Vec3& t = h.tip_move[v == 0 ? 0 : 1];
        if (move.norm() > t.norm()) t = move;
      }
    }
    // Belly–belly: the vertex and the face it is in each take half (the face all of it when the
    // vertex cannot move). Belly–bone: the vertex takes all.
    const double own_share = other_yields ? 0.5 : 1.0;
    if (r > 0.0) {
      // Radial depth: from the vertex towards its centre to where it leaves the other solid (a
      // squeezed vertex cannot take it, but its push still shifts its section).
      const Vec3 dir = -b.offsets.row(v).transpose().normalized();
      const auto hit = q.cast_ray(x, dir, 0.0, r);
      const double radial = hit ? hit->t : r;
      h.push.emplace_back(static_cast<int>(v), own_share * radial + o.margin_m);
    }
    if (other_yields) {
      // The face: the smallest vertex moves that move the closest point by the face's share.
      const double amount = (stuck || self_frozen ? 1.0 : 0.5) * cp.distance + o.margin_m;
      const Vec3 w = cp.barycentric;
      const double w2 = w.squaredNorm();
      for (int c = 0; c < 3; ++c)
        if (w(c) > 0.0) h.remote.push_back({j, q.get_mesh().F(cp.triangle, c), amount * std::min(1.0, w(c) / w2)});
    }
  }
  return h;
}

// Belly `self` against every solid whose box meets its own. `cache` (optional) holds the previous
// iteration's pair results; a pair neither of whose solids moved since (moved[j] == 0) is reused.
BellyHits calc_hits(const BellyShape& b, const Points3& V, int self, int num_bellies, const Solids& solids,
                    const BellyPackingOptions& o, std::vector<PairHit>* cache, const std::vector<char>* moved) {
  BellyHits h;
  h.push = VecX::Zero(V.rows());
  h.depth.assign(solids.query.size(), 0.0);
  const Eigen::AlignedBox3d own = calc_box(V);
  std::vector<PairHit> pairs;
  size_t c = 0;
  for (int j = 0; j < static_cast<int>(solids.query.size()); ++j) {
    if (j == self || !own.intersects(solids.box[j])) continue;
    while (cache && c < cache->size() && (*cache)[c].solid < j) ++c;
    const bool reuse = cache && moved && c < cache->size() && (*cache)[c].solid == j && !(*moved)[self] &&
                       (j >= num_bellies || !(*moved)[j]);
    PairHit p = reuse ? std::move((*cache)[c]) : calc_pair_hit(b, V, self, j, num_bellies, solids, o);
    if (p.depth > 0.0) pairs.push_back(std::move(p));
  }
  for (const PairHit& p : pairs) {
    h.depth[p.solid] = p.depth;
    for (const auto& [v, push] : p.push) h.push(v) = std::max(h.push(v), push);
    h.remote.insert(h.remote.end(), p.remote.begin(), p.remote.end());
    h.tip_inside = h.tip_inside || p.tip_inside;
    for (int t = 0; t < 2; ++t)
      if (p.tip_move[t].norm() > h.tip_move[t].norm()) h.tip_move[t] = p.tip_move[t];
  }
  if (cache) *cache = std::move(pairs);
  return h;
}

std::vector<PackingContact> list_contacts(const std::vector<BellyShape>& bellies,
                                          const std::vector<PackingObstacle>& obstacles,
                                          const std::vector<BellyHits>& hits) {
  std::vector<PackingContact> out;
  for (size_t i = 0; i < hits.size(); ++i)
    for (size_t j = 0; j < hits[i].depth.size(); ++j)
      if (hits[i].depth[j] > 0.0)
        out.push_back({bellies[i].name, j < bellies.size() ? bellies[j].name : obstacles[j - bellies.size()].name,
                       hits[i].depth[j]});
  std::stable_sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.depth_m > b.depth_m; });
  return out;
}

// Scales the free vertices' scale by one factor s so the belly encloses its volume, no vertex
// growing beyond `cap` (a vertex already above it is left as it is): V(s) is continuous and
// non-decreasing, solved by Newton safeguarded by bisection on [0, s_max]. False (and the belly
// unchanged) when even s_max cannot reach the volume.
bool restore_volume(BellyShape& b, const std::vector<char>& free, const VecX& cap) {
  const Vec3 centre = b.centres.colwise().mean().transpose();
  const VecX base = b.scale;
  double s_max = 1.0;
  bool unbounded = false;  // a free vertex without a cap
  for (Eigen::Index v = 0; v < base.size(); ++v) {
    if (!free[v]) continue;
    if (!std::isfinite(cap(v))) unbounded = true;
    else if (base(v) > 0.0 && base(v) < cap(v)) s_max = std::max(s_max, cap(v) / base(v));
  }
  const auto scaled = [&](double s) {
    VecX out = base;
    for (Eigen::Index v = 0; v < out.size(); ++v)
      if (free[v] && base(v) < cap(v)) out(v) = std::min(s * base(v), cap(v));
    return out;
  };
  BellyShape t;
  t.centres = b.centres;
  t.offsets = b.offsets;
  const auto volume_at = [&](double s) {
    t.scale = scaled(s);
    return calc_enclosed_volume(t.calc_vertices(), b.F, centre);
  };
  if (unbounded)  // uncapped: double until the volume is enclosed (V grows without bound)
    for (int k = 0; k < 60 && volume_at(s_max) < b.volume_m3; ++k) s_max *= 2.0;
  double lo = 0.0, hi = s_max;  // V(1) may exceed the volume (ring shifts change it too)
  if (!(volume_at(hi) >= b.volume_m3)) return false;
  double s = 1.0;
  for (int it = 0; it < 60; ++it) {
    const double v = volume_at(s);
    if (std::abs(v - b.volume_m3) <= 1e-12 * b.volume_m3) break;
    (v < b.volume_m3 ? lo : hi) = s;
    const double h = 1e-7 * s;
    const double dv = (volume_at(s + h) - volume_at(s - h)) / (2.0 * h);
    double next = dv > 0.0 ? s - (v - b.volume_m3) / dv : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    s = next;
  }
  if (std::abs(volume_at(s) - b.volume_m3) > 1e-9 * b.volume_m3) return false;
  b.scale = scaled(s);
  return true;
}

}  // namespace

std::vector<PackingContact> calc_packing_contacts(const std::vector<BellyShape>& bellies,
                                                  const std::vector<PackingObstacle>& obstacles) {
  const size_t nb = bellies.size();
  std::vector<Points3> V;
  std::vector<std::unique_ptr<MeshQuery>> owned;
  const Solids solids = make_solids(bellies, obstacles, V, owned);
  std::vector<BellyHits> hits(nb);
  parallel_for(nb, [&](size_t i) {
    hits[i] = calc_hits(bellies[i], V[i], static_cast<int>(i), static_cast<int>(nb), solids, {}, nullptr, nullptr);
  });
  return list_contacts(bellies, obstacles, hits);
}

namespace {

// Where a belly's crossing faces are, for the debug log: "tip" for the tip fans, "k-k+1" for the
// band between rings k and k+1 (faces are laid out per segment: two tip faces, then the bands).
std::string describe_faces(const BellyShape& b, const FacePairs& pairs) {
  std::vector<int> bands;  // -1: a tip fan
  for (const auto& p : pairs)
    for (int f : p) {
      const int r = f % (2 * b.rings);
      bands.push_back(r < 2 ? -1 : (r - 2) / 2 + 1);
    }
  std::sort(bands.begin(), bands.end());
  bands.erase(std::unique(bands.begin(), bands.end()), bands.end());
  std::string out;
  for (int k : bands) out += (out.empty() ? "" : ", ") + (k < 0 ? std::string("tip") : fmt::format("{}-{}", k, k + 1));
  return out;
}

constexpr int kSectionWindow = 6;  // rings each side that keep_sections_apart checks

PackingReport pack_bellies_impl(std::vector<BellyShape>& bellies, const std::vector<PackingObstacle>& obstacles,
                                const BellyPackingOptions& o, bool check_folds, const std::vector<char>& frozen);

}  // namespace

PackingReport pack_bellies(std::vector<BellyShape>& bellies, const std::vector<PackingObstacle>& obstacles,
                           const BellyPackingOptions& o) {
  return pack_bellies_impl(bellies, obstacles, o, true, {});
}

namespace {

PackingReport pack_bellies_impl(std::vector<BellyShape>& bellies, const std::vector<PackingObstacle>& obstacles,
                                const BellyPackingOptions& o, bool check_folds, const std::vector<char>& frozen) {
  const size_t nb = bellies.size();
  PackingReport report;
  std::vector<VecX> scale0(nb);
  std::vector<Points3> centres0(nb);
  for (size_t i = 0; i < nb; ++i) {
    scale0[i] = bellies[i].scale;
    centres0[i] = bellies[i].centres;
  }
  std::vector<Points3> V;
  std::vector<std::unique_ptr<MeshQuery>> owned;
  Solids solids = make_solids(bellies, obstacles, V, owned);
  solids.frozen = frozen;
  std::vector<std::vector<int>> contact(nb);  // per vertex: the last iteration that pushed it (-1: none)
  std::vector<std::vector<char>> squeezed(nb);
  for (size_t i = 0; i < nb; ++i) {
    contact[i].assign(static_cast<size_t>(V[i].rows()), -1);
    squeezed[i].assign(static_cast<size_t>(V[i].rows()), 0);
  }
  std::vector<BellyHits> hits(nb);
  std::vector<char> all_in_contact(nb, 0);
  std::vector<std::vector<PairHit>> cache(nb);
  std::vector<char> moved(nb, 1);  // per belly: changed by the last iteration
  for (int it = 0;; ++it) {
    parallel_for(nb, [&](size_t i) {
      hits[i] = calc_hits(bellies[i], V[i], static_cast<int>(i), static_cast<int>(nb), solids, o, &cache[i],
                          it == 0 ? nullptr : &moved);
    });
    if (it == 0) report.before = list_contacts(bellies, obstacles, hits);
    double deepest = 0.0;
    for (const BellyHits& h : hits)
      for (double d : h.depth) deepest = std::max(deepest, d);
    report.iterations = it;
    spdlog::debug("belly packing: iteration {}: deepest overlap {:.3f} mm", it, 1e3 * deepest);
    if (deepest <= o.tolerance_m) break;
    if (it >= o.max_iterations) {
      report.converged = false;
      break;
    }
    // Pushes on faces, gathered in a fixed order (deterministic).
    for (size_t i = 0; i < nb; ++i)
      for (const RemotePush& r : hits[i].remote) {
        const double radial = bellies[r.belly].offsets.row(r.vertex).norm();
        if (radial > 0.0) hits[r.belly].push(r.vertex) = std::max(hits[r.belly].push(r.vertex), r.push_m);
      }
    std::fill(moved.begin(), moved.end(), 0);
    parallel_for(nb, [&](size_t i) {
      if (!frozen.empty() && frozen[i]) return;
      BellyShape& b = bellies[i];
      const BellyHits& h = hits[i];
      if (!(h.push.array() > 0.0).any() && h.tip_move[0].squaredNorm() == 0.0 && h.tip_move[1].squaredNorm() == 0.0)
        return;
      const int s = b.segments, n = b.rings;
      const auto nv = b.scale.size();
      // Held vertices: pushed in one of the last few iterations (not scaled by the volume restore).
      std::vector<int>& last_push = contact[i];
      std::vector<char> in_contact(static_cast<size_t>(nv), 0);
      for (Eigen::Index v = 0; v < nv; ++v) in_contact[v] = last_push[v] >= 0 && it - last_push[v] < o.hold_iterations;
      const double lowest = o.min_scale_fraction * b.R;
      VecX push = h.push;
      // Ring shifts: a section pushed on one side moves away as a whole by half the mean push
      // (smoothed along the rings, kept in the section plane, at most R from the path); the pushes
      // left for its vertices are what the shift did not do.
      Points3 delta = Points3::Zero(n + 2, 3);
      delta.row(0) = 0.5 * h.tip_move[0].transpose();
      delta.row(n + 1) = 0.5 * h.tip_move[1].transpose();
      for (int k = 1; k <= n; ++k) {
        Vec3 sum = Vec3::Zero();
        int count = 0;
        for (int j = 0; j < s; ++j) {
          const int v = 1 + (k - 1) * s + j;
          if (push(v) > 0.0) {
            sum -= push(v) * b.offsets.row(v).transpose().normalized();
            ++count;
          }
        }
        if (count > 0) delta.row(k) = (0.5 / count) * sum.transpose();
      }
      if (o.shift_rings && delta.squaredNorm() > 0.0) {
        Points3 smooth = delta;
        for (int k = 0; k <= n + 1; ++k) {
          const int a = std::max(k - 1, 0), c = std::min(k + 1, n + 1);
          smooth.row(k) = 0.5 * delta.row(k) + 0.25 * (delta.row(a) + delta.row(c));
        }
        // The new shifts: in the section plane, at most max_shift_fraction R from the path, and
        // changing by at most max_shift_slope per unit length between neighbouring rings so the
        // sections never cross each other (two passes of a slope limiter).
        const auto first_vertex = [&](int k) { return k == 0 ? 0 : (k == n + 1 ? static_cast<int>(nv) - 1 : 1 + (k - 1) * s); };
        Points3 shift(n + 2, 3), next(n + 2, 3);
        for (int k = 0; k <= n + 1; ++k) {
          shift.row(k) = b.centres.row(first_vertex(k)) - b.line.points.row(k);
          Vec3 d = smooth.row(k).transpose();
          const Vec3 tangent = b.line.frames[k].toRotationMatrix().col(0);  // tips too: never along the axis
          d -= d.dot(tangent) * tangent;
          Vec3 x = shift.row(k).transpose() + d;
          if (x.norm() > o.max_shift_fraction * b.R) x *= o.max_shift_fraction * b.R / x.norm();
          next.row(k) = x.transpose();
        }
        const double step = o.max_shift_slope * b.line.length_m / (n + 1);
        const auto limit = [&](int k, int from) {
          const Vec3 diff = (next.row(k) - next.row(from)).transpose();
          if (diff.norm() > step) next.row(k) = next.row(from) + (diff * (step / diff.norm())).transpose();
        };
        for (int k = 1; k <= n + 1; ++k) limit(k, k - 1);
        for (int k = n; k >= 0; --k) limit(k, k + 1);
        for (int k = 0; k <= n + 1; ++k) {
          const int first = first_vertex(k);
          const int count = (k == 0 || k == n + 1) ? 1 : s;
          const Vec3 d = (next.row(k) - shift.row(k)).transpose();
          if (!(d.squaredNorm() > 0.0)) continue;
          for (int v = first; v < first + count; ++v) {
            b.centres.row(v) += d.transpose();
            if (push(v) > 0.0) {
              const double along = -d.dot(b.offsets.row(v).transpose().normalized());
              push(v) = std::max(push(v) - along, 0.0);
              in_contact[v] = 1;
              last_push[v] = it;
            }
          }
        }
      }
      for (Eigen::Index v = 0; v < nv; ++v) {
        if (!(push(v) > 0.0)) continue;
        const double wanted = b.scale(v) - push(v) / b.offsets.row(v).norm();
        if (wanted < lowest) squeezed[i][v] = 1;
        b.scale(v) = std::min(b.scale(v), std::max(wanted, lowest));
        in_contact[v] = 1;
        last_push[v] = it;
      }
      // Taper: a free vertex next to a contact vertex comes down to at most the mean of itself and
      // its four grid neighbours' mean (lowering only, one pass), so a contact leaves a dent, not a
      // ridge; vertices further away keep their profile.
      const VecX old = b.scale;
      for (int k = 1; k <= n; ++k)
        for (int j = 0; j < s; ++j) {
          const int v = 1 + (k - 1) * s + j;
          if (in_contact[v]) continue;
          const int nb4[4] = {1 + (k - 1) * s + (j + 1) % s, 1 + (k - 1) * s + (j + s - 1) % s,
                              k > 1 ? v - s : -1, k < n ? v + s : -1};
          bool near = false;
          double sum = 0.0;
          int count = 0;
          for (int q : nb4) {
            if (q < 0) continue;
            near = near || in_contact[q];
            sum += old(q);
            ++count;
          }
          if (near) b.scale(v) = std::min(old(v), 0.5 * (old(v) + sum / count));
        }
      std::vector<char> free(static_cast<size_t>(nv), 0);
      bool any_free = false;
      for (Eigen::Index v = 1; v + 1 < nv; ++v) {
        free[v] = in_contact[v] ? 0 : 1;
        any_free = any_free || free[v];
      }
      VecX cap = VecX::Constant(nv, o.max_growth * b.R);
      if (o.keep_sections_apart) {
        // Each section stays behind the planes of the next kSectionWindow rings and ahead of those
        // of the previous ones (with a tenth of the gap spare), so sections cannot cross each other
        // where the belly bends.
        const auto centre = [&](int k) -> Vec3 {
          return b.centres.row(k == 0 ? 0 : (k == n + 1 ? static_cast<int>(nv) - 1 : 1 + (k - 1) * s)).transpose();
        };
        for (int k = 1; k <= n; ++k)
          for (int j = 0; j < s; ++j) {
            const int v = 1 + (k - 1) * s + j;
            const double len = b.offsets.row(v).norm();
            if (!(len > 0.0)) continue;
            const Vec3 u = b.offsets.row(v).transpose() / len;
            double r_max = std::numeric_limits<double>::infinity();
            for (int m = std::max(k - kSectionWindow, 0); m <= std::min(k + kSectionWindow, n + 1); ++m) {
              if (m == k) continue;
              // Behind ring m's plane (m > k) or ahead of it (m < k): sign * (x - c_m) . t_m < 0.
              const double sign = m > k ? 1.0 : -1.0;
              const Vec3 t = b.line.frames[m].toRotationMatrix().col(0);
              const double along = sign * u.dot(t);
              if (along > 0.0) r_max = std::min(r_max, 0.9 * std::max(sign * (centre(m) - centre(k)).dot(t), 0.0) / along);
            }
            const double limit = std::max(r_max / len, lowest);
            cap(v) = std::min(cap(v), limit);
            b.scale(v) = std::min(b.scale(v), limit);
          }
      }
      if (!any_free || !restore_volume(b, free, cap)) {
        // Nothing left to grow (or the free part cannot hold the volume): every vertex grows,
        // contacts included; the overlap that leaves is reported at the end.
        all_in_contact[i] = 1;
        for (Eigen::Index v = 1; v + 1 < nv; ++v) free[v] = 1;
        if (!restore_volume(b, free, cap) &&
            !restore_volume(b, free, VecX::Constant(nv, std::numeric_limits<double>::infinity())))
          throw_numerical("belly packing: could not restore the volume", {.object = b.name});
      }
      moved[i] = 1;
      V[i] = b.calc_vertices();
      owned[i]->update_vertices(V[i]);
      solids.box[i] = calc_box(V[i]);
      solids.capsules[i] = make_capsules(b);
    });
  }
  report.after = list_contacts(bellies, obstacles, hits);
  if (check_folds) {
    // Bellies packing made self-intersecting: clean unpacked, crossing faces now.
    std::vector<FacePairs> crossing(nb);
    parallel_for(nb, [&](size_t i) {
      const BellyShape& b = bellies[i];
      if (b.scale == scale0[i] && b.centres == centres0[i]) return;
      Points3 V0(b.centres.rows(), 3);
      for (Eigen::Index v = 0; v < V0.rows(); ++v) V0.row(v) = centres0[i].row(v) + scale0[i](v) * b.offsets.row(v);
      if (!calc_self_intersections(TriMesh{V0, b.F}).empty()) return;
      crossing[i] = calc_self_intersections(TriMesh{V[i], b.F});
    });
    for (size_t i = 0; i < nb; ++i) {
      if (crossing[i].empty()) continue;
      BellyShape& b = bellies[i];
      PackingFold fold;
      fold.name = b.name;
      fold.crossing_pairs = static_cast<int>(crossing[i].size());
      spdlog::debug("belly packing: {} has {} crossing face pairs (bands {})", b.name, crossing[i].size(),
                    describe_faces(b, crossing[i]));
      // Packed again alone, from its unpacked shape, against everything else held fixed.
      std::vector<char> others_fixed(nb, 1);
      others_fixed[i] = 0;
      struct Gentler {
        const char* what;
        double slope;
        bool shift;
        bool apart;
      };
      const Gentler tries[] = {
          {"a quarter of the ring shift slope", 0.25 * o.max_shift_slope, o.shift_rings, false},
          {"no ring shifts", o.max_shift_slope, false, false},
          {"a quarter of the ring shift slope and sections kept apart", 0.25 * o.max_shift_slope, o.shift_rings, true},
          {"no ring shifts and sections kept apart", o.max_shift_slope, false, true}};
      for (const Gentler& g : tries) {
        BellyPackingOptions og = o;
        og.max_shift_slope = g.slope;
        og.shift_rings = g.shift;
        og.keep_sections_apart = g.apart;
        std::vector<BellyShape> all = bellies;
        all[i].scale = scale0[i];
        all[i].centres = centres0[i];
        pack_bellies_impl(all, obstacles, og, false, others_fixed);
        std::vector<BellyShape> one{std::move(all[i])};
        const FacePairs left = calc_self_intersections(TriMesh{one[0].calc_vertices(), one[0].F});
        spdlog::debug("belly packing: {} re-packed with {}: {} crossing face pairs (bands {})", b.name, g.what,
                      left.size(), describe_faces(b, left));
        if (left.empty()) {
          b = std::move(one[0]);
          fold.remedy = g.what;
          break;
        }
      }
      if (fold.remedy.empty()) {
        b.scale = scale0[i];
        b.centres = centres0[i];
        fold.kept_unpacked = true;
      }
      V[i] = b.calc_vertices();
      report.folds.push_back(std::move(fold));
    }
    if (!report.folds.empty()) {
      report.after = calc_packing_contacts(bellies, obstacles);
      if (!report.after.empty() && report.after.front().depth_m > o.tolerance_m) report.converged = false;
      for (PackingFold& f : report.folds) {
        for (const PackingContact& c : report.after)
          if (c.a == f.name || c.b == f.name) f.overlap_m = std::max(f.overlap_m, c.depth_m);
        if (f.kept_unpacked)
          spdlog::warn("belly packing: {} keeps its unpacked shape: packing made its surface self-intersect ({} "
                       "face pairs) and re-packing it alone with gentler settings did not clear that; it overlaps "
                       "its neighbours by up to {:.2f} mm",
                       f.name, f.crossing_pairs, 1e3 * f.overlap_m);
        else
          spdlog::info("belly packing: {} re-packed alone with {} (packing had made {} of its face pairs cross); "
                       "deepest overlap {:.3f} mm",
                       f.name, f.remedy, f.crossing_pairs, 1e3 * f.overlap_m);
      }
    }
  }
  report.changed.assign(nb, false);
  report.max_radial_change_m.assign(nb, 0.0);
  report.mean_radial_change_m.assign(nb, 0.0);
  for (size_t i = 0; i < nb; ++i) {
    const BellyShape& b = bellies[i];
    double sum = 0.0;
    for (Eigen::Index v = 0; v < b.scale.size(); ++v) {
      const double d = (b.calc_vertex(v) - (centres0[i].row(v).transpose() + scale0[i](v) * b.offsets.row(v).transpose())).norm();
      sum += d;
      report.max_radial_change_m[i] = std::max(report.max_radial_change_m[i], d);
      report.changed[i] = report.changed[i] || b.scale(v) != scale0[i](v) || b.centres.row(v) != centres0[i].row(v);
    }
    report.mean_radial_change_m[i] = sum / static_cast<double>(b.scale.size());
  }
  if (!report.converged && check_folds) {  // (the re-packing of one belly stays quiet)
    // The pairs left above the tolerance (deepest first, at most 10), and why their bellies could
    // not get out.
    std::string list;
    std::vector<std::string> named;
    int shown = 0;
    for (const PackingContact& c : report.after) {
      if (c.depth_m <= o.tolerance_m || shown == 10) continue;
      list += fmt::format("{}{} in {} by {:.2f} mm", list.empty() ? "" : ", ", c.a, c.b, 1e3 * c.depth_m);
      ++shown;
      named.push_back(c.a);
    }
    for (size_t i = 0; i < nb; ++i) {
      if (std::find(named.begin(), named.end(), bellies[i].name) == named.end()) continue;
      const bool sq = std::any_of(squeezed[i].begin(), squeezed[i].end(), [](char c) { return c != 0; });
      if (hits[i].tip_inside || all_in_contact[i] || sq)
        list += fmt::format("; {}: {}", bellies[i].name,
                            hits[i].tip_inside    ? "a tip inside another solid"
                            : all_in_contact[i] ? "in contact all round"
                                                : "squeezed to the minimum radius somewhere");
    }
    spdlog::warn("belly packing stopped after {} iterations with overlaps above {:.2f} mm: {}", report.iterations,
                 1e3 * o.tolerance_m, list);
  }
  return report;
}

}  // namespace

}  // namespace fascicle
