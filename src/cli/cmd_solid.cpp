// `fascicle solid fit|info|export`: B-spline solid muscles (docs/bspline-solids.md).
#include "commands.hpp"

#include "fascicle/bspline/fibres.hpp"
#include "fascicle/bspline/fitting.hpp"
#include "fascicle/bspline/solid_io.hpp"
#include "fascicle/bspline/tessellation.hpp"
#include "fascicle/bspline/volume.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/core/units.hpp"
#include "fascicle/io/mesh_io.hpp"

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
