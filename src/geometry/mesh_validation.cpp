#include "fascicle/geometry/mesh_validation.hpp"

#include "mesh_validation_internal.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"

#include <embree3/rtcore.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <mutex>
#include <numeric>
#include <sstream>

namespace fascicle {
namespace mesh_detail {

std::vector<char> find_topological_faces(const TriMesh& mesh) {
  const Eigen::Index nv = mesh.V.rows();
  std::vector<char> use(static_cast<std::size_t>(mesh.F.rows()), 0);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const int a = mesh.F(f, 0), b = mesh.F(f, 1), c = mesh.F(f, 2);
    const bool in_range = a >= 0 && b >= 0 && c >= 0 && a < nv && b < nv && c < nv;
    use[static_cast<std::size_t>(f)] = in_range && a != b && b != c && c != a;
  }
  return use;
}

std::vector<EdgeUse> collect_edge_uses(const TriMesh& mesh, const std::vector<char>& use) {
  std::vector<EdgeUse> uses;
  uses.reserve(3 * use.size());
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!use[static_cast<std::size_t>(f)]) continue;
    for (int k = 0; k < 3; ++k) {
      const int i = mesh.F(f, k), j = mesh.F(f, (k + 1) % 3);
      uses.push_back({std::min(i, j), std::max(i, j), static_cast<int>(f), i < j});
    }
  }
  std::sort(uses.begin(), uses.end(), [](const EdgeUse& x, const EdgeUse& y) {
    return std::tie(x.a, x.b, x.face) < std::tie(y.a, y.b, y.face);
  });
  return uses;
}

namespace {
int find_root(std::vector<int>& parent, int i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}
}  // namespace

std::vector<int> label_face_components(const TriMesh& mesh, const std::vector<char>& use,
                                       int& count) {
  std::vector<int> parent(static_cast<std::size_t>(mesh.V.rows()));
  std::iota(parent.begin(), parent.end(), 0);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!use[static_cast<std::size_t>(f)]) continue;
    const int r0 = find_root(parent, mesh.F(f, 0));
    for (int k = 1; k < 3; ++k) {
      const int r = find_root(parent, mesh.F(f, k));
      if (r != r0) parent[std::max(r, r0)] = std::min(r, r0);
    }
  }
  // labels in order of the first face of each component
  std::vector<int> label_of_root(parent.size(), -1);
  std::vector<int> labels(use.size(), -1);
  count = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!use[static_cast<std::size_t>(f)]) continue;
    const int r = find_root(parent, mesh.F(f, 0));
    if (label_of_root[r] < 0) label_of_root[r] = count++;
    labels[static_cast<std::size_t>(f)] = label_of_root[r];
  }
  return labels;
}

double calc_signed_volume(const TriMesh& mesh, const std::vector<char>& use) {
  Vec3 lo = Vec3::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  bool any = false;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!use[static_cast<std::size_t>(f)]) continue;
    for (int k = 0; k < 3; ++k) {
      const Vec3 p = mesh.V.row(mesh.F(f, k));
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
      any = true;
    }
  }
  if (!any) return 0.0;
  const Vec3 o = 0.5 * (lo + hi);
  double six_v = 0.0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!use[static_cast<std::size_t>(f)]) continue;
    const Vec3 a = mesh.V.row(mesh.F(f, 0)).transpose() - o;
    const Vec3 b = mesh.V.row(mesh.F(f, 1)).transpose() - o;
    const Vec3 c = mesh.V.row(mesh.F(f, 2)).transpose() - o;
    six_v += a.dot(b.cross(c));
  }
  return six_v / 6.0;
}

bool has_zero_area(const Vec3& a, const Vec3& b, const Vec3& c) {
  if (!a.allFinite() || !b.allFinite() || !c.allFinite()) return false;
  const double l2 = std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()});
  return (b - a).cross(c - a).norm() <= 16.0 * std::numeric_limits<double>::epsilon() * l2;
}

}  // namespace mesh_detail

