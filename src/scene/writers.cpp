// Built-in frame writers: ParaView series, per-muscle metric tables (.sto, .csv), summary.json.
#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/io/vtk_series.hpp"
#include "fascicle/scene/builtins.hpp"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>

namespace fascicle {

const std::vector<std::string>& get_muscle_metric_names() {
  static const std::vector<std::string> names = {
      "activation",        "musculotendon_length_m", "fiber_length_m",        "norm_fiber_length",
      "pennation_rad",     "tendon_length_m",        "tendon_force_N",        "active_fiber_force_N",
      "passive_fiber_force_N", "volume_m3",          "relative_volume_change",
      "max_bone_penetration_m", "max_muscle_overlap_m", "mean_fibre_length_m", "mean_pennation_rad",
      "max_muscle_overlap_growth_m"};
  return names;
}

std::vector<double> get_muscle_metrics(const Muscle& muscle, const MuscleFrame& f) {
  const MuscleOutputs& h = f.hill;
  const double activation = muscle.actuator ? h.activation : muscle.activation;
  return {activation,          f.musculotendon_length_m, h.fiber_length_m,        h.norm_fiber_length,
          h.pennation_rad,     h.tendon_length_m,        h.tendon_force_N,        h.active_fiber_force_N,
          h.passive_fiber_force_N, f.volume_m3,          f.relative_volume_change,
          f.max_bone_penetration_m, f.max_muscle_overlap_m, f.mean_fibre_length_m, f.mean_pennation_rad,
          f.max_muscle_overlap_growth_m};
}

namespace {

std::string frame_file(const std::string& kind, const std::string& name, int frame) {
  char num[16];
  std::snprintf(num, sizeof num, "%05d", frame);
  return kind + "_" + name + "_" + num + ".vtp";
}

Points3 transform_points(const Transform& X, const Points3& P) {
  return ((P * X.linear().transpose()).rowwise() + X.translation().transpose()).eval();
}

class ParaViewWriter final : public FrameWriter {
 public:
  void begin(const Model&, const RunInfo& info) override {
    folder_ = info.out_dir;
    frames_dir_ = info.basename + "_frames";
    series_ = std::make_unique<VtkSeriesWriter>(info.out_dir / (info.basename + ".pvd"));
  }

