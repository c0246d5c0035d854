#include "fascicle/geometry/primitives.hpp"

#include "fascicle/core/error.hpp"

#include <cmath>
#include <map>
#include <numbers>
#include <utility>
#include <vector>

namespace fascicle {
namespace {

// Growable vertex and triangle lists, turned into a TriMesh at the end.
struct MeshBuilder {
  std::vector<Vec3> v;
  std::vector<Eigen::Vector3i> f;
  int add(const Vec3& p) {
    v.push_back(p);
    return static_cast<int>(v.size()) - 1;
  }
  void tri(int a, int b, int c) { f.emplace_back(a, b, c); }
  void quad(int a, int b, int c, int d) {  // counter-clockwise a b c d
    tri(a, b, c);
    tri(a, c, d);
  }
  TriMesh build() const {
    TriMesh m;
    m.V.resize(static_cast<Eigen::Index>(v.size()), 3);
    m.F.resize(static_cast<Eigen::Index>(f.size()), 3);
    for (std::size_t i = 0; i < v.size(); ++i) m.V.row(static_cast<Eigen::Index>(i)) = v[i];
    for (std::size_t i = 0; i < f.size(); ++i) m.F.row(static_cast<Eigen::Index>(i)) = f[i];
    return m;
  }
};

void require_positive(double value, const char* what) {
  if (!(value > 0.0) || !std::isfinite(value)) {
    throw_bad_input(std::string(what) + " must be positive and finite, got " + std::to_string(value));
  }
}

}  // namespace

TriMesh make_box(const Vec3& h) {
  require_positive(h.minCoeff(), "box half extent");
  MeshBuilder b;
  for (int i = 0; i < 8; ++i) {
    b.add(Vec3((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(), (i & 4) ? h.z() : -h.z()));
  }
  // faces as counter-clockwise quads seen from outside
  b.quad(0, 2, 3, 1);  // z-
  b.quad(4, 5, 7, 6);  // z+
  b.quad(0, 1, 5, 4);  // y-
  b.quad(2, 6, 7, 3);  // y+
  b.quad(0, 4, 6, 2);  // x-
  b.quad(1, 3, 7, 5);  // x+
  return b.build();
}

TriMesh make_icosphere(double radius, int subdivisions) {
  require_positive(radius, "sphere radius");
  if (subdivisions < 0 || subdivisions > 8) throw_bad_input("icosphere subdivisions must be in [0, 8]");
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  MeshBuilder b;
  const double base[12][3] = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0},
                              {0, -1, t}, {0, 1, t}, {0, -1, -t}, {0, 1, -t},
                              {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  for (const auto& p : base) b.add(Vec3(p[0], p[1], p[2]).normalized());
  const int faces[20][3] = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                            {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                            {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                            {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (const auto& f : faces) b.tri(f[0], f[1], f[2]);
  for (int level = 0; level < subdivisions; ++level) {
    std::map<std::pair<int, int>, int> midpoint;
    auto mid = [&](int a, int c) {
      const auto key = std::minmax(a, c);
      auto it = midpoint.find(key);
      if (it != midpoint.end()) return it->second;
      const int m = b.add((b.v[a] + b.v[c]).normalized());
      midpoint.emplace(key, m);
      return m;
    };
    std::vector<Eigen::Vector3i> old;
    old.swap(b.f);
    for (const auto& f : old) {
      const int ab = mid(f[0], f[1]), bc = mid(f[1], f[2]), ca = mid(f[2], f[0]);
      b.tri(f[0], ab, ca);
      b.tri(f[1], bc, ab);
      b.tri(f[2], ca, bc);
      b.tri(ab, bc, ca);
    }
  }
  for (auto& p : b.v) p *= radius;
  return b.build();
}

TriMesh make_ellipsoid(const Vec3& radii, int subdivisions) {
  require_positive(radii.minCoeff(), "ellipsoid radius");
  TriMesh m = make_icosphere(1.0, subdivisions);
  for (Eigen::Index i = 0; i < m.V.rows(); ++i) m.V.row(i) = m.V.row(i).cwiseProduct(radii.transpose());
  return m;
}

TriMesh make_cylinder(double radius, double height, int segments, int rings) {
  require_positive(radius, "cylinder radius");
  require_positive(height, "cylinder height");
  if (segments < 3 || rings < 1) throw_bad_input("cylinder needs >= 3 segments and >= 1 ring");
  MeshBuilder b;
  const double two_pi = 2.0 * std::numbers::pi;
  for (int r = 0; r <= rings; ++r) {
    const double z = -0.5 * height + height * double(r) / double(rings);
    for (int s = 0; s < segments; ++s) {
      const double a = two_pi * double(s) / double(segments);
      b.add(Vec3(radius * std::cos(a), radius * std::sin(a), z));
    }
  }
  auto idx = [&](int r, int s) { return r * segments + (s % segments); };
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) b.quad(idx(r, s), idx(r, s + 1), idx(r + 1, s + 1), idx(r + 1, s));
  }
  const int bottom = b.add(Vec3(0, 0, -0.5 * height));
  const int top = b.add(Vec3(0, 0, 0.5 * height));
  for (int s = 0; s < segments; ++s) {
    b.tri(bottom, idx(0, s + 1), idx(0, s));
    b.tri(top, idx(rings, s), idx(rings, s + 1));
  }
  return b.build();
}

TriMesh make_torus(double major, double minor, int major_segments, int minor_segments) {
  require_positive(minor, "torus tube radius");
  if (!(major > minor)) throw_bad_input("torus major radius must exceed the tube radius");
  if (major_segments < 3 || minor_segments < 3) throw_bad_input("torus needs >= 3 segments each way");
  MeshBuilder b;
  const double two_pi = 2.0 * std::numbers::pi;
  for (int i = 0; i < major_segments; ++i) {
    const double u = two_pi * double(i) / double(major_segments);
    for (int j = 0; j < minor_segments; ++j) {
      const double v = two_pi * double(j) / double(minor_segments);
      const double rho = major + minor * std::cos(v);
      b.add(Vec3(rho * std::cos(u), rho * std::sin(u), minor * std::sin(v)));
    }
  }
  auto idx = [&](int i, int j) { return (i % major_segments) * minor_segments + (j % minor_segments); };
  for (int i = 0; i < major_segments; ++i) {
    for (int j = 0; j < minor_segments; ++j) b.quad(idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
  }
  return b.build();
}

TriMesh make_spindle(double z0, double z1, int segments, int rings,
                     const std::function<double(double t)>& radius) {
  if (!(z1 > z0)) throw_bad_input("spindle needs z1 > z0");
  if (segments < 3 || rings < 1) throw_bad_input("spindle needs >= 3 segments and >= 1 ring");
  MeshBuilder b;
  const double two_pi = 2.0 * std::numbers::pi;
  const int bottom = b.add(Vec3(0, 0, z0));
  for (int r = 1; r <= rings; ++r) {
    const double t = double(r) / double(rings + 1);
    const double rad = radius(t);
    require_positive(rad, "spindle radius");
    for (int s = 0; s < segments; ++s) {
      const double a = two_pi * double(s) / double(segments);
      b.add(Vec3(rad * std::cos(a), rad * std::sin(a), z0 + t * (z1 - z0)));
    }
  }
  const int top = b.add(Vec3(0, 0, z1));
  auto idx = [&](int r, int s) { return 1 + (r - 1) * segments + (s % segments); };
  for (int s = 0; s < segments; ++s) {
    b.tri(bottom, idx(1, s + 1), idx(1, s));
    b.tri(top, idx(rings, s), idx(rings, s + 1));
  }
  for (int r = 1; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) b.quad(idx(r, s), idx(r, s + 1), idx(r + 1, s + 1), idx(r + 1, s));
  }
  return b.build();
}

}  // namespace fascicle
