// `fascicle solid fit|info|export|simulate`: B-spline solid muscles (docs/bspline-solids.md,
// docs/solid-dynamics.md).
#include "commands.hpp"

#include "fascicle/bspline/fibres.hpp"
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/solid_io.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/units.hpp"
#include "fascicle/dynamics/solid_dynamics.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/io/polydata.hpp"
#include "fascicle/io/table.hpp"
#include "fascicle/io/vtk_series.hpp"
#include "fascicle/core/atomic_file.hpp"

#include <spdlog/spdlog.h>

#include <fmt/format.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>

namespace fascicle::cli {

namespace {

// Mean of the points in a CSV/whitespace table (x y z per row; rows that are not three numbers,
// such as a header, are skipped), scaled to metres.
Vec3 read_point_centroid(const std::string& path, double scale) {
  std::ifstream in(path);
  if (!in) throw_bad_input("cannot open the points file", ErrorContext{.file = path});
  std::string line;
  Vec3 sum = Vec3::Zero();
  int n = 0;
  while (std::getline(in, line)) {
    for (char& c : line)
      if (c == ',' || c == ';' || c == '\t') c = ' ';
    std::istringstream ss(line);
    double x, y, z;
    if (ss >> x >> y >> z) {
      sum += Vec3(x, y, z);
      ++n;
    }
  }
  if (n == 0) {
    throw_bad_input("no points (rows of x, y, z) found", ErrorContext{.file = path});
  }
  return scale * sum / n;
}

std::array<int, 3> parse_triple(const std::string& text, const char* what) {
  std::array<int, 3> v{};
  if (std::sscanf(text.c_str(), "%dx%dx%d", &v[0], &v[1], &v[2]) != 3 || v[0] < 2 || v[1] < 3 ||
      v[2] < 2) {
    throw_usage(fmt::format("{} must look like 4x16x14 (u radial x v around x w along), got '{}'",
                            what, text));
  }
  return v;
}

struct SimulateArgs {
  std::string solid, out, activation = "1", fix = "origin,insertion", integrator = "backward-euler",
              volume = "exact";
  double duration = 0.5, dt = 1e-3, frame_dt = 0.01, tendon = 0.0, pennation = 0.0;
  double c1 = 2e3, damping = 0.0, explicit_safety = 0.5, tendon_modulus = 2e6;
  double release = -1.0;  // quick release: the insertion is let go at this time (s)
  int reuse = SolverOptions{}.reuse_factorisation_steps;  // keep a factorisation over <= N steps
  bool gravity = false;
  bool extrapolate = false;     // --extrapolate-start given (the solver's default is on)
  bool no_extrapolate = false;  // --no-extrapolate-start: Newton starts from x_n + h v_n
};

// Excitation over time: a constant in [0, 1] or the first data column of a .sto/.mot/.csv table.
std::function<double(double)> make_excitation(const std::string& text) {
  char* end = nullptr;
  const double v = std::strtod(text.c_str(), &end);
  if (end && *end == '\0' && end != text.c_str()) {
    if (!(v >= 0.0 && v <= 1.0))
      throw_usage(fmt::format("--activation {} is outside [0, 1]", text));
    return [v](double) { return v; };
  }
  auto table = std::make_shared<Table>(read_table(text));
  if (table->columns() < 1 || table->rows() < 1)
    throw_bad_input("the activation table has no data column", ErrorContext{.file = text});
  return [table](double t) { return std::clamp(calc_row_at(*table, t)[0], 0.0, 1.0); };
}

// One frame of the ParaView series: boundary surface, fibre curves, hexahedral volume.
void write_solid_frame(const std::filesystem::path& dir, VtkSeriesWriter& series,
                       const BSplineSolid& rest, const Points3& P, int frame, double t) {
  BSplineSolid s = rest;
  s.P = P;
  const BoundaryTessellation b = make_boundary_tessellation(s, 3);
  const std::string stem = fmt::format("{:05d}", frame);
  write_polydata(dir / ("boundary_" + stem + ".vtp"), make_polydata(b.mesh));
  write_polylines_vtp(dir / ("fibres_" + stem + ".vtp"), calc_fibre_curves(s, 5, 5, 25));
  const VolumeTessellation v = make_volume_tessellation(s, 2);
  write_hexahedra_vtu(dir / ("volume_" + stem + ".vtu"), v.V, v.hexes);
  series.add(t, series.find_or_add_part("boundary"), "boundary_" + stem + ".vtp");
  series.add(t, series.find_or_add_part("fibres"), "fibres_" + stem + ".vtp");
  series.add(t, series.find_or_add_part("volume"), "volume_" + stem + ".vtu");
  series.commit();
}

void run_simulate(const SimulateArgs& a) {
  const BSplineSolid rest = read_solid(a.solid);
  SolidDynamicsSpec spec;
  spec.ground.c1_Pa = a.c1;
  spec.ground.c2_Pa = 0.5 * a.c1;
  spec.rayleigh_alpha_1_s = a.damping;
  spec.tendon_fraction_start = spec.tendon_fraction_end = a.tendon;
  spec.tendon_modulus_Pa = a.tendon_modulus;
  spec.pennation_rad = a.pennation;
  if (!a.gravity) spec.gravity_m_s2.setZero();
  if (a.volume == "exact") spec.volume = VolumeMethod::exact;
  else if (a.volume == "penalty") spec.volume = VolumeMethod::penalty;
  else if (a.volume == "none") spec.volume = VolumeMethod::none;
  else throw_usage("--volume must be exact, penalty or none");
  std::stringstream fixes(a.fix);
  std::string item;
  while (std::getline(fixes, item, ',')) {
    if (item == "origin") spec.attachments.push_back({"origin", -1, find_end_layer(rest, 0)});
    else if (item == "insertion") spec.attachments.push_back({"insertion", -1, find_end_layer(rest, 1)});
    else if (item != "none" && !item.empty())
      throw_usage(fmt::format("--fix takes origin, insertion or none, got '{}'", item));
  }
  SolverOptions o;
  if (a.integrator == "backward-euler") o.integrator = Integrator::backward_euler;
  else if (a.integrator == "symplectic-euler") o.integrator = Integrator::symplectic_euler;
  else if (a.integrator == "quasi-static") o.integrator = Integrator::quasi_static;
  else throw_usage("--integrator must be backward-euler, symplectic-euler or quasi-static");
  o.explicit_safety = a.explicit_safety;
  o.reuse_factorisation_steps = a.reuse;
  o.extrapolate_start = a.extrapolate || (o.extrapolate_start && !a.no_extrapolate);
  if (a.extrapolate && o.integrator != Integrator::backward_euler)
    throw_usage("--extrapolate-start applies to --integrator backward-euler only");
  if (!(a.dt > 0.0) || !(a.duration > 0.0) || !(a.frame_dt >= a.dt))
    throw_usage("need dt > 0, duration > 0 and frame-dt >= dt");
  const auto excitation = make_excitation(a.activation);
  auto model = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(rest, spec));
  SolidDynamicsSolver solver(model, o);
  // Quick release: the same solid with the insertion attachment removed, continued from the state.
  std::shared_ptr<const SolidDynamicsModel> released;
  if (a.release >= 0.0) {
    SolidDynamicsSpec rs = spec;
    std::erase_if(rs.attachments, [](const SolidAttachmentSpec& x) { return x.name == "insertion"; });
    released = std::make_shared<const SolidDynamicsModel>(compile_solid_dynamics(rest, rs));
  }

