// Fibre analysis, DTI comparison, report and VTK output.
#include "fascicle/fibres/analysis.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/io/polydata.hpp"
#include "point_index.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

namespace fascicle {

namespace {

double angle_between_lines(const Vec3& a, const Vec3& b) {
  const double na = a.norm(), nb = b.norm();
  if (na == 0.0 || nb == 0.0) return 0.0;
  return std::acos(std::clamp(std::abs(a.dot(b)) / (na * nb), 0.0, 1.0));
}

}  // namespace

FibreAnalysis analyse_fibres(const TriMesh& muscle, const Attachments& areas,
                             const FibreSet& fibres, int volume_samples) {
  if (fibres.fibres.empty()) throw_bad_input("there are no fibres to analyse");
  FibreAnalysis r;
  r.volume_m3 = calc_enclosed_volume(muscle);
  r.origin_area_m2 = areas.origin.area_m2;
  r.insertion_area_m2 = areas.insertion.area_m2;
  const Vec3 action = areas.insertion.centroid - areas.origin.centroid;
  r.fibres.resize(fibres.size());
  for (std::size_t i = 0; i < fibres.size(); ++i) {
    const Points3& P = fibres.fibres[i];
    FibreMeasures& m = r.fibres[i];
    m.length_m = calc_polyline_length(P);
    const Eigen::Index n = P.rows();
    if (n < 2) continue;
    const Vec3 t0 = P.row(1) - P.row(0), t1 = P.row(n - 1) - P.row(n - 2);
    m.pennation_proximal_rad = angle_between_lines(t0, action);
    m.pennation_distal_rad = angle_between_lines(t1, action);
    m.surface_angle_proximal_rad = M_PI / 2 - angle_between_lines(t0, areas.origin.normal);
    m.surface_angle_distal_rad = M_PI / 2 - angle_between_lines(t1, areas.insertion.normal);
  }
  // Volume shares: interior grid points assigned to the fibre of their nearest fibre point.
  std::vector<int> owner;
  Eigen::Index total_points = 0;
  for (const Points3& P : fibres.fibres) total_points += P.rows();
  Points3 all(total_points, 3);
  Eigen::Index row = 0;
  for (std::size_t i = 0; i < fibres.size(); ++i) {
    all.middleRows(row, fibres.fibres[i].rows()) = fibres.fibres[i];
    row += fibres.fibres[i].rows();
    owner.insert(owner.end(), fibres.fibres[i].rows(), static_cast<int>(i));
  }
  const detail::PointIndex index(all);
  const Vec3 lo = muscle.V.colwise().minCoeff(), hi = muscle.V.colwise().maxCoeff();
  const double box = (hi - lo).prod();
  const double h = std::cbrt(box / std::max(volume_samples, 1));
  const Eigen::Array3i dims = (((hi - lo) / h).array().ceil().cast<int>()).max(1);
  Points3 grid(static_cast<Eigen::Index>(dims.prod()), 3);
  Eigen::Index g = 0;
  for (int i = 0; i < dims(0); ++i)
    for (int j = 0; j < dims(1); ++j)
      for (int k = 0; k < dims(2); ++k)
        grid.row(g++) = (lo + h * Vec3(i + 0.5, j + 0.5, k + 0.5)).transpose();
  const MeshQuery query(muscle);
  const InsideFlags inside = query.calc_is_inside(grid);
  std::vector<double> count(fibres.size(), 0.0);
  double total = 0.0;
  for (Eigen::Index p = 0; p < grid.rows(); ++p) {
    if (!inside(p)) continue;
    count[owner[index.find_nearest(grid.row(p).transpose()).first]] += 1.0;
    total += 1.0;
  }
  double sum_len = 0.0, sum_pen = 0.0;
  for (std::size_t i = 0; i < fibres.size(); ++i) {
    FibreMeasures& m = r.fibres[i];
    m.volume_share = total > 0 ? count[i] / total : 1.0 / fibres.size();
    sum_len += m.length_m;
    const double pen = 0.5 * (m.pennation_proximal_rad + m.pennation_distal_rad);
    sum_pen += pen;
    if (m.length_m > 0)
      r.pcsa_ravichandiran_m2 += m.volume_share * r.volume_m3 * std::cos(pen) / m.length_m;
  }
  r.mean_fibre_length_m = sum_len / fibres.size();
  r.mean_pennation_rad = sum_pen / fibres.size();
  r.pcsa_m2 = r.mean_fibre_length_m > 0 ? r.volume_m3 / r.mean_fibre_length_m : 0.0;
  return r;
}

DirectionDeviation compare_directions(const FibreSet& fibres, const FibreSet& tracts,
                                      double fibre_spacing_m) {
  // Each fibre segment is cut into pieces no longer than fibre_spacing_m (same direction), so the
  // nearest piece midpoint is the nearest point of the fibre polylines to within half the spacing.
  std::vector<Vec3> mids, dirs;
  for (const Points3& P : fibres.fibres)
    for (Eigen::Index k = 1; k < P.rows(); ++k) {
      const Vec3 a = P.row(k - 1), b = P.row(k);
      const double len = (b - a).norm();
      const int pieces = fibre_spacing_m > 0.0
                             ? static_cast<int>(std::clamp(std::ceil(len / fibre_spacing_m), 1.0, 1e6))
                             : 1;
      for (int j = 0; j < pieces; ++j) {
        mids.emplace_back(a + (j + 0.5) / pieces * (b - a));
        dirs.emplace_back(b - a);
      }
    }
  if (mids.empty()) throw_bad_input("there are no fibre segments to compare");
  Points3 M(mids.size(), 3);
  for (std::size_t i = 0; i < mids.size(); ++i) M.row(i) = mids[i].transpose();
  const detail::PointIndex index(M);
  std::vector<double> angles;
  for (const Points3& T : tracts.fibres)
    for (Eigen::Index k = 1; k < T.rows(); ++k) {
      const Vec3 d = T.row(k) - T.row(k - 1);
      if (d.norm() == 0.0) continue;
      const Vec3 mid = 0.5 * (T.row(k) + T.row(k - 1));
      angles.push_back(angle_between_lines(d, dirs[index.find_nearest(mid).first]));
    }
  DirectionDeviation r;
  r.segments = angles.size();
  if (angles.empty()) return r;
  double sum = 0.0, sum2 = 0.0;
  for (double a : angles) {
    sum += a;
    sum2 += a * a;
  }
  r.mean_rad = sum / angles.size();
  r.stddev_rad = std::sqrt(std::max(0.0, sum2 / angles.size() - r.mean_rad * r.mean_rad));
  std::nth_element(angles.begin(), angles.begin() + angles.size() / 2, angles.end());
  r.median_rad = angles[angles.size() / 2];
  return r;
}

FibreSet read_tracts(const std::filesystem::path& path, double metres_per_unit) {
  std::ifstream in(path);
  if (!in) throw_bad_input("cannot open the tract file", {.file = path.string()});
  FibreSet set;
  std::string line;
  long line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::istringstream ss(line);
    std::vector<double> v;
    double x;
    while (ss >> x) v.push_back(x);
    if (v.empty()) continue;
    if (v.size() % 3 != 0 || v.size() < 6)
      throw_bad_input("a tract line must hold at least two points of three coordinates",
                      {.file = path.string(), .line = line_no});
    Points3 P(v.size() / 3, 3);
    for (std::size_t k = 0; k < v.size() / 3; ++k)
      P.row(k) = metres_per_unit * Vec3(v[3 * k], v[3 * k + 1], v[3 * k + 2]).transpose();
    set.fibres.push_back(std::move(P));
  }
  if (set.fibres.empty()) throw_bad_input("the tract file holds no tract", {.file = path.string()});
  return set;
}

