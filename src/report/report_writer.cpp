// The "report" writer: viewer data files per frame, the manifest, and report.html.
#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/report/report.hpp"
#include "fascicle/report/viewer_data.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/state.hpp"

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include <cstdio>
#include <fstream>
#include <optional>
#include <set>
#include <sstream>

namespace fascicle {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

// One colour per muscle (sRGB 0…1), distinct hues around the reds and warm tones first.
constexpr double kPalette[][3] = {{0.85, 0.25, 0.22}, {0.93, 0.55, 0.18}, {0.60, 0.30, 0.70},
                                  {0.20, 0.55, 0.80}, {0.90, 0.40, 0.60}, {0.35, 0.70, 0.35},
                                  {0.75, 0.65, 0.20}, {0.25, 0.70, 0.70}, {0.55, 0.35, 0.20},
                                  {0.45, 0.45, 0.90}};

std::string frame_name(int frame) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "frames/%05d.bin", frame);
  return buf;
}

std::string read_file(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// A numeric CSV with a header line, as columns; nullopt when it is not one.
std::optional<json> read_numeric_csv(const fs::path& path) {
  std::ifstream in(path);
  std::string line;
  if (!std::getline(in, line)) return std::nullopt;
  std::vector<std::string> names;
  std::stringstream header(line);
  for (std::string cell; std::getline(header, cell, ',');) names.push_back(cell);
  std::vector<std::vector<double>> cols(names.size());
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream row(line);
    size_t c = 0;
    for (std::string cell; std::getline(row, cell, ','); ++c) {
      if (c >= cols.size()) return std::nullopt;
      char* end = nullptr;
      const double v = std::strtod(cell.c_str(), &end);
      if (end == cell.c_str()) return std::nullopt;
      cols[c].push_back(v);
    }
  }
  json table;
  table["columns"] = names;
  table["data"] = cols;
  return table;
}

// The Hill experiments' tables (fascicle muscle experiment / curves) found in the run folder or
// its experiments/ subfolder.
json find_experiments(const fs::path& out_dir) {
  static constexpr const char* kNames[] = {"isometric", "tetanus", "quick-release", "isotonic",
                                           "force_length", "force_velocity", "tendon_force_length"};
  json list = json::array();
  for (const fs::path& dir : {out_dir, out_dir / "experiments"}) {
    for (const char* name : kNames) {
      const fs::path csv = dir / (std::string(name) + ".csv");
      std::error_code ec;
      if (!fs::is_regular_file(csv, ec)) continue;
      if (auto table = read_numeric_csv(csv)) {
        (*table)["name"] = name;
        (*table)["file"] = fs::relative(csv, out_dir).generic_string();
        list.push_back(std::move(*table));
      }
    }
  }
  return list;
}

// Text placed inside an inline <script>/<style> element must not close it early.
std::string replace_all(std::string text, const std::string& from, const std::string& to) {
  for (size_t at = text.find(from); at != std::string::npos; at = text.find(from, at + to.size()))
    text.replace(at, from.size(), to);
  return text;
}
std::string escape_json_for_script(const std::string& text) {
  return replace_all(replace_all(text, "</", "<\\/"), "<!--", "<\\u0021--");
}
std::string escape_js_for_script(const std::string& text) {
  return replace_all(replace_all(text, "</script", "<\\/script"), "</SCRIPT", "<\\/SCRIPT");
}
std::string escape_css_for_style(const std::string& text) { return replace_all(text, "</style", "<\\/style"); }

class ReportWriter final : public FrameWriter {
 public:
  explicit ReportWriter(ReportOptions options) : options_(std::move(options)) {}

  void begin(const Model& model, const RunInfo& info) override {
    info_ = info;
    begin_time_ = fs::file_time_type::clock::now();
    viewer_dir_ = info.out_dir / "viewer";
    std::error_code ec;
    fs::remove_all(viewer_dir_ / "frames", ec);
    fs::create_directories(viewer_dir_ / "frames", ec);
    if (ec)
      throw_bad_input("cannot create " + (viewer_dir_ / "frames").string() + ": " + ec.message(),
                      {.file = viewer_dir_.string(), .suggestion = "choose a writable output folder"});
    drawn_bodies_.clear();
    for (size_t b = 1; b < model.bodies.size(); ++b)
      if (model.bodies[b].mesh.V.rows() > 0) drawn_bodies_.push_back(b);
    frame_bytes_.clear();
    frame_numbers_.clear();
    frame_files_.clear();
    times_.clear();
    metrics_.assign(model.muscles.size(), {});
    box_ = {};
    write_static(model);
    write_manifest(model);
  }