  const std::filesystem::path dir(a.out);
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) throw_bad_input("cannot create the output folder: " + ec.message(), ErrorContext{.file = a.out});
  VtkSeriesWriter series(dir / "solid.pvd");
  std::string csv = "time_s,volume_m3,volume_error,mean_fibre_length_m,mean_fibre_stretch,"
                    "mean_pennation_rad,kinetic_J,elastic_J,activation,newton_iterations\n";
  auto record = [&](int iterations) {
    const SolidMetrics mm = solver.calc_metrics({});
    csv += fmt::format("{:.6f},{:.9e},{:.6e},{:.6e},{:.6f},{:.6f},{:.6e},{:.6e},{:.4f},{}\n",
                       mm.time_s, mm.volume_m3, mm.volume_error, mm.mean_fibre_length_m,
                       mm.mean_fibre_stretch, mm.mean_pennation_rad, mm.energies.kinetic_J,
                       mm.energies.elastic_J, mm.activation, iterations);
    write_file_atomically(dir / "metrics.csv", [&](std::ostream& os) { os << csv; });
  };
  int frame = 0;
  write_solid_frame(dir, series, rest, solver.get_state().P, frame++, 0.0);
  record(0);
  const int frames = static_cast<int>(std::ceil(a.duration / a.frame_dt - 1e-9));
  const int sub = std::max(1, static_cast<int>(std::round(a.frame_dt / a.dt)));
  for (int f = 1; f <= frames; ++f) {
    int iterations = 0;
    try {
      for (int k = 0; k < sub; ++k) {
        if (released && solver.get_state().time_s >= a.release - 1e-12) {
          SolidDynamicsSolver next(released, o);
          next.set_state(solver.get_state());
          solver = std::move(next);
          released.reset();
          spdlog::info("released the insertion at t = {:.4f} s", solver.get_state().time_s);
        }
        StepInputs in;
        in.excitation = excitation(solver.get_state().time_s);
        iterations += solver.step(a.frame_dt / sub, in).newton_iterations;
      }
    } catch (const Error& e) {
      // The last good state is the solver's: write it as the final frame, then report.
      write_solid_frame(dir, series, rest, solver.get_state().P, frame++, solver.get_state().time_s);
      record(iterations);
      throw;
    }
    write_solid_frame(dir, series, rest, solver.get_state().P, frame++, solver.get_state().time_s);
    record(iterations);
  }
  const SolidMetrics mm = solver.calc_metrics({});
  fmt::print("simulated {:.3f} s of '{}' ({} frames): volume error {:.2e}, mean fibre stretch {:.4f}, "
             "mean pennation {:.2f} deg; wrote {}\n",
             mm.time_s, rest.name, frame, mm.volume_error, mm.mean_fibre_stretch,
             mm.mean_pennation_rad * 180.0 / M_PI, a.out);
}