// ---------------------------------------------------------------------------------------------
// Triangle-triangle intersection (own code after Moeller 1997's interval formulation).
namespace {

double orient2d(const Vec2& a, const Vec2& b, const Vec2& c) {
  return (b.x() - a.x()) * (c.y() - a.y()) - (b.y() - a.y()) * (c.x() - a.x());
}

int sign_of(double v) { return (v > 0.0) - (v < 0.0); }

// Closed segments p0p1 and q0q1 in 2D share a point.
bool segments_meet_2d(const Vec2& p0, const Vec2& p1, const Vec2& q0, const Vec2& q1) {
  const int o1 = sign_of(orient2d(p0, p1, q0)), o2 = sign_of(orient2d(p0, p1, q1));
  const int o3 = sign_of(orient2d(q0, q1, p0)), o4 = sign_of(orient2d(q0, q1, p1));
  if (o1 * o2 < 0 && o3 * o4 < 0) return true;
  const auto on_segment = [](const Vec2& a, const Vec2& b, const Vec2& p) {
    return p.x() >= std::min(a.x(), b.x()) && p.x() <= std::max(a.x(), b.x()) &&
           p.y() >= std::min(a.y(), b.y()) && p.y() <= std::max(a.y(), b.y());
  };
  return (o1 == 0 && on_segment(p0, p1, q0)) || (o2 == 0 && on_segment(p0, p1, q1)) ||
         (o3 == 0 && on_segment(q0, q1, p0)) || (o4 == 0 && on_segment(q0, q1, p1));
}

bool inside_triangle_2d(const Vec2& p, const std::array<Vec2, 3>& t) {
  const double d0 = orient2d(t[0], t[1], p), d1 = orient2d(t[1], t[2], p),
               d2 = orient2d(t[2], t[0], p);
  return (d0 >= 0 && d1 >= 0 && d2 >= 0) || (d0 <= 0 && d1 <= 0 && d2 <= 0);
}

bool coplanar_triangles_intersect(const std::array<Vec3, 3>& a, const std::array<Vec3, 3>& b,
                                  const Vec3& normal) {
  // drop the dominant axis of the normal
  int drop = 0;
  normal.cwiseAbs().maxCoeff(&drop);
  const int u = (drop + 1) % 3, v = (drop + 2) % 3;
  std::array<Vec2, 3> p, q;
  for (int k = 0; k < 3; ++k) {
    p[k] = Vec2(a[k][u], a[k][v]);
    q[k] = Vec2(b[k][u], b[k][v]);
  }
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) {
      if (segments_meet_2d(p[i], p[(i + 1) % 3], q[j], q[(j + 1) % 3])) return true;
    }
  }
  return inside_triangle_2d(p[0], q) || inside_triangle_2d(q[0], p);
}

// The interval that triangle t cuts on the line direction `dir`, given signed distances d of its
// corners to the other plane (not all of one strict sign).
std::array<double, 2> cut_interval(const std::array<Vec3, 3>& t, const std::array<double, 3>& d,
                                   const Vec3& dir) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  const auto add = [&](const Vec3& p) {
    const double s = dir.dot(p);
    lo = std::min(lo, s);
    hi = std::max(hi, s);
  };
  for (int i = 0; i < 3; ++i) {
    const int j = (i + 1) % 3;
    if (d[i] == 0.0) add(t[i]);
    if ((d[i] < 0.0 && d[j] > 0.0) || (d[i] > 0.0 && d[j] < 0.0)) {
      add(t[i] + (t[j] - t[i]) * (d[i] / (d[i] - d[j])));
    }
  }
  return {lo, hi};
}

}  // namespace

bool triangles_intersect(const Vec3& a0, const Vec3& a1, const Vec3& a2, const Vec3& b0,
                         const Vec3& b1, const Vec3& b2) {
  const std::array<Vec3, 3> a{a0, a1, a2}, b{b0, b1, b2};
  double longest = 0.0;
  for (int k = 0; k < 3; ++k) {
    longest = std::max({longest, (a[k] - a[(k + 1) % 3]).norm(), (b[k] - b[(k + 1) % 3]).norm()});
  }
  const Vec3 na = (a1 - a0).cross(a2 - a0), nb = (b1 - b0).cross(b2 - b0);
  // signed distances (times |n|) of one triangle's corners to the other's plane, snapped to 0
  const auto distances = [&](const std::array<Vec3, 3>& t, const Vec3& n, const Vec3& origin) {
    std::array<double, 3> d;
    const double tol = 1e-12 * n.norm() * longest;
    for (int k = 0; k < 3; ++k) {
      d[k] = n.dot(t[k] - origin);
      if (std::abs(d[k]) <= tol) d[k] = 0.0;
    }
    return d;
  };
  const auto one_side = [](const std::array<double, 3>& d) {
    return (d[0] > 0 && d[1] > 0 && d[2] > 0) || (d[0] < 0 && d[1] < 0 && d[2] < 0);
  };
  const std::array<double, 3> da = distances(a, nb, b0);
  if (one_side(da)) return false;
  const std::array<double, 3> db = distances(b, na, a0);
  if (one_side(db)) return false;
  const Vec3 dir = na.cross(nb);
  const bool coplanar = (da[0] == 0 && da[1] == 0 && da[2] == 0) ||
                        (db[0] == 0 && db[1] == 0 && db[2] == 0) ||
                        dir.norm() <= 1e-12 * na.norm() * nb.norm();
  if (coplanar) return coplanar_triangles_intersect(a, b, na);
  const auto ia = cut_interval(a, da, dir), ib = cut_interval(b, db, dir);
  return ia[1] >= ib[0] && ib[1] >= ia[0];
}