  void write_frame(const Model& model, const State& state, int frame) override {
    ViewerFrame vf;
    vf.time_s = state.time_s;
    for (size_t b : drawn_bodies_) vf.X_ground_body.push_back(state.X_ground_body[b]);
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const MuscleFrame& mf = state.muscles[m];
      ViewerMuscleFrame out;
      if (mf.surface.rows() == model.muscles[m].rest_mesh.V.rows()) out.surface = mf.surface;
      out.action_line = mf.action_line;
      out.fibres = mf.fibres;
      if (mf.fibre_strain.size() == static_cast<Eigen::Index>(mf.fibres.size())) out.fibre_strain = mf.fibre_strain;
      vf.muscles.push_back(std::move(out));
      metrics_[m].push_back(get_muscle_metrics(model.muscles[m], mf));
    }
    const ViewerBox box = calc_viewer_box(vf);
    box_ = frame_bytes_.empty() ? box : merge_boxes(box_, box);
    const std::string bytes = encode_viewer_frame(vf, PositionEncoding::float32);
    write_file_atomically(viewer_dir_ / frame_name(frame), [&](std::ostream& out) { out << bytes; });
    frame_files_.resize(std::max<size_t>(frame_files_.size(), frame + 1));
    frame_files_[frame] = frame_name(frame);
    frame_bytes_.push_back(bytes);  // float32: re-encoded for the page at finish()
    frame_numbers_.push_back(frame);
    times_.push_back(state.time_s);
  }

  void finish(const Model& model) override {
    write_manifest(model);
    write_html(model);
  }

  std::vector<fs::path> get_outputs() const override {
    return {info_.out_dir / "report.html", viewer_dir_ / "manifest.json"};
  }

 private:
  void write_static(const Model& model) {
    ViewerMesh mesh;
    for (size_t b : drawn_bodies_) {
      mesh.body_vertices.push_back(model.bodies[b].mesh.V);
      mesh.body_triangles.push_back(model.bodies[b].mesh.F);
    }
    for (const Muscle& m : model.muscles) mesh.muscle_triangles.push_back(m.rest_mesh.F);
    mesh_bytes_ = encode_viewer_mesh(mesh);
    write_file_atomically(viewer_dir_ / "mesh.bin", [&](std::ostream& out) { out << mesh_bytes_; });
  }

  json make_manifest(const Model& model) const {
    json j;
    j["format"] = "fascicle-viewer";
    j["version"] = 1;
    j["scene"] = model.name;
    j["frames_expected"] = info_.num_frames;
    j["frames_written"] = frame_bytes_.size();
    j["complete"] = static_cast<int>(frame_bytes_.size()) == info_.num_frames && info_.num_frames > 0;
    j["frame_rate_hz"] = info_.frame_rate_hz;
    j["times_s"] = times_;
    j["mesh_file"] = "mesh.bin";
    json files = json::array();
    for (int f : frame_numbers_) files.push_back(frame_files_[f]);
    j["frame_files"] = files;
    for (size_t b : drawn_bodies_) {
      const Body& body = model.bodies[b];
      // Pose at the default coordinates (4×4 column-major): drawn when no frame was written.
      std::vector<double> X_default(16, 0.0);
      if (b < model.X_ground_body_default.size())
        Eigen::Map<Mat4>(X_default.data()) = model.X_ground_body_default[b].matrix();
      j["bodies"].push_back({{"name", body.name}, {"mass_kg", body.mass_kg},
                             {"mesh_volume_m3", body.mesh_volume_m3}, {"X_ground_default", X_default}});
    }
    if (drawn_bodies_.empty()) j["bodies"] = json::array();
    const auto& names = get_muscle_metric_names();
    j["metric_names"] = names;
    j["muscles"] = json::array();
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const Muscle& muscle = model.muscles[m];
      const auto& c = kPalette[m % std::size(kPalette)];
      json jm = {{"name", muscle.name},
                 {"color", {c[0], c[1], c[2]}},
                 {"representation", muscle.representation_name},
                 {"actuator", muscle.actuator_type},
                 {"fibre_template", muscle.fibre_template},
                 {"rest_volume_m3", muscle.rest_volume_m3},
                 {"has_surface", muscle.rest_mesh.F.rows() > 0}};
      json metrics;
      for (size_t k = 0; k < names.size(); ++k) {
        json series = json::array();
        for (const auto& row : metrics_[m]) series.push_back(row[k]);  // NaN → null
        metrics[names[k]] = series;
      }
      jm["metrics"] = metrics;
      j["muscles"].push_back(jm);
    }
    j["box_m"] = {{box_.lo.x(), box_.lo.y(), box_.lo.z()}, {box_.hi.x(), box_.hi.y(), box_.hi.z()}};
    std::error_code ec;
    // Only a summary.json of this run (a writer listed before "report"), never a stale one.
    if (fs::is_regular_file(info_.out_dir / "summary.json", ec) &&
        fs::last_write_time(info_.out_dir / "summary.json", ec) >= begin_time_ && !ec) {
      try {
        std::ifstream in(info_.out_dir / "summary.json");
        j["summary"] = json::parse(in);
      } catch (const std::exception&) {
        spdlog::warn("report: summary.json is not valid JSON; left out of the report");
      }
    }
    j["experiments"] = find_experiments(info_.out_dir);
    return j;
  }

  void write_manifest(const Model& model) {
    const json j = make_manifest(model);
    write_file_atomically(viewer_dir_ / "manifest.json", [&](std::ostream& out) { out << j.dump() << "\n"; });
  }

  // The frames embedded in the page: every k-th (and the last) so that they fit the budget.
  std::vector<size_t> choose_embedded_frames(size_t bytes_per_frame) const {
    std::vector<size_t> chosen;
    const size_t n = frame_bytes_.size();
    if (n == 0) return chosen;
    const size_t fit = std::max<size_t>(2, options_.html_frame_budget_bytes / std::max<size_t>(bytes_per_frame, 1));
    const size_t step = (n + fit - 1) / fit;
    for (size_t i = 0; i < n; i += std::max<size_t>(step, 1)) chosen.push_back(i);
    if (chosen.back() != n - 1) chosen.push_back(n - 1);
    return chosen;
  }

  void write_html(const Model& model) {
    const ViewerBox box = pad_box(box_, 1e-6);
    std::vector<std::string> encoded;
    const auto get_frame = [&](size_t i) { return decode_viewer_frame(frame_bytes_[i]); };
    size_t per_frame = 0;
    if (!frame_bytes_.empty()) per_frame = encode_viewer_frame(get_frame(0), PositionEncoding::uint16, box).size();
    const std::vector<size_t> chosen = choose_embedded_frames(per_frame);
    json manifest = make_manifest(model);
    manifest["box_m"] = {{box.lo.x(), box.lo.y(), box.lo.z()}, {box.hi.x(), box.hi.y(), box.hi.z()}};
    json embedded;
    embedded["position_encoding"] = "uint16";
    embedded["frame_indices"] = chosen;
    embedded["subsampled"] = chosen.size() < frame_bytes_.size();
    embedded["step"] = chosen.size() > 1 ? chosen[1] - chosen[0] : 1;
    manifest["embedded"] = embedded;

    std::string data;
    data += "<script type=\"application/json\" id=\"fascicle-manifest\">" + escape_json_for_script(manifest.dump()) +
            "</script>\n";
    data += "<script type=\"application/octet-stream\" id=\"fascicle-mesh\">" + encode_base64(mesh_bytes_) +
            "</script>\n";
    for (size_t i : chosen)
      data += "<script type=\"application/octet-stream\" class=\"fascicle-frame\">" +
              encode_base64(encode_viewer_frame(get_frame(i), PositionEncoding::uint16, box)) + "</script>\n";

    std::string css, js;
    const fs::path assets = options_.viewer_dir.empty() ? find_viewer_assets() : options_.viewer_dir;
    if (!assets.empty() && fs::exists(assets / "viewer.js")) {
      css = read_file(assets / "viewer.css");
      js = read_file(assets / "viewer.js");
    } else {
      spdlog::warn("report: the viewer assets were not found (build them with `make`, or set "
                   "FASCICLE_VIEWER_DIR); report.html shows the run's summary only");
    }
    const std::string page = make_viewer_page("fascicle report — " + model.name, css, js, data);
    write_file_atomically(info_.out_dir / "report.html", [&](std::ostream& out) { out << page; });
  }

  ReportOptions options_;
  RunInfo info_;
  fs::file_time_type begin_time_;
  fs::path viewer_dir_;
  std::vector<size_t> drawn_bodies_;
  std::string mesh_bytes_;
  std::vector<std::string> frame_bytes_;  // per frame written, float32 encoding
  std::vector<int> frame_numbers_;
  std::vector<std::string> frame_files_;
  std::vector<double> times_;
  std::vector<std::vector<std::vector<double>>> metrics_;  // [muscle][frame][metric]
  ViewerBox box_;
};

}  // namespace