std::string to_json(const FibreAnalysis& a) {
  nlohmann::json j;
  j["volume_m3"] = a.volume_m3;
  j["mean_fibre_length_m"] = a.mean_fibre_length_m;
  j["mean_pennation_deg"] = a.mean_pennation_rad * 180.0 / M_PI;
  j["pcsa_m2"] = a.pcsa_m2;
  j["pcsa_ravichandiran_m2"] = a.pcsa_ravichandiran_m2;
  j["origin_area_m2"] = a.origin_area_m2;
  j["insertion_area_m2"] = a.insertion_area_m2;
  j["fibre_count"] = a.fibres.size();
  nlohmann::json list = nlohmann::json::array();
  for (const FibreMeasures& m : a.fibres)
    list.push_back({{"length_m", m.length_m},
                    {"pennation_proximal_deg", m.pennation_proximal_rad * 180.0 / M_PI},
                    {"pennation_distal_deg", m.pennation_distal_rad * 180.0 / M_PI},
                    {"surface_angle_proximal_deg", m.surface_angle_proximal_rad * 180.0 / M_PI},
                    {"surface_angle_distal_deg", m.surface_angle_distal_rad * 180.0 / M_PI},
                    {"volume_share", m.volume_share}});
  j["fibres"] = std::move(list);
  return j.dump(2);
}