// ---------------------------------------------------------------------------------------------
// Self-intersections: Embree's collision of user-geometry boxes gives candidate pairs.
namespace {

struct CollideData {
  const TriMesh* mesh = nullptr;
  std::vector<int> faces;  // user primitive -> face
  std::mutex mutex;
  FacePairs candidates;
};

void face_bounds(const RTCBoundsFunctionArguments* args) {
  const auto* data = static_cast<const CollideData*>(args->geometryUserPtr);
  const int f = data->faces[args->primID];
  Vec3 lo = data->mesh->V.row(data->mesh->F(f, 0)), hi = lo;
  for (int k = 1; k < 3; ++k) {
    lo = lo.cwiseMin(data->mesh->V.row(data->mesh->F(f, k)).transpose());
    hi = hi.cwiseMax(data->mesh->V.row(data->mesh->F(f, k)).transpose());
  }
  // round outward so that the float box contains the double triangle
  const float inf = std::numeric_limits<float>::infinity();
  RTCBounds* out = args->bounds_o;
  out->lower_x = std::nextafter(static_cast<float>(lo.x()), -inf);
  out->lower_y = std::nextafter(static_cast<float>(lo.y()), -inf);
  out->lower_z = std::nextafter(static_cast<float>(lo.z()), -inf);
  out->upper_x = std::nextafter(static_cast<float>(hi.x()), inf);
  out->upper_y = std::nextafter(static_cast<float>(hi.y()), inf);
  out->upper_z = std::nextafter(static_cast<float>(hi.z()), inf);
}

void collect_candidates(void* user, RTCCollision* collisions, unsigned num) {
  auto* data = static_cast<CollideData*>(user);
  const Triangles& F = data->mesh->F;
  FacePairs local;
  for (unsigned c = 0; c < num; ++c) {
    const int i = data->faces[collisions[c].primID0], j = data->faces[collisions[c].primID1];
    if (i == j) continue;
    bool shared = false;
    for (int p = 0; p < 3 && !shared; ++p) {
      for (int q = 0; q < 3; ++q) shared = shared || F(i, p) == F(j, q);
    }
    if (!shared) local.push_back({std::min(i, j), std::max(i, j)});
  }
  if (local.empty()) return;
  const std::lock_guard<std::mutex> lock(data->mutex);
  data->candidates.insert(data->candidates.end(), local.begin(), local.end());
}

struct DeviceDeleter {
  void operator()(RTCDeviceTy* d) const { rtcReleaseDevice(d); }
};
struct SceneDeleter {
  void operator()(RTCSceneTy* s) const { rtcReleaseScene(s); }
};

}  // namespace

