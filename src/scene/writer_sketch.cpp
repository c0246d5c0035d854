// Writer "sketch": OUT/<basename>_sketch.svg, a side view of the first frame — bone vertices as
// grey dots, each muscle's fibres and its action line — for reports and docs without ParaView.
#include "fascicle/io/svg_plot.hpp"
#include "fascicle/scene/builtins.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fascicle {
namespace {

class SketchWriter final : public FrameWriter {
 public:
  void begin(const Model&, const RunInfo& info) override {
    path_ = info.out_dir / (info.basename + "_sketch.svg");
    written_ = false;
  }

  void write_frame(const Model& model, const State& state, int) override {
    if (written_) return;
    // Horizontal axis x (anterior in OpenSim's frames); vertical: y or z, whichever spans more.
    Eigen::AlignedBox3d box;
    for (size_t b = 1; b < model.bodies.size(); ++b)
      for (Eigen::Index i = 0; i < model.bodies[b].mesh.V.rows(); ++i)
        box.extend(state.X_ground_body[b] * Vec3(model.bodies[b].mesh.V.row(i).transpose()));
    for (const MuscleFrame& m : state.muscles)
      for (Eigen::Index i = 0; i < m.action_line.rows(); ++i) box.extend(m.action_line.row(i).transpose());
    const int up = box.isEmpty() || box.sizes().y() >= box.sizes().z() ? 1 : 2;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    PlotSpec plot;
    plot.title = model.name + " at t = " + std::to_string(state.time_s) + " s";
    plot.x_label = "x (m)";
    plot.y_label = up == 1 ? "y (m)" : "z (m)";
    PlotSeries bones{.name = "bones", .markers = true, .marker_radius_px = 0.8, .colour = "#b0b0b0"};
    for (size_t b = 1; b < model.bodies.size(); ++b) {
      const Points3& V = model.bodies[b].mesh.V;
      const Eigen::Index step = std::max<Eigen::Index>(1, V.rows() / 1500);
      for (Eigen::Index i = 0; i < V.rows(); i += step) {
        const Vec3 p = state.X_ground_body[b] * Vec3(V.row(i).transpose());
        bones.x.push_back(p.x());
        bones.y.push_back(p[up]);
      }
    }
    if (!bones.x.empty()) plot.series.push_back(std::move(bones));
    for (size_t m = 0; m < model.muscles.size(); ++m) {
      const MuscleFrame& mf = state.muscles[m];
      PlotSeries s{.name = model.muscles[m].name};
      for (const Points3& f : mf.fibres) {
        for (Eigen::Index i = 0; i < f.rows(); ++i) {
          s.x.push_back(f(i, 0));
          s.y.push_back(f(i, up));
        }
        s.x.push_back(nan);
        s.y.push_back(nan);
      }
      for (Eigen::Index i = 0; i < mf.action_line.rows(); ++i) {
        s.x.push_back(mf.action_line(i, 0));
        s.y.push_back(mf.action_line(i, up));
      }
      if (!s.x.empty()) plot.series.push_back(std::move(s));
    }
    // Equal scales on both axes: the page's aspect follows the drawing's.
    const double w = std::max(box.isEmpty() ? 1.0 : box.sizes().x(), 1e-6);
    const double h = std::max(box.isEmpty() ? 1.0 : box.sizes()[up], 1e-6);
    plot.height_px = 900;
    plot.width_px = std::clamp(static_cast<int>(std::lround(900.0 * w / h)) + 220, 420, 1600);
    write_svg_plot(path_, plot);
    written_ = true;
  }

  void finish(const Model&) override {}
  std::vector<std::filesystem::path> get_outputs() const override {
    if (!written_) return {};
    return {path_};
  }

 private:
  std::filesystem::path path_;
  bool written_ = false;
};

}  // namespace

std::unique_ptr<FrameWriter> make_sketch_writer() { return std::make_unique<SketchWriter>(); }

}  // namespace fascicle