void write_fibre_csv(const std::filesystem::path& path, const FibreAnalysis& a) {
  write_file_atomically(path, [&](std::ostream& out) {
    out << "fibre,length_m,pennation_proximal_deg,pennation_distal_deg,surface_angle_proximal_deg,"
           "surface_angle_distal_deg,volume_share\n";
    out.precision(10);
    for (std::size_t i = 0; i < a.fibres.size(); ++i) {
      const FibreMeasures& m = a.fibres[i];
      out << i << ',' << m.length_m << ',' << m.pennation_proximal_rad * 180 / M_PI << ','
          << m.pennation_distal_rad * 180 / M_PI << ',' << m.surface_angle_proximal_rad * 180 / M_PI
          << ',' << m.surface_angle_distal_rad * 180 / M_PI << ',' << m.volume_share << '\n';
    }
  });
}

void write_fibres_vtp(const std::filesystem::path& path, const FibreSet& fibres,
                      const FibreAnalysis* analysis) {
  PolyData data;
  Eigen::Index total = 0;
  for (const Points3& P : fibres.fibres) total += P.rows();
  data.points.resize(total, 3);
  DataField parameter{"parameter", MatX(total, 1)};
  Eigen::Index row = 0;
  for (const Points3& P : fibres.fibres) {
    std::vector<int> line;
    const double length = calc_polyline_length(P);
    double s = 0.0;
    for (Eigen::Index k = 0; k < P.rows(); ++k) {
      if (k > 0) s += (P.row(k) - P.row(k - 1)).norm();
      data.points.row(row) = P.row(k);
      parameter.values(row, 0) = length > 0 ? s / length : 0.0;
      line.push_back(static_cast<int>(row++));
    }
    data.lines.push_back(std::move(line));
  }
  data.triangles.resize(0, 3);
  data.point_fields.push_back(std::move(parameter));
  const Eigen::Index n = static_cast<Eigen::Index>(fibres.size());
  DataField length{"length", MatX(n, 1)};
  for (Eigen::Index i = 0; i < n; ++i) length.values(i, 0) = calc_polyline_length(fibres.fibres[i]);
  data.cell_fields.push_back(std::move(length));
  if (analysis && analysis->fibres.size() == fibres.size()) {
    DataField pp{"pennation_proximal_deg", MatX(n, 1)}, pd{"pennation_distal_deg", MatX(n, 1)},
        vs{"volume_share", MatX(n, 1)};
    for (Eigen::Index i = 0; i < n; ++i) {
      pp.values(i, 0) = analysis->fibres[i].pennation_proximal_rad * 180 / M_PI;
      pd.values(i, 0) = analysis->fibres[i].pennation_distal_rad * 180 / M_PI;
      vs.values(i, 0) = analysis->fibres[i].volume_share;
    }
    data.cell_fields.push_back(std::move(pp));
    data.cell_fields.push_back(std::move(pd));
    data.cell_fields.push_back(std::move(vs));
  }
  write_polydata(path, data);
}

}  // namespace fascicle