FacePairs calc_self_intersections(const TriMesh& mesh) {
  CollideData data;
  data.mesh = &mesh;
  const std::vector<char> topo = mesh_detail::find_topological_faces(mesh);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!topo[static_cast<std::size_t>(f)]) continue;
    bool finite = true;
    for (int k = 0; k < 3; ++k) finite = finite && mesh.V.row(mesh.F(f, k)).allFinite();
    if (finite) data.faces.push_back(static_cast<int>(f));
  }
  if (data.faces.size() < 2) return {};

  const std::unique_ptr<RTCDeviceTy, DeviceDeleter> device(rtcNewDevice(nullptr));
  if (!device) throw_internal("Embree device creation failed");
  const std::unique_ptr<RTCSceneTy, SceneDeleter> scene(rtcNewScene(device.get()));
  RTCGeometry geometry = rtcNewGeometry(device.get(), RTC_GEOMETRY_TYPE_USER);
  rtcSetGeometryUserPrimitiveCount(geometry, static_cast<unsigned>(data.faces.size()));
  rtcSetGeometryUserData(geometry, &data);
  rtcSetGeometryBoundsFunction(geometry, &face_bounds, nullptr);
  rtcCommitGeometry(geometry);
  rtcAttachGeometry(scene.get(), geometry);
  rtcReleaseGeometry(geometry);
  rtcCommitScene(scene.get());
  rtcCollide(scene.get(), scene.get(), &collect_candidates, &data);
  if (const RTCError err = rtcGetDeviceError(device.get()); err != RTC_ERROR_NONE) {
    throw_internal("Embree collision query failed (error " + std::to_string(err) + ")");
  }

  // exact decision per candidate pair, in a deterministic order
  FacePairs& cand = data.candidates;
  std::sort(cand.begin(), cand.end());
  cand.erase(std::unique(cand.begin(), cand.end()), cand.end());
  std::vector<char> hit(cand.size(), 0);
  parallel_for(cand.size(), [&](std::size_t n) {
    const auto corner = [&](int f, int k) -> Vec3 { return mesh.V.row(mesh.F(f, k)); };
    const int i = cand[n][0], j = cand[n][1];
    hit[n] = triangles_intersect(corner(i, 0), corner(i, 1), corner(i, 2), corner(j, 0),
                                 corner(j, 1), corner(j, 2));
  });
  FacePairs result;
  for (std::size_t n = 0; n < cand.size(); ++n) {
    if (hit[n]) result.push_back(cand[n]);
  }
  return result;
}

// ---------------------------------------------------------------------------------------------

std::string to_string(SurfaceOrientation orientation) {
  switch (orientation) {
    case SurfaceOrientation::outward: return "outward";
    case SurfaceOrientation::inward: return "inward";
    case SurfaceOrientation::undefined: break;
  }
  return "undefined";
}

bool MeshReport::is_closed() const { return num_faces > 0 && boundary_edges.empty(); }
bool MeshReport::is_manifold() const { return nonmanifold_edges.empty(); }
bool MeshReport::is_consistently_oriented() const { return inconsistent_edges.empty(); }
bool MeshReport::is_solid() const {
  return nonfinite_vertices.empty() && out_of_range_faces.empty() && degenerate_faces.empty() &&
         is_closed() && is_manifold() && is_consistently_oriented() &&
         orientation == SurfaceOrientation::outward && self_intersections.empty();
}

std::vector<std::string> MeshReport::list_problems() const {
  std::vector<std::string> out;
  const auto add = [&](std::size_t n, const std::string& what) {
    if (n > 0) out.push_back(std::to_string(n) + " " + what);
  };
  if (num_faces == 0) out.push_back("no faces");
  add(nonfinite_vertices.size(), "vertices with NaN/Inf coordinates");
  add(out_of_range_faces.size(), "faces with out-of-range vertex indices");
  add(degenerate_faces.size(), "degenerate faces (repeated index or zero area)");
  add(boundary_edges.size(), "boundary edges (the surface is open)");
  add(nonmanifold_edges.size(), "non-manifold edges (used by 3 or more faces)");
  add(inconsistent_edges.size(), "edges with inconsistent orientation");
  add(self_intersections.size(), "self-intersecting face pairs");
  if (is_closed() && is_manifold() && is_consistently_oriented() &&
      orientation == SurfaceOrientation::inward) {
    out.push_back("normals point inward (negative signed volume)");
  }
  return out;
}

