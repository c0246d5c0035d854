// `fascicle muscle experiment ...` and `fascicle muscle curves ...`: the classical Hill-muscle
// experiments (seed 000 §4.6) and the normalised curves, as CSV tables and SVG plots.
#include "commands.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/io/svg_plot.hpp"
#include "fascicle/musculotendon/experiments.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"
#include "fascicle/musculotendon/params_json.hpp"

#include <spdlog/spdlog.h>

#include <filesystem>
#include <memory>

namespace fascicle::cli {

namespace {
struct MuscleOptions {
  std::string model = "millard";
  std::string params_json;
  std::string osim;
  std::string muscle;
  std::string out;
  std::string kind;
  bool rigid = false;
};

MuscleParameters load_parameters(const MuscleOptions& o, bool model_given) {
  if (!o.params_json.empty() && !o.osim.empty()) {
    throw_usage("give either --params or --osim, not both");
  }
  MuscleParameters p;
  if (!o.params_json.empty()) {
    p = read_muscle_parameters_json(o.params_json);
  } else if (!o.osim.empty()) {
    if (o.muscle.empty()) throw_usage("--osim needs --muscle NAME");
    p = read_osim_muscle(o.osim, o.muscle);
  } else {
    p = default_muscle_parameters(parse_muscle_model(o.model));
    p.name = std::string("default_") + to_string(p.model);
  }
  if (model_given && parse_muscle_model(o.model) != p.model) {
    throw_usage(std::string("--model ") + o.model + " contradicts the parameter source, which is a " +
                opensim_class(p.model));
  }
  if (o.rigid) p.rigid_tendon = true;
  return p;
}

void write_csv(const std::filesystem::path& path, const ExperimentTable& t) {
  write_file_atomically(path, [&](std::ostream& out) {
    out.precision(12);
    for (size_t j = 0; j < t.columns.size(); ++j) out << (j ? "," : "") << t.columns[j];
    out << '\n';
    for (const auto& r : t.rows) {
      for (size_t j = 0; j < r.size(); ++j) out << (j ? "," : "") << r[j];
      out << '\n';
    }
  });
}

void write_summary(const std::filesystem::path& path, const MuscleParameters& p,
                   const ExperimentResult& r) {
  write_file_atomically(path, [&](std::ostream& out) {
    out.precision(12);
    out << "quantity,value\n";
    for (const auto& [k, v] : r.summary) out << k << ',' << v << '\n';
  });
  for (const auto& [k, v] : r.summary) spdlog::info("{} {}: {} = {:.6g}", opensim_class(p.model), p.name, k, v);
}

PlotSeries series(const ExperimentTable& t, const std::string& name, const std::string& x,
                  const std::string& y, double yscale = 1.0, bool markers = false) {
  PlotSeries s{name, t.column(x), t.column(y), markers};
  for (double& v : s.y) v *= yscale;
  return s;
}

void run_experiment(const MuscleOptions& o, bool model_given) {
  const MuscleParameters p = load_parameters(o, model_given);
  const Musculotendon m = compile_musculotendon(p);
  const std::filesystem::path dir = o.out;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw_bad_input("cannot create output folder: " + ec.message(), {.file = dir.string()});
  const std::string title = std::string(opensim_class(p.model)) + " '" + p.name + "'";
  ExperimentResult r;
  PlotSpec plot;
  if (o.kind == "isometric") {
    r = run_isometric_experiment(m);
    plot = {"Isometric force-length, " + title, "fibre length / optimal fibre length (-)",
            "fibre force (N)",
            {series(r.table, "total", "norm_fiber_length", "total_fiber_force_N"),
             series(r.table, "active", "norm_fiber_length", "active_fiber_force_N"),
             series(r.table, "passive", "norm_fiber_length", "passive_fiber_force_N")}};
  } else if (o.kind == "tetanus") {
    r = run_tetanus_experiment(m);
    plot = {"Rise to tetanus, " + title, "time (s)", "tendon force (N)",
            {series(r.table, "tendon force", "time_s", "tendon_force_N")}};
  } else if (o.kind == "quick-release") {
    r = run_quick_release_experiment(m);
    plot = {"Quick release to half the isometric force, " + title, "time (s)", "length (mm)",
            {series(r.table, "musculotendon - initial", "time_s", "musculotendon_length_m", 1e3),
             series(r.table, "fibre", "time_s", "fiber_length_m", 1e3),
             series(r.table, "tendon", "time_s", "tendon_length_m", 1e3)}};
    const double l0 = r.table.rows.front()[1] * 1e3;
    for (double& v : plot.series[0].y) v -= l0;
  } else if (o.kind == "isotonic") {
    r = run_isotonic_experiment(m);
    // Model F-V curve for comparison: normalised force vs normalised velocity at l0.
    PlotSeries curve{"force-velocity curve (a = 1)", {}, {}};
    for (int i = 0; i <= 200; ++i) {
      const double v = -1.0 + 2.2 * i / 200.0;
      curve.x.push_back(v);
      curve.y.push_back(calc_force_velocity(m, 1.0, v).value);
    }
    plot = {"Isotonic contractions, " + title, "initial fibre velocity / (l0 vmax) (-)",
            "force-velocity multiplier (-)",
            {curve, series(r.table, "isotonic runs", "initial_norm_fiber_velocity",
                           "force_velocity_multiplier", 1.0, true)}};
  } else {
    throw_usage("unknown experiment '" + o.kind + "'",
                {.suggestion = "use isometric, tetanus, quick-release or isotonic"});
  }
  write_csv(dir / (o.kind + ".csv"), r.table);
  write_summary(dir / (o.kind + "_summary.csv"), p, r);
  write_svg_plot(dir / (o.kind + ".svg"), plot);
  spdlog::info("wrote {}/{}.csv, .svg and _summary.csv", dir.string(), o.kind);
}

void run_curves(const MuscleOptions& o, bool model_given) {
  const MuscleParameters p = load_parameters(o, model_given);
  const Musculotendon m = compile_musculotendon(p);
  const std::filesystem::path dir = o.out;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw_bad_input("cannot create output folder: " + ec.message(), {.file = dir.string()});
  ExperimentTable fl{{"norm_fiber_length", "active_force_length", "d_active_force_length",
                      "passive_force_length", "d_passive_force_length"}, {}};
  for (int i = 0; i <= 300; ++i) {
    const double l = 0.3 + 1.6 * i / 300.0;
    const CurvePoint a = calc_active_force_length(m, l), b = calc_passive_force_length(m, l);
    fl.rows.push_back({l, a.value, a.derivative, b.value, b.derivative});
  }
  ExperimentTable fv{{"norm_fiber_velocity", "force_velocity", "d_force_velocity"}, {}};
  for (int i = 0; i <= 300; ++i) {
    const double v = -1.1 + 2.2 * i / 300.0;
    const CurvePoint c = calc_force_velocity(m, 1.0, v);
    fv.rows.push_back({v, c.value, c.derivative});
  }
  ExperimentTable ft{{"norm_tendon_length", "tendon_force_length", "d_tendon_force_length"}, {}};
  const double strain_max = 1.6 * (calc_tendon_length_for_force(m, 1.0) / p.tendon_slack_length_m - 1.0);
  for (int i = 0; i <= 300; ++i) {
    const double t = 1.0 - 0.1 * strain_max + 1.1 * strain_max * i / 300.0;
    const CurvePoint c = calc_tendon_force_length(m, t);
    ft.rows.push_back({t, c.value, c.derivative});
  }
  write_csv(dir / "force_length.csv", fl);
  write_csv(dir / "force_velocity.csv", fv);
  write_csv(dir / "tendon_force_length.csv", ft);
  const std::string title = std::string(opensim_class(p.model)) + " '" + p.name + "'";
  write_svg_plot(dir / "force_length.svg",
                 {"Force-length curves, " + title, "fibre length / l0 (-)", "force / F0 (-)",
                  {series(fl, "active", "norm_fiber_length", "active_force_length"),
                   series(fl, "passive", "norm_fiber_length", "passive_force_length")}});
  write_svg_plot(dir / "force_velocity.svg",
                 {"Force-velocity curve (a = 1), " + title, "fibre velocity / (l0 vmax) (-)",
                  "force / (a fal F0) (-)", {series(fv, "fv", "norm_fiber_velocity", "force_velocity")}});
  write_svg_plot(dir / "tendon_force_length.svg",
                 {"Tendon force-length curve, " + title, "tendon length / slack length (-)",
                  "force / F0 (-)",
                  {series(ft, "tendon", "norm_tendon_length", "tendon_force_length")}});
  spdlog::info("wrote normalised curves of {} to {}", title, dir.string());
}

void add_source_options(CLI::App* c, MuscleOptions& o) {
  c->add_option("--model", o.model, "thelen | millard | degroote (default millard)");
  c->add_option("--params", o.params_json, "Muscle parameter JSON file (docs/musculotendon.md)");
  c->add_option("--osim", o.osim, "OpenSim model file to take the muscle from");
  c->add_option("--muscle", o.muscle, "Muscle name in the --osim file");
  c->add_flag("--rigid-tendon", o.rigid, "Use the rigid-tendon variant");
  c->add_option("--out", o.out, "Output folder")->required();
}
}  // namespace

void add_muscle_commands(CLI::App& app, Invocation& run) {
  CLI::App* muscle = app.add_subcommand("muscle", "Hill-type musculotendon models");
  muscle->require_subcommand(1);
  auto opts = std::make_shared<MuscleOptions>();
  CLI::App* exp = muscle->add_subcommand(
      "experiment", "Run isometric | tetanus | quick-release | isotonic; writes CSV + SVG");
  exp->add_option("kind", opts->kind, "isometric | tetanus | quick-release | isotonic")
      ->required()
      ->check(CLI::IsMember({"isometric", "tetanus", "quick-release", "isotonic"}));
  add_source_options(exp, *opts);
  exp->callback([opts, exp, &run] {
    const bool model_given = exp->count("--model") > 0;
    run.action = [opts, model_given] { run_experiment(*opts, model_given); };
  });
  CLI::App* curves = muscle->add_subcommand("curves", "Write the normalised curves (CSV + SVG)");
  add_source_options(curves, *opts);
  curves->callback([opts, curves, &run] {
    const bool model_given = curves->count("--model") > 0;
    run.action = [opts, model_given] { run_curves(*opts, model_given); };
  });
}

}  // namespace fascicle::cli