  void write_frame(const Model& model, const State& state, int frame) override {
    // The frame's files are gathered first, written in parallel (one VTK writer per file), then
    // listed in the series in a fixed order.
    struct Part {
      std::string name;
      std::string rel;  // file, relative to the output folder
      PolyData data;
      bool write = true;
      VtpCompression compression = VtpCompression::lz4;
    };
    std::vector<Part> parts;
    // LZ4 only where a file has a field that repeats (the force, one value over all cells of a
    // surface or all fibres); bones and action lines are stored raw (LZ4 gained 1.9 % on the VH
    // bones, 20 % on the demo's procedural ones; docs/scene-format.md).
    const auto write = [&](const std::string& part_name, const std::string& file, PolyData d,
                           VtpCompression compression = VtpCompression::lz4) {
      parts.push_back({part_name, frames_dir_ + "/" + file, std::move(d), true, compression});
    };
    // A bone that has not moved since its last file is listed again with that file (a fixed
    // shank is written once, not once per frame).
    last_bone_pose_.resize(model.bodies.size());
    for (size_t b = 1; b < model.bodies.size(); ++b) {
      const Body& body = model.bodies[b];
      if (body.mesh.V.rows() == 0) continue;
      const Transform& X = state.X_ground_body[b];
      LastBonePose& last = last_bone_pose_[b];
      if (!last.rel.empty() && last.X.matrix() == X.matrix()) {
        parts.push_back({"bone_" + body.name, last.rel, PolyData{}, false});
        continue;
      }
      PolyData d;
      d.points = transform_points(X, body.mesh.V);
      d.triangles = body.mesh.F;
      write("bone_" + body.name, frame_file("bone", body.name, frame), std::move(d), VtpCompression::none);
      last = {X, parts.back().rel};
    }
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const Muscle& muscle = model.muscles[m];
      const MuscleFrame& mf = state.muscles[m];
      const double force = mf.hill.tendon_force_N;
      if (mf.surface.rows() > 0) {
        PolyData d;
        d.points = mf.surface;
        d.triangles = muscle.rest_mesh.F;
        d.point_fields.push_back({"displacement_m", mf.surface - muscle.rest_mesh.V});
        d.cell_fields.push_back({"tendon_force_N", MatX::Constant(d.num_cells(), 1, force)});
        write("muscle_" + muscle.name, frame_file("muscle", muscle.name, frame), std::move(d));
      }
      if (mf.action_line.rows() >= 2) {
        PolyData d;
        d.points = mf.action_line;
        d.lines.emplace_back();
        for (int i = 0; i < mf.action_line.rows(); ++i) d.lines.back().push_back(i);
        MatX body(mf.action_line.rows(), 1);
        for (int i = 0; i < body.rows(); ++i) body(i, 0) = mf.action_line_bodies[i].v;
        d.point_fields.push_back({"body_index", body});
        d.cell_fields.push_back({"tendon_force_N", MatX::Constant(1, 1, force)});
        d.cell_fields.push_back({"musculotendon_length_m", MatX::Constant(1, 1, mf.musculotendon_length_m)});
        write("action_line_" + muscle.name, frame_file("action_line", muscle.name, frame), std::move(d),
              VtpCompression::none);
      }
      if (!mf.fibres.empty()) {
        PolyData d;
        long n = 0;
        for (const auto& f : mf.fibres) n += f.rows();
        d.points.resize(n, 3);
        MatX length(static_cast<Eigen::Index>(mf.fibres.size()), 1);
        long at = 0;
        for (size_t k = 0; k < mf.fibres.size(); ++k) {
          const Points3& f = mf.fibres[k];
          d.points.middleRows(at, f.rows()) = f;
          d.lines.emplace_back();
          double len = 0;
          for (long i = 0; i < f.rows(); ++i) {
            d.lines.back().push_back(static_cast<int>(at + i));
            if (i > 0) len += (f.row(i) - f.row(i - 1)).norm();
          }
          length(static_cast<Eigen::Index>(k), 0) = len;
          at += f.rows();
        }
        d.cell_fields.push_back({"fibre_length_m", length});
        const auto n_fibres = static_cast<Eigen::Index>(mf.fibres.size());
        if (mf.fibre_strain.size() == n_fibres) d.cell_fields.push_back({"fibre_strain", mf.fibre_strain});
        if (mf.fibre_pennation_rad.size() == n_fibres)
          d.cell_fields.push_back({"pennation_rad", mf.fibre_pennation_rad});
        // Each fibre stands for an equal share of the muscle's cross-section: it carries that share
        // of the Hill fibre force (active + passive).
        const double fibre_force = mf.hill.active_fiber_force_N + mf.hill.passive_fiber_force_N;
        if (std::isfinite(fibre_force))
          d.cell_fields.push_back({"fibre_force_N", MatX::Constant(n_fibres, 1, fibre_force / static_cast<double>(n_fibres))});
        write("fibres_" + muscle.name, frame_file("fibres", muscle.name, frame), std::move(d));
      }
    }
    parallel_for(parts.size(), [&](std::size_t i) {
      if (parts[i].write) write_polydata(folder_ / parts[i].rel, parts[i].data, parts[i].compression);
    });
    for (const Part& p : parts) series_->add(state.time_s, series_->find_or_add_part(p.name), p.rel);
    // The collection lists only complete frames: rewrite it after each frame.
    series_->commit();
  }

  void finish(const Model&) override {
    if (series_) series_->commit();
  }

  std::vector<std::filesystem::path> get_outputs() const override {
    if (!series_) return {};
    return {series_->get_pvd_path()};
  }

 private:
  std::filesystem::path folder_;
  std::string frames_dir_;
  std::unique_ptr<VtkSeriesWriter> series_;
  struct LastBonePose {
    Transform X;
    std::string rel;  // empty: no file yet
  };
  std::vector<LastBonePose> last_bone_pose_;  // by body
};

// Accumulates the metric rows; writes the table at finish() (also after a failure).
class MetricTableWriter final : public FrameWriter {
 public:
  explicit MetricTableWriter(bool sto) : sto_(sto) {}

  void begin(const Model& model, const RunInfo& info) override {
    path_ = info.out_dir / (info.basename + (sto_ ? "_muscles.sto" : "_muscles.csv"));
    table_ = Table{};
    table_.name = info.basename + "_muscles";
    for (const auto& m : model.muscles)
      for (const auto& metric : get_muscle_metric_names()) table_.labels.push_back(m.name + "." + metric);
    rows_.clear();
    times_.clear();
  }

  void write_frame(const Model& model, const State& state, int) override {
    std::vector<double> row;
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const auto v = get_muscle_metrics(model.muscles[m], state.muscles[m]);
      row.insert(row.end(), v.begin(), v.end());
    }
    rows_.push_back(std::move(row));
    times_.push_back(state.time_s);
  }