MeshReport validate_mesh(const TriMesh& mesh, const ValidationOptions& options) {
  using namespace mesh_detail;
  MeshReport r;
  r.num_vertices = mesh.V.rows();
  r.num_faces = mesh.F.rows();
  const Eigen::Index nv = mesh.V.rows();
  for (Eigen::Index i = 0; i < nv; ++i) {
    if (!mesh.V.row(i).allFinite()) r.nonfinite_vertices.push_back(static_cast<int>(i));
  }
  // per-face validity
  const std::vector<char> topo = find_topological_faces(mesh);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const int a = mesh.F(f, 0), b = mesh.F(f, 1), c = mesh.F(f, 2);
    if (a < 0 || b < 0 || c < 0 || a >= nv || b >= nv || c >= nv) {
      r.out_of_range_faces.push_back(static_cast<int>(f));
    } else if (!topo[static_cast<std::size_t>(f)] ||
               has_zero_area(mesh.V.row(a), mesh.V.row(b), mesh.V.row(c))) {
      r.degenerate_faces.push_back(static_cast<int>(f));
    }
  }
  // edges
  const std::vector<EdgeUse> uses = collect_edge_uses(mesh, topo);
  for (std::size_t s = 0; s < uses.size();) {
    std::size_t e = s;
    while (e < uses.size() && uses[e].a == uses[s].a && uses[e].b == uses[s].b) ++e;
    const std::array<int, 2> edge{uses[s].a, uses[s].b};
    ++r.num_edges;
    if (e - s == 1) r.boundary_edges.push_back(edge);
    else if (e - s > 2) r.nonmanifold_edges.push_back(edge);
    else if (uses[s].forward == uses[s + 1].forward) r.inconsistent_edges.push_back(edge);
    s = e;
  }
  // vertices, components, Euler characteristic
  std::vector<char> referenced(static_cast<std::size_t>(nv), 0);
  long num_topo_faces = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!topo[static_cast<std::size_t>(f)]) continue;
    ++num_topo_faces;
    for (int k = 0; k < 3; ++k) referenced[static_cast<std::size_t>(mesh.F(f, k))] = 1;
  }
  const long num_referenced = std::count(referenced.begin(), referenced.end(), 1);
  r.num_unreferenced_vertices = nv - num_referenced;
  r.euler_characteristic = num_referenced - r.num_edges + num_topo_faces;
  label_face_components(mesh, topo, r.num_components);
  // orientation
  r.signed_volume = calc_signed_volume(mesh, topo);
  if (r.is_closed() && r.is_manifold() && r.is_consistently_oriented() &&
      r.out_of_range_faces.empty() && std::isfinite(r.signed_volume) && r.signed_volume != 0.0) {
    r.orientation = r.signed_volume > 0 ? SurfaceOrientation::outward : SurfaceOrientation::inward;
  }
  if (options.check_self_intersections) {
    r.self_intersections = calc_self_intersections(mesh);
    r.self_intersections_checked = true;
  }
  return r;
}

nlohmann::json to_json(const MeshReport& r, std::size_t max_listed) {
  using nlohmann::json;
  const auto listed = [&](const auto& items) {
    json out = json::array();
    for (std::size_t i = 0; i < items.size() && i < max_listed; ++i) out.push_back(items[i]);
    return out;
  };
  const auto item = [&](const auto& items) {
    return json{{"count", items.size()}, {"items", listed(items)}};
  };
  json j;
  j["vertices"] = r.num_vertices;
  j["faces"] = r.num_faces;
  j["edges"] = r.num_edges;
  j["unreferenced_vertices"] = r.num_unreferenced_vertices;
  j["components"] = r.num_components;
  j["euler_characteristic"] = r.euler_characteristic;
  j["closed"] = r.is_closed();
  j["manifold"] = r.is_manifold();
  j["consistently_oriented"] = r.is_consistently_oriented();
  j["orientation"] = to_string(r.orientation);
  j["signed_volume_m3"] = std::isfinite(r.signed_volume) ? json(r.signed_volume) : json(nullptr);
  j["solid"] = r.is_solid();
  j["nonfinite_vertices"] = item(r.nonfinite_vertices);
  j["out_of_range_faces"] = item(r.out_of_range_faces);
  j["degenerate_faces"] = item(r.degenerate_faces);
  j["boundary_edges"] = item(r.boundary_edges);
  j["nonmanifold_edges"] = item(r.nonmanifold_edges);
  j["inconsistent_edges"] = item(r.inconsistent_edges);
  j["self_intersections"] = item(r.self_intersections);
  j["self_intersections"]["checked"] = r.self_intersections_checked;
  j["problems"] = r.list_problems();
  return j;
}

std::string format_report(const MeshReport& r) {
  std::ostringstream out;
  out << "vertices " << r.num_vertices << ", faces " << r.num_faces << ", edges " << r.num_edges
      << ", components " << r.num_components << ", Euler characteristic "
      << r.euler_characteristic << "\n";
  out << "closed " << (r.is_closed() ? "yes" : "no") << ", manifold "
      << (r.is_manifold() ? "yes" : "no") << ", consistently oriented "
      << (r.is_consistently_oriented() ? "yes" : "no") << ", orientation "
      << to_string(r.orientation) << ", self-intersections "
      << (r.self_intersections_checked ? std::to_string(r.self_intersections.size())
                                       : std::string("not checked"))
      << "\n";
  const std::vector<std::string> problems = r.list_problems();
  if (problems.empty()) out << "no problems found\n";
  for (const std::string& p : problems) out << "problem: " << p << "\n";
  return out.str();
}

}  // namespace fascicle