void print_solid_info(const BSplineSolid& s) {
  fmt::print("name: {}\n", s.name.empty() ? "(unnamed)" : s.name);
  for (int d = 0; d < 3; ++d) {
    const auto& b = s.basis[d];
    fmt::print("{}: degree {}, {} control points, {}{}, domain [{}, {}]\n", "uvw"[d], b.degree,
               b.num_control, b.periodic ? "periodic" : (b.is_clamped() ? "clamped" : "unclamped"),
               "", b.get_lower(), b.get_upper());
  }
  fmt::print("fibre direction: {}\n", "uvw"[static_cast<int>(s.fibre_direction)]);
  const double vq = calc_volume(s);
  fmt::print("volume (quadrature of det J): {:.9g} m^3 ({:.4f} cm^3)\n", vq, vq * 1e6);
  bool clamped = true;
  for (const auto& b : s.basis) clamped = clamped && (b.periodic || b.is_clamped());
  if (clamped) fmt::print("volume (boundary formula):    {:.9g} m^3\n", calc_boundary_volume(s));
  const Vec3 lo = s.P.colwise().minCoeff(), hi = s.P.colwise().maxCoeff();
  fmt::print("control-point bounds: [{:.4g}, {:.4g}, {:.4g}] .. [{:.4g}, {:.4g}, {:.4g}] m\n", lo[0],
             lo[1], lo[2], hi[0], hi[1], hi[2]);
}

}  // namespace