  void finish(const Model&) override {
    if (rows_.empty()) return;
    table_.time = Eigen::Map<const VecX>(times_.data(), static_cast<Eigen::Index>(times_.size()));
    table_.data.resize(static_cast<Eigen::Index>(rows_.size()), static_cast<Eigen::Index>(table_.labels.size()));
    for (size_t r = 0; r < rows_.size(); ++r)
      for (size_t c = 0; c < rows_[r].size(); ++c) table_.data(r, c) = rows_[r][c];
    // Metrics never computed (e.g. Hill outputs of a muscle without actuator) are left out.
    Table out = table_;
    std::vector<Eigen::Index> keep;
    out.labels.clear();
    for (Eigen::Index c = 0; c < table_.data.cols(); ++c) {
      if (!table_.data.col(c).array().isFinite().any()) continue;
      keep.push_back(c);
      out.labels.push_back(table_.labels[c]);
    }
    out.data.resize(table_.data.rows(), static_cast<Eigen::Index>(keep.size()));
    for (size_t k = 0; k < keep.size(); ++k) out.data.col(static_cast<Eigen::Index>(k)) = table_.data.col(keep[k]);
    if (sto_)
      write_sto(path_, out);
    else
      write_csv(path_, out);
  }

  std::vector<std::filesystem::path> get_outputs() const override { return {path_}; }

 private:
  bool sto_;
  std::filesystem::path path_;
  Table table_;
  std::vector<std::vector<double>> rows_;
  std::vector<double> times_;
};

// summary.json: frame count and, per muscle, the range of every metric; per body, mass and volume.
class SummaryWriter final : public FrameWriter {
 public:
  void begin(const Model& model, const RunInfo& info) override {
    info_ = info;
    path_ = info.out_dir / "summary.json";
    const size_t n = get_muscle_metric_names().size();
    lo_.assign(model.muscles.size(), std::vector<double>(n, std::numeric_limits<double>::infinity()));
    hi_.assign(model.muscles.size(), std::vector<double>(n, -std::numeric_limits<double>::infinity()));
    frames_ = 0;
    t0_ = t1_ = 0;
  }
  void write_frame(const Model& model, const State& state, int) override {
    if (frames_ == 0) t0_ = state.time_s;
    t1_ = state.time_s;
    ++frames_;
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const auto v = get_muscle_metrics(model.muscles[m], state.muscles[m]);
      for (size_t k = 0; k < v.size(); ++k) {
        if (!std::isfinite(v[k])) continue;
        lo_[m][k] = std::min(lo_[m][k], v[k]);
        hi_[m][k] = std::max(hi_[m][k], v[k]);
      }
    }
  }
  void finish(const Model& model) override {
    nlohmann::ordered_json j;
    j["scene"] = model.name;
    j["frames"] = frames_;
    j["frame_rate_hz"] = info_.frame_rate_hz;
    j["time_s"] = {t0_, t1_};
    j["complete"] = frames_ == info_.num_frames;
    for (size_t b = 1; b < model.bodies.size(); ++b) {
      const Body& body = model.bodies[b];
      j["bodies"][body.name] = {{"mass_kg", body.mass_kg}, {"mesh_volume_m3", body.mesh_volume_m3},
                                {"mesh_triangles", body.mesh.F.rows()}};
    }
    for (const auto& c : model.coordinates)
      j["coordinates"].push_back({{"name", c.name}, {"rotational", c.rotational}});
    const auto& names = get_muscle_metric_names();
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      auto& jm = j["muscles"][model.muscles[m].name];
      jm["representation"] = model.muscles[m].representation_name;
      jm["fibre_template"] = model.muscles[m].fibre_template;
      jm["rest_volume_m3"] = model.muscles[m].rest_volume_m3;
      for (size_t k = 0; k < names.size(); ++k)
        if (lo_[m][k] <= hi_[m][k]) jm["range"][names[k]] = {lo_[m][k], hi_[m][k]};
    }
    write_file_atomically(path_, [&](std::ostream& out) { out << j.dump(2) << "\n"; });
  }
  std::vector<std::filesystem::path> get_outputs() const override { return {path_}; }

 private:
  RunInfo info_;
  std::filesystem::path path_;
  std::vector<std::vector<double>> lo_, hi_;
  int frames_ = 0;
  double t0_ = 0, t1_ = 0;
};

}  // namespace

std::unique_ptr<FrameWriter> make_paraview_writer() { return std::make_unique<ParaViewWriter>(); }
std::unique_ptr<FrameWriter> make_sto_writer() { return std::make_unique<MetricTableWriter>(true); }
std::unique_ptr<FrameWriter> make_csv_writer() { return std::make_unique<MetricTableWriter>(false); }
std::unique_ptr<FrameWriter> make_summary_writer() { return std::make_unique<SummaryWriter>(); }

}  // namespace fascicle