std::unique_ptr<FrameWriter> make_report_writer(const ReportOptions& options) {
  return std::make_unique<ReportWriter>(options);
}

void register_report_writers(Registry& registry) {
  registry.writers.add("report", [] { return make_report_writer(); });
}

std::string make_viewer_page(const std::string& title, const std::string& css, const std::string& js,
                             const std::string& embedded_data) {
  std::string page = "<!doctype html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
                     "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n<title>";
  for (char c : title) page += c == '<' ? std::string("&lt;") : c == '&' ? std::string("&amp;") : std::string(1, c);
  page += "</title>\n<style>" + escape_css_for_style(css) + "</style>\n</head>\n<body>\n";
  if (js.empty()) {
    page += "<div id=\"fascicle-missing\" style=\"font-family:sans-serif;padding:2em\"><h1>fascicle viewer "
            "not available</h1><p>The viewer's JavaScript was not found when this page was written. Build it "
            "with <code>make</code> (it writes viewer/dist) or set FASCICLE_VIEWER_DIR, then write the run "
            "again. The run's data is embedded below this message.</p></div>\n";
  } else {
    page += "<div id=\"app\"></div>\n";
  }
  page += embedded_data;
  if (!js.empty()) page += "<script>" + escape_js_for_script(js) + "</script>\n";
  page += "</body>\n</html>\n";
  return page;
}

}  // namespace fascicle
