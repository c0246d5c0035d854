// Attachment areas from vertex sets, end regions, landmarks and bones.
#include "fascicle/fibres/attachment.hpp"

#include "sampling.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "point_index.hpp"

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace fascicle {

AttachmentArea make_attachment_area(const TriMesh& muscle, std::vector<int> vertices,
                                    const std::string& name) {
  std::sort(vertices.begin(), vertices.end());
  vertices.erase(std::unique(vertices.begin(), vertices.end()), vertices.end());
  if (vertices.empty())
    throw_bad_input("the " + name + " attachment area is empty",
                    {.object = name,
                     .suggestion = "check that the landmarks or bones touch this muscle, or "
                                   "increase --attach-distance"});
  if (vertices.front() < 0 || vertices.back() >= muscle.num_vertices())
    throw_bad_input("the " + name + " attachment area has a vertex index out of range",
                    {.object = name});
  std::vector<char> in(muscle.num_vertices(), 0);
  for (int v : vertices) in[v] = 1;
  AttachmentArea area;
  area.name = name;
  Vec3 weighted = Vec3::Zero();
  Vec3 normal_sum = Vec3::Zero();
  for (Eigen::Index f = 0; f < muscle.num_faces(); ++f) {
    const auto t = muscle.F.row(f);
    if (!in[t(0)] || !in[t(1)] || !in[t(2)]) continue;
    const Vec3 a = muscle.V.row(t(0)), b = muscle.V.row(t(1)), c = muscle.V.row(t(2));
    const Vec3 n2 = (b - a).cross(c - a);
    const double A = 0.5 * n2.norm();
    area.triangles.push_back(static_cast<int>(f));
    area.area_m2 += A;
    weighted += A * (a + b + c) / 3.0;
    normal_sum += 0.5 * n2;
  }
  if (area.area_m2 > 0.0) {
    area.centroid = weighted / area.area_m2;
  } else {
    for (int v : vertices) area.centroid += muscle.V.row(v).transpose();
    area.centroid /= static_cast<double>(vertices.size());
  }
  if (normal_sum.norm() > 0.0) area.normal = normal_sum.normalized();
  area.vertices = std::move(vertices);
  return area;
}

void check_attachments(const TriMesh& muscle, const Attachments& areas) {
  for (const AttachmentArea* a : {&areas.origin, &areas.insertion}) {
    if (a->vertices.empty() || a->triangles.empty())
      throw_bad_input("the " + a->name + " attachment area has no triangle of the muscle surface",
                      {.object = a->name,
                       .suggestion = "give a larger area (more landmarks, a larger radius or "
                                     "--attach-distance)"});
  }
  std::vector<int> shared;
  std::set_intersection(areas.origin.vertices.begin(), areas.origin.vertices.end(),
                        areas.insertion.vertices.begin(), areas.insertion.vertices.end(),
                        std::back_inserter(shared));
  if (!shared.empty())
    throw_bad_input("the origin and insertion areas overlap (" + std::to_string(shared.size()) +
                        " shared vertices of " + std::to_string(muscle.num_vertices()) + ")",
                    {.suggestion = "give disjoint areas (smaller landmark radius or attachment "
                                   "distance, or assign the bones to origin and insertion)"});
}

Vec3 calc_principal_axis(const TriMesh& muscle, const Vec3& origin_towards) {
  if (muscle.num_vertices() < 3) throw_bad_input("the muscle mesh has fewer than 3 vertices");
  const Vec3 mean = muscle.V.colwise().mean();
  const Points3 D = muscle.V.rowwise() - mean.transpose();
  const Mat3 C = D.transpose() * D;
  const Eigen::SelfAdjointEigenSolver<Mat3> eig(C);
  Vec3 axis = eig.eigenvectors().col(2);
  if (axis.dot(origin_towards) < 0.0) axis = -axis;
  return axis;
}

namespace {

// Position of every vertex along `axis`, normalised to [0, 1] (0 at the origin end, which is the
// +axis end).
VecX calc_axial_parameter(const TriMesh& muscle, const Vec3& axis) {
  const VecX s = muscle.V * axis;
  const double hi = s.maxCoeff(), lo = s.minCoeff();
  if (hi - lo <= 0.0) throw_bad_input("the muscle mesh has no extent along its principal axis");
  return ((hi - s.array()) / (hi - lo)).matrix();
}

}  // namespace

Attachments find_end_attachments(const TriMesh& muscle, double fraction,
                                 const Vec3& origin_towards) {
  if (!(fraction > 0.0 && fraction < 0.5))
    throw_usage("the end-region fraction must be in (0, 0.5)", {});
  const Vec3 axis = calc_principal_axis(muscle, origin_towards);
  const VecX t = calc_axial_parameter(muscle, axis);
  std::vector<int> o, i;
  for (Eigen::Index v = 0; v < t.size(); ++v) {
    if (t(v) <= fraction) o.push_back(static_cast<int>(v));
    if (t(v) >= 1.0 - fraction) i.push_back(static_cast<int>(v));
  }
  Attachments a{make_attachment_area(muscle, o, "origin"),
                make_attachment_area(muscle, i, "insertion")};
  check_attachments(muscle, a);
  return a;
}

namespace {

double calc_mean_edge_length(const TriMesh& m) {
  double sum = 0.0;
  for (Eigen::Index f = 0; f < m.num_faces(); ++f)
    for (int k = 0; k < 3; ++k) sum += (m.V.row(m.F(f, k)) - m.V.row(m.F(f, (k + 1) % 3))).norm();
  return m.num_faces() > 0 ? sum / (3.0 * m.num_faces()) : 0.0;
}

std::vector<int> find_vertices_near_landmarks(const TriMesh& muscle, const MeshQuery& query,
                                              const detail::PointIndex& vertex_index,
                                              const Points3& landmarks, double radius,
                                              double max_offset, const std::string& name) {
  if (landmarks.rows() == 0)
    throw_bad_input("the " + name + " landmark set is empty", {.object = name});
  double r = radius;
  if (r <= 0.0) {
    std::vector<double> spacing;
    if (landmarks.rows() > 1) {
      // O(n^2): landmark sets are small (tens to hundreds of points).
      for (Eigen::Index k = 0; k < landmarks.rows(); ++k) {
        double best = std::numeric_limits<double>::infinity();
        for (Eigen::Index j = 0; j < landmarks.rows(); ++j)
          if (j != k) best = std::min(best, (landmarks.row(j) - landmarks.row(k)).norm());
        spacing.push_back(best);
      }
      std::nth_element(spacing.begin(), spacing.begin() + spacing.size() / 2, spacing.end());
      r = 1.5 * spacing[spacing.size() / 2];
    }
    r = std::max(r, calc_mean_edge_length(muscle));
  }
  std::vector<int> out;
  for (Eigen::Index k = 0; k < landmarks.rows(); ++k) {
    const Vec3 p = landmarks.row(k).transpose();
    const ClosestPoint c = query.calc_closest_point(p);
    if (!(c.distance <= max_offset))
      throw_bad_input(
          "landmark " + std::to_string(k + 1) + " of the " + name + " area lies " +
              std::to_string(c.distance * 1e3) + " mm from the muscle surface (limit " +
              std::to_string(max_offset * 1e3) + " mm)",
          {.object = name,
           .suggestion = "check that the landmarks belong to this muscle and use the same "
                         "length unit (--units)"});
    for (int v : vertex_index.find_within(c.point, r)) out.push_back(v);
    // Always include the nearest vertex, so a sparse mesh still gets an area.
    out.push_back(vertex_index.find_nearest(c.point).first);
  }
  return out;
}

}  // namespace

Attachments find_landmark_attachments(const TriMesh& muscle, const Points3& origin_landmarks,
                                      const Points3& insertion_landmarks, double radius,
                                      double max_offset) {
  const MeshQuery query(muscle);
  const detail::PointIndex vertex_index(muscle.V);
  auto o = find_vertices_near_landmarks(muscle, query, vertex_index, origin_landmarks, radius,
                                        max_offset, "origin");
  auto i = find_vertices_near_landmarks(muscle, query, vertex_index, insertion_landmarks, radius,
                                        max_offset, "insertion");
  Attachments a{make_attachment_area(muscle, std::move(o), "origin"),
                make_attachment_area(muscle, std::move(i), "insertion")};
  check_attachments(muscle, a);
  return a;
}

namespace {

// Bone contacts: drops the connected pieces (triangles sharing vertices) of a contact set whose
// area is under `min_fraction` of the set's area, and vertices in no triangle. A muscle passing
// within the attachment distance of a bone far from its attachment leaves such specks (the VH
// soleus: one 1 mm^2 triangle 60 mm from the tibial/fibular contact strip); kept, they would be
// Dirichlet sinks inside the belly for the harmonic field.
std::vector<int> drop_contact_specks(const TriMesh& muscle, std::vector<int> vertices,
                                     double min_fraction) {
  if (vertices.empty()) return vertices;
  std::vector<char> in(muscle.num_vertices(), 0);
  for (int v : vertices) in[v] = 1;
  std::vector<int> parent(muscle.num_vertices());
  for (std::size_t v = 0; v < parent.size(); ++v) parent[v] = static_cast<int>(v);
  const auto root = [&](int v) {
    while (parent[v] != v) v = parent[v] = parent[parent[v]];
    return v;
  };
  std::vector<int> faces;
  for (Eigen::Index f = 0; f < muscle.num_faces(); ++f) {
    const auto t = muscle.F.row(f);
    if (!in[t(0)] || !in[t(1)] || !in[t(2)]) continue;
    faces.push_back(static_cast<int>(f));
    parent[root(t(1))] = root(t(0));
    parent[root(t(2))] = root(t(0));
  }
  std::vector<double> piece_area(muscle.num_vertices(), 0.0);
  double total = 0.0;
  for (int f : faces) {
    const Vec3 a = muscle.V.row(muscle.F(f, 0)), b = muscle.V.row(muscle.F(f, 1)),
               c = muscle.V.row(muscle.F(f, 2));
    const double A = 0.5 * (b - a).cross(c - a).norm();
    piece_area[root(muscle.F(f, 0))] += A;
    total += A;
  }
  if (!(total > 0.0)) return vertices;
  std::vector<char> in_triangle(muscle.num_vertices(), 0);
  for (int f : faces)
    for (int k = 0; k < 3; ++k) in_triangle[muscle.F(f, k)] = 1;
  std::vector<int> kept;
  for (int v : vertices)
    if (in_triangle[v] && piece_area[root(v)] >= min_fraction * total) kept.push_back(v);
  return kept;
}

}  // namespace

Attachments find_bone_attachments(const TriMesh& muscle, const std::vector<TriMesh>& bones,
                                  double distance, bool split_by_bone, double end_fraction,
                                  const Vec3& origin_towards) {
  if (bones.empty()) throw_usage("no bone mesh given for the attachment areas", {});
  if (!(distance > 0.0)) throw_usage("the attachment distance must be positive", {});
  // Nearest bone (index) within `distance` of every muscle vertex, -1 if none.
  std::vector<int> bone_of(muscle.num_vertices(), -1);
  VecX best = VecX::Constant(muscle.num_vertices(), std::numeric_limits<double>::infinity());
  for (std::size_t b = 0; b < bones.size(); ++b) {
    const MeshQuery q(bones[b]);
    const VecX d = q.calc_distances(muscle.V);
    for (Eigen::Index v = 0; v < d.size(); ++v)
      if (d(v) <= distance && d(v) < best(v)) {
        best(v) = d(v);
        bone_of[v] = static_cast<int>(b);
      }
  }
  if (std::all_of(bone_of.begin(), bone_of.end(), [](int b) { return b < 0; }))
    throw_bad_input("no part of the muscle lies within " + std::to_string(distance * 1e3) +
                        " mm of the given bones",
                    {.suggestion = "check the bones belong to this muscle and share its frame "
                                   "and unit, or increase --attach-distance"});
  std::vector<int> o, i;
  if (split_by_bone) {
    for (Eigen::Index v = 0; v < muscle.num_vertices(); ++v) {
      if (bone_of[v] == 0) o.push_back(static_cast<int>(v));
      if (bone_of[v] > 0) i.push_back(static_cast<int>(v));
    }
    o = drop_contact_specks(muscle, std::move(o), 0.02);
    i = drop_contact_specks(muscle, std::move(i), 0.02);
    if (o.empty() || i.empty())
      throw_bad_input(std::string("no part of the muscle lies within the attachment distance of ") +
                          (o.empty() ? "the origin bone (the first)" : "any insertion bone"),
                      {.suggestion = "increase --attach-distance or list other bones"});
  } else {
    const Vec3 axis = calc_principal_axis(muscle, origin_towards);
    const VecX t = calc_axial_parameter(muscle, axis);
    for (Eigen::Index v = 0; v < muscle.num_vertices(); ++v) {
      if (bone_of[v] < 0) continue;
      (t(v) < 0.5 ? o : i).push_back(static_cast<int>(v));
    }
    o = drop_contact_specks(muscle, std::move(o), 0.02);
    i = drop_contact_specks(muscle, std::move(i), 0.02);
    // A side without bone contact (a belly without tendon) takes its end region.
    const auto fill_end = [&](std::vector<int>& side, bool origin_side) {
      if (!side.empty()) return;
      for (Eigen::Index v = 0; v < t.size(); ++v)
        if (origin_side ? t(v) <= end_fraction : t(v) >= 1.0 - end_fraction)
          side.push_back(static_cast<int>(v));
    };
    fill_end(o, true);
    fill_end(i, false);
  }
  Attachments a{make_attachment_area(muscle, std::move(o), "origin"),
                make_attachment_area(muscle, std::move(i), "insertion")};
  check_attachments(muscle, a);
  return a;
}

Attachments find_bone_role_attachments(const TriMesh& muscle,
                                       const std::vector<TriMesh>& origin_bones,
                                       const std::vector<TriMesh>& insertion_bones,
                                       const BoneRoleOptions& options) {
  if (origin_bones.empty() && insertion_bones.empty())
    throw_usage("no bone mesh given for the attachment areas", {});
  if (!(options.distance > 0.0)) throw_usage("the attachment distance must be positive", {});
  if (!(options.end_fraction > 0.0 && options.end_fraction < 0.5))
    throw_usage("the end-region fraction must be in (0, 0.5)", {});
  const Vec3 axis = calc_principal_axis(muscle, options.origin_towards);
  const VecX t = calc_axial_parameter(muscle, axis);  // 0 at the origin end
  // Vertices within `distance` of any of `bones` and within `reach` of their own end.
  const auto contact = [&](const std::vector<TriMesh>& bones, bool origin_side, double reach) {
    std::vector<char> near(muscle.num_vertices(), 0);
    for (const TriMesh& bone : bones) {
      const MeshQuery q(bone);
      const VecX d = q.calc_distances(muscle.V);
      for (Eigen::Index v = 0; v < d.size(); ++v) near[v] |= d(v) <= options.distance;
    }
    std::vector<int> out;
    for (Eigen::Index v = 0; v < muscle.num_vertices(); ++v)
      if (near[v] && (origin_side ? t(v) <= reach : t(v) >= 1.0 - reach))
        out.push_back(static_cast<int>(v));
    return drop_contact_specks(muscle, std::move(out), 0.02);
  };
  std::vector<int> o = contact(origin_bones, true, options.origin_reach);
  std::vector<int> i = contact(insertion_bones, false, options.insertion_reach);
  if (o.empty() && i.empty())
    throw_bad_input("no part of the muscle lies within " + std::to_string(options.distance * 1e3) +
                        " mm of its origin or insertion bones",
                    {.suggestion = "check the bones belong to this muscle and share its frame "
                                   "and unit, or increase --attach-distance"});
  // A side without contact takes its end region; the other side's contact leaves it.
  const auto in_end = [&](Eigen::Index v, bool origin_side) {
    return origin_side ? t(v) <= options.end_fraction : t(v) >= 1.0 - options.end_fraction;
  };
  for (const bool origin_side : {true, false}) {
    std::vector<int>& side = origin_side ? o : i;
    if (!side.empty()) continue;
    for (Eigen::Index v = 0; v < t.size(); ++v)
      if (in_end(v, origin_side)) side.push_back(static_cast<int>(v));
    std::vector<int>& other = origin_side ? i : o;
    std::erase_if(other, [&](int v) { return in_end(v, origin_side); });
    other = drop_contact_specks(muscle, std::move(other), 0.02);
  }
  Attachments a{make_attachment_area(muscle, std::move(o), "origin"),
                make_attachment_area(muscle, std::move(i), "insertion")};
  check_attachments(muscle, a);
  return a;
}

Points3 read_landmarks_csv(const std::filesystem::path& path, double metres_per_unit) {
  std::ifstream in(path);
  if (!in)
    throw_bad_input("cannot open the landmark file",
                    {.file = path.string(), .suggestion = "check the path"});
  std::vector<Vec3> pts;
  std::string line;
  long line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    for (char& c : line)
      if (c == ',' || c == ';' || c == '\t') c = ' ';
    std::istringstream ss(line);
    std::string first;
    if (!(ss >> first)) continue;
    char* end = nullptr;
    const double x = std::strtod(first.c_str(), &end);
    if (end == first.c_str() || *end != '\0') {
      if (pts.empty()) continue;  // a header row
      throw_bad_input("malformed landmark row (expected x,y,z numbers)",
                      {.file = path.string(), .line = line_no});
    }
    double y, z;
    if (!(ss >> y >> z) || !std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z))
      throw_bad_input("malformed landmark row (expected three finite numbers x,y,z)",
                      {.file = path.string(), .line = line_no});
    pts.emplace_back(x, y, z);
  }
  if (pts.empty())
    throw_bad_input("the landmark file holds no point",
                    {.file = path.string(), .suggestion = "write one x,y,z row per landmark"});
  Points3 P(pts.size(), 3);
  for (std::size_t k = 0; k < pts.size(); ++k) P.row(k) = metres_per_unit * pts[k].transpose();
  return P;
}

}  // namespace fascicle

namespace fascicle {

Points3 calc_area_samples(const TriMesh& muscle, const AttachmentArea& area, int count) {
  if (area.triangles.empty())
    throw_bad_input("the " + area.name + " area has no triangle", {.object = area.name});
  const std::vector<detail::TriangleSample> samples = detail::sample_triangles(
      detail::make_area_weighted(muscle.V, muscle.F, area.triangles), count);
  Points3 P(samples.size(), 3);
  for (std::size_t i = 0; i < samples.size(); ++i) P.row(i) = samples[i].point.transpose();
  return P;
}

}  // namespace fascicle