void add_solid_commands(CLI::App& app, Invocation& run) {
  CLI::App* solid = app.add_subcommand("solid", "B-spline solid muscles: fit, info, export");
  solid->require_subcommand(1);

  // fit
  {
    CLI::App* cmd = solid->add_subcommand("fit", "Fit a B-spline solid to a closed muscle mesh");
    struct Args {
      std::string mesh, units = "m", origin, insertion, axis, lattice = "4x16x14", out;
      int degree = 3, slices = 48;
    };
    auto a = std::make_shared<Args>();
    cmd->add_option("--mesh", a->mesh, "Closed muscle surface (STL/OBJ/PLY/VTP)")->required();
    cmd->add_option("--units", a->units, "Length unit of the mesh and point files: m, cm, mm");
    cmd->add_option("--origin", a->origin, "Origin attachment points (CSV x,y,z)");
    cmd->add_option("--insertion", a->insertion, "Insertion attachment points (CSV x,y,z)");
    cmd->add_option("--axis", a->axis, "'auto': longest axis of the oriented bounding box");
    cmd->add_option("--lattice", a->lattice, "Control points u x v x w (radial x around x along)");
    cmd->add_option("--degree", a->degree, "Degree along v and w (u: min(degree, 2))")
        ->check(CLI::Range(1, 7));
    cmd->add_option("--slices", a->slices, "Slicing planes along the axis")->check(CLI::Range(4, 1000));
    cmd->add_option("--out", a->out, "Output solid (.json)")->required();
    cmd->callback([a, &run] {
      run.action = [a] {
        if (a->origin.empty() != a->insertion.empty()) {
          throw_usage("give both --origin and --insertion, or --axis auto");
        }
        if (a->origin.empty() && a->axis != "auto") {
          throw_usage("give --origin and --insertion, or --axis auto");
        }
        const LengthUnit unit = parse_length_unit(a->units);
        MeshFitOptions o;
        o.count = parse_triple(a->lattice, "--lattice");  // usage errors before reading files
        const TriMesh mesh = read_mesh(a->mesh, unit);
        o.degree = {std::min(a->degree, std::min(2, o.count[0] - 1)), a->degree,
                    std::min(a->degree, o.count[2] - 1)};
        o.num_slices = a->slices;
        o.name = std::filesystem::path(a->mesh).stem().string();
        if (!a->origin.empty()) {
          o.origin = read_point_centroid(a->origin, metres_per(unit));
          o.insertion = read_point_centroid(a->insertion, metres_per(unit));
        }
        MeshFitResult fit;
        try {
          fit = fit_solid_to_mesh(mesh, o);
        } catch (const Error& e) {
          throw e.with_file(a->mesh);
        }
        if (fit.correction_backed_off) {
          spdlog::info("{}: the parameter correction was backed off because it would invert the "
                       "solid (kept: {}, {} of {} closest-point rounds)", o.name,
                       fit.mesh_vertex_samples_used ? "mesh-vertex samples" : "no mesh-vertex samples",
                       fit.reparametrise_rounds, o.reparametrise_iterations);
        }
        if (!(fit.min_jacobian_det > 0.0)) {
          spdlog::warn("{}: the fitted solid is inverted at material point ({:.3f}, {:.3f}, {:.3f}) "
                       "(det J {:.3e}); solid dynamics will reject it: try another --lattice or "
                       "--origin/--insertion", o.name, fit.min_jacobian_material[0],
                       fit.min_jacobian_material[1], fit.min_jacobian_material[2], fit.min_jacobian_det);
        }
        write_solid(a->out, fit.solid);
        fmt::print("fitted {} ({} samples, lattice {}x{}x{})\n", o.name, fit.num_samples,
                   o.count[0], o.count[1], o.count[2]);
        fmt::print("boundary-to-mesh distance: mean {:.3f} mm, max {:.3f} mm\n",
                   fit.mean_distance_m * 1e3, fit.max_distance_m * 1e3);
        fmt::print("volume: mesh {:.3f} cm^3, solid {:.3f} cm^3 ({:+.3f}%)\n",
                   fit.mesh_volume_m3 * 1e6, fit.solid_volume_m3 * 1e6,
                   100 * fit.volume_difference);
        fmt::print("wrote {}\n", a->out);
      };
    });
  }

  // info
  {
    CLI::App* cmd = solid->add_subcommand("info", "Print a B-spline solid's lattice and volume");
    auto path = std::make_shared<std::string>();
    cmd->add_option("solid", *path, "Solid (.json)")->required();
    cmd->callback([path, &run] { run.action = [path] { print_solid_info(read_solid(*path)); }; });
  }

  // simulate
  {
    CLI::App* cmd = solid->add_subcommand(
        "simulate", "Simulate a solid muscle (seed 000 ch. 4): ParaView series and metrics.csv");
    auto a = std::make_shared<SimulateArgs>();
    cmd->add_option("solid", a->solid, "Solid (.json)")->required();
    cmd->add_option("--out", a->out, "Output folder")->required();
    cmd->add_option("--activation", a->activation,
                    "Excitation: a constant in [0, 1] or a .sto/.mot/.csv table (first column)");
    cmd->add_option("--duration", a->duration, "Simulated time (s)");
    cmd->add_option("--dt", a->dt, "Integration step (s)");
    cmd->add_option("--frame-dt", a->frame_dt, "Output frame interval (s)");
    cmd->add_option("--fix", a->fix, "Attached ends: origin,insertion | origin | insertion | none");
    cmd->add_option("--integrator", a->integrator,
                    "backward-euler | symplectic-euler | quasi-static");
    cmd->add_option("--volume", a->volume, "exact | penalty | none");
    cmd->add_option("--tendon", a->tendon, "Fraction of the fibre range at each end that is tendon");
    cmd->add_option("--pennation", a->pennation, "Rest fibre angle to the fibre parameter (rad)");
    cmd->add_option("--tendon-modulus", a->tendon_modulus, "Along-fibre modulus of the tendon (Pa)");
    cmd->add_option("--c1", a->c1, "Mooney-Rivlin c1 of the ground substance (Pa); c2 = c1/2");
    cmd->add_option("--damping", a->damping, "Mass-proportional Rayleigh damping (1/s)");
    cmd->add_flag("--gravity", a->gravity, "Apply gravity (-z, 9.81 m/s^2)");
    cmd->add_option("--reuse-factorisation", a->reuse,
                    "Backward Euler: keep a factorisation over up to N steps (lagged Jacobian, "
                    "refreshed when Newton slows; default: no step cap; 0: full Newton)");
    cmd->add_flag("--extrapolate-start", a->extrapolate,
                  "Backward Euler: start Newton from the last two steps' acceleration (same "
                  "equations and tolerance; fewer iterations on smooth motions; the default)");
    cmd->add_flag("--no-extrapolate-start", a->no_extrapolate,
                  "Backward Euler: start Newton from x_n + h v_n instead");
    cmd->add_option("--release", a->release, "Quick release: let the insertion go at this time (s)");
    cmd->add_option("--explicit-safety", a->explicit_safety,
                    "Symplectic Euler sub-step as a fraction of the stability limit 2/w_max");
    cmd->callback([a, &run] { run.action = [a] { run_simulate(*a); }; });
  }

  // export
  {
    CLI::App* cmd = solid->add_subcommand(
        "export", "Write boundary.vtp, fibres.vtp and volume.vtu of a solid into a folder");
    struct Args {
      std::string solid, out;
      int density = 4, fibres = 8;
    };
    auto a = std::make_shared<Args>();
    cmd->add_option("solid", a->solid, "Solid (.json)")->required();
    cmd->add_option("--out", a->out, "Output folder")->required();
    cmd->add_option("--density", a->density, "Samples per knot span")->check(CLI::Range(1, 64));
    cmd->add_option("--fibres", a->fibres, "Fibre curves per cross-section direction")
        ->check(CLI::Range(1, 100));
    cmd->callback([a, &run] {
      run.action = [a] {
        const BSplineSolid s = read_solid(a->solid);
        std::error_code ec;
        std::filesystem::create_directories(a->out, ec);
        if (ec) {
          throw_bad_input("cannot create the output folder: " + ec.message(),
                          ErrorContext{.file = a->out});
        }
        const std::filesystem::path dir(a->out);
        const BoundaryTessellation b = make_boundary_tessellation(s, a->density);
        write_mesh(dir / "boundary.vtp", b.mesh);
        write_polylines_vtp(dir / "fibres.vtp",
                            calc_fibre_curves(s, a->fibres, a->fibres, 8 * a->density + 1));
        const VolumeTessellation v = make_volume_tessellation(s, a->density);
        Points3 dirs(v.material.rows(), 3);
        for (Eigen::Index r = 0; r < dirs.rows(); ++r) {
          dirs.row(r) = calc_fibre_direction(s, v.material.row(r).transpose()).transpose();
        }
        write_hexahedra_vtu(dir / "volume.vtu", v.V, v.hexes, &dirs);
        fmt::print("wrote {} (boundary: {} triangles; volume: {} hexahedra; fibres)\n", a->out,
                   b.mesh.F.rows(), v.hexes.rows());
      };
    });
  }
}

}  // namespace fascicle::cli
