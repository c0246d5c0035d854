// Scene JSON → SceneSpec: schema validation, name references, unit conversion, mesh loading.
#include "fascicle/scene/scene_json.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/core/units.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "fascicle/scene/osim_scene.hpp"

#include <nlohmann/json.hpp>

#include <Eigen/Geometry>
#include <exception>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>

namespace fascicle {

using nlohmann::json;

SchemaNode get_scene_schema(const Registry& registry) {
  using namespace schema;
  const SchemaNode length = number(0.0);
  const SchemaNode coordinate = object({
      required("name", string()),
      optional("default", number()),
      optional("range", array(number(), 2)),
  });
  const SchemaNode body = object({
      required("name", string()),
      optional("mesh", string()),
      optional("meshes", array(string(), 1)),
      optional("mass", number(0.0)),
      optional("center_of_mass", vec3()),
      optional("inertia", array(number(), 6)),
      optional("density", number(1.0)),
  });
  const SchemaNode joint = object({
      required("name", string()),
      required("type", one_of(registry.joint_types.get_names())),
      required("parent", reference("body")),
      required("child", reference("body")),
      optional("location_in_parent", vec3()),
      optional("orientation_in_parent", vec3()),
      optional("location_in_child", vec3()),
      optional("orientation_in_child", vec3()),
      optional("axis", vec3()),
      optional("coordinates", array(coordinate)),
  });
  const SchemaNode attachment = object({
      required("body", reference("body")),
      required("points", array(vec3(), 1)),
      optional("radius", length),
  });
  const SchemaNode actuator = object({
      optional("type", one_of(registry.actuators.get_names())),
      optional("model", one_of({"thelen", "millard", "degroote"})),
      optional("max_isometric_force", number(0.0)),
      optional("optimal_fiber_length", number(0.0)),
      optional("tendon_slack_length", number(0.0)),
      optional("pennation_angle", number(0.0, 1.57)),
      optional("rigid_tendon", boolean()),
  });
  const SchemaNode muscle = object({
      required("name", string()),
      optional("representation", one_of(registry.get_representation_names())),
      optional("mesh", string()),
      required("origin", attachment),
      required("insertion", attachment),
      optional("via_points", array(object({required("body", reference("body")), required("point", vec3())}))),
      optional("actuator", actuator),
      optional("activation", number(0.0, 1.0)),
      optional("fibre_template", one_of({"parallel", "pennate", "bipennate", "curved", "fanned"})),
      optional("options", map(number())),
  });
  return object({
      required("fascicle_scene", integer(1, 1)),
      optional("name", string()),
      optional("units", one_of({"m", "cm", "mm"})),
      optional("geometry_frame", one_of({"body", "ground"})),
      optional("bodies", array(body)),
      optional("joints", array(joint)),
      optional("opensim_model", object({
          required("file", string()),
          optional("muscles", array(string())),
          optional("geometry", array(string())),
          optional("specific_tension", number(1e-3)),
          optional("pack_bellies", boolean()),
          optional("activation", number(0.0, 1.0)),
          optional("representation", one_of(registry.get_representation_names())),
          optional("options", map(number())),
      })),
      optional("muscles", array(muscle)),
      optional("motion", object({required("file", string()), optional("frame_rate", number(1e-6))})),
      optional("outputs", array(one_of(registry.writers.get_names()))),
  });
}

namespace {

Vec3 get_vec3(const json& v) { return Vec3(v[0].get<double>(), v[1].get<double>(), v[2].get<double>()); }

// Body-fixed x-y-z rotation (OpenSim's orientation convention), radians.
Mat3 rotation_xyz(const Vec3& r) {
  return (Eigen::AngleAxisd(r.x(), Vec3::UnitX()) * Eigen::AngleAxisd(r.y(), Vec3::UnitY()) *
          Eigen::AngleAxisd(r.z(), Vec3::UnitZ()))
      .toRotationMatrix();
}

struct Reader {
  std::filesystem::path file;
  std::filesystem::path folder;
  double unit = 1.0;  // metres per file length unit
  // Meshes read ahead (prefetch_meshes), by resolved path: the mesh or the error its reading threw.
  struct Prefetched {
    std::optional<TriMesh> mesh;
    std::exception_ptr error;
    int uses = 0;  // how often the scene names the file: the last use takes the mesh (no copy)
  };
  mutable std::map<std::string, Prefetched> prefetched;

  ErrorContext at(const std::string& pointer, std::string suggestion = {}) const {
    return {.file = file.string(), .json_path = pointer, .suggestion = std::move(suggestion)};
  }

  std::filesystem::path resolve(const std::string& name) const {
    std::filesystem::path p(name);
    if (p.is_relative()) p = folder / p;
    return p;
  }

  LengthUnit get_length_unit() const {
    if (unit == 1e-3) return LengthUnit::millimetre;
    if (unit == 1e-2) return LengthUnit::centimetre;
    return LengthUnit::metre;
  }

  // Reads the mesh files a scene names (bodies' "mesh" and "meshes", muscles' "mesh") in parallel
  // before the scene is parsed in order; read_mesh_at then takes each from here. A file is read
  // once however often it is named. Failures are kept and rethrown by read_mesh_at where the
  // sequential reading would have thrown them (same message, same JSON pointer); a missing file
  // is left to read_mesh_at's own check. Reading is most of a scene's parse time (the VH shank's
  // 17 STL files) and the files are independent.
  void prefetch_meshes(const json& doc) {
    std::vector<std::string> names;
    const auto add = [&](const json& v) {
      if (v.is_string()) names.push_back(v.get<std::string>());
    };
    for (const char* list : {"bodies", "muscles"}) {
      if (!doc.contains(list) || !doc.at(list).is_array()) continue;
      for (const json& j : doc.at(list)) {
        if (!j.is_object()) continue;
        if (j.contains("mesh")) add(j.at("mesh"));
        if (j.contains("meshes") && j.at("meshes").is_array())
          for (const json& m : j.at("meshes")) add(m);
      }
    }
    std::vector<std::string> paths;
    std::map<std::string, int> uses;
    for (const std::string& n : names) {
      const std::string p = resolve(n).string();
      if (uses[p]++ == 0 && std::filesystem::exists(p)) paths.push_back(p);
    }
    std::vector<Prefetched> read(paths.size());
    const LengthUnit u = get_length_unit();
    parallel_for(paths.size(), [&](std::size_t i) {
      try {
        read[i].mesh = read_mesh(paths[i], u);
      } catch (...) {
        read[i].error = std::current_exception();
      }
    });
    for (std::size_t i = 0; i < paths.size(); ++i) {
      read[i].uses = uses[paths[i]];
      prefetched[paths[i]] = std::move(read[i]);
    }
  }

  TriMesh read_mesh_at(const std::string& name, const std::string& pointer, std::filesystem::path* resolved) const {
    const std::filesystem::path p = resolve(name);
    *resolved = p;
    if (!std::filesystem::exists(p))
      throw_bad_input("mesh file '" + p.string() + "' does not exist",
                      at(pointer, "paths are relative to the scene file's folder"));
    try {
      if (const auto it = prefetched.find(p.string()); it != prefetched.end()) {
        if (it->second.error) std::rethrow_exception(it->second.error);
        if (it->second.mesh) {
          if (--it->second.uses > 0) return *it->second.mesh;
          TriMesh mesh = std::move(*it->second.mesh);
          prefetched.erase(it);
          return mesh;
        }
      }
      return read_mesh(p, get_length_unit());
    } catch (const Error& e) {
      ErrorContext ctx = e.context();
      ctx.json_path = pointer;
      throw Error(e.kind(), e.message() + " (mesh of " + pointer + ")", ctx);
    }
  }

  Transform get_frame(const json& j, const char* location, const char* orientation) const {
    Transform X = Transform::Identity();
    if (j.contains(location)) X.translation() = unit * get_vec3(j.at(location));
    if (j.contains(orientation)) X.linear() = rotation_xyz(get_vec3(j.at(orientation)));
    return X;
  }

  AttachmentSpec get_attachment(const json& j) const {
    AttachmentSpec a;
    a.body = j.at("body").get<std::string>();
    for (const auto& p : j.at("points")) a.points.push_back(unit * get_vec3(p));
    a.radius_m = unit * j.value("radius", 0.0);
    return a;
  }
};

}  // namespace

SceneSpec parse_scene(const std::string& text, const std::filesystem::path& path, const Registry& registry) {
  json doc;
  try {
    doc = json::parse(text);
  } catch (const json::parse_error& e) {
    throw_bad_input(std::string("not valid JSON: ") + e.what(),
                    {.file = path.string(), .suggestion = "check the syntax (a JSON linter shows the spot)"});
  }
  // Names that references may use, gathered leniently before validation.
  NameTable names;
  names["body"] = {"ground"};
  if (doc.is_object() && doc.contains("bodies") && doc["bodies"].is_array())
    for (const auto& b : doc["bodies"])
      if (b.is_object() && b.contains("name") && b["name"].is_string()) names["body"].push_back(b["name"]);
  validate_json(doc, get_scene_schema(registry), names, path.string());

  Reader r{path, path.parent_path(), metres_per(parse_length_unit(doc.value("units", std::string("m")))), {}};
  if (!doc.contains("opensim_model")) r.prefetch_meshes(doc);
  SceneSpec spec;
  spec.source = path;
  spec.name = doc.value("name", path.stem().string());
  spec.geometry_frame = doc.value("geometry_frame", std::string("body")) == "ground" ? GeometryFrame::ground
                                                                                      : GeometryFrame::body;
  if (doc.contains("opensim_model")) {
    // The skeleton, paths and generated muscles of an OpenSim model (docs/opensim-volumes.md).
    if (doc.contains("bodies") || doc.contains("joints") || doc.contains("muscles"))
      throw_bad_input("a scene made from an OpenSim model lists no bodies, joints or muscles of its own",
                      r.at("/opensim_model", "remove \"bodies\", \"joints\" and \"muscles\", or \"opensim_model\""));
    const json& o = doc.at("opensim_model");
    std::filesystem::path model_file(o.at("file").get<std::string>());
    if (model_file.is_relative()) model_file = r.folder / model_file;
    if (!std::filesystem::exists(model_file))
      throw_bad_input("OpenSim model '" + model_file.string() + "' does not exist",
                      r.at("/opensim_model/file", "paths are relative to the scene file's folder"));
    OsimImportOptions import;
    for (const auto& g : o.value("geometry", json::array())) {
      std::filesystem::path dir(g.get<std::string>());
      import.geometry_dirs.push_back(dir.is_relative() ? r.folder / dir : dir);
    }
    import.geometry_dirs.push_back(model_file.parent_path() / ".." / "Geometry");
    OsimSceneOptions options;
    for (const auto& m : o.value("muscles", json::array())) options.muscles.push_back(m.get<std::string>());
    options.belly.specific_tension_Pa = 1e4 * o.value("specific_tension", 25.0);
    options.belly.packing.enabled = o.value("pack_bellies", true);
    options.activation = o.value("activation", -1.0);
    if (o.contains("representation")) options.representation = o.at("representation").get<std::string>();
    const json muscle_options = o.value("options", json::object());  // items() must not outlive it
    for (const auto& [key, value] : muscle_options.items()) options.muscle_options[key] = value.get<double>();
    try {
      spec = make_scene_from_osim(read_osim(model_file, import), options);
    } catch (const Error& e) {
      ErrorContext ctx = e.context();
      if (ctx.json_path.empty()) ctx.json_path = "/opensim_model";
      throw Error(e.kind(), e.message(), ctx);
    }
    spec.source = path;
    spec.name = doc.value("name", spec.name);
  } else {
    if (!doc.contains("bodies") || !doc.contains("joints"))
      throw_bad_input("a scene needs \"bodies\" and \"joints\", or an \"opensim_model\"", r.at(""));
    const auto& bodies = doc.at("bodies");
    for (size_t i = 0; i < bodies.size(); ++i) {
      const json& j = bodies[i];
      const std::string ptr = "/bodies/" + std::to_string(i);
      SceneBodySpec b;
      b.name = j.at("name");
      if (j.contains("mesh") && j.contains("meshes"))
        throw_bad_input("a body has either \"mesh\" or \"meshes\", not both",
                        r.at(ptr, "list every file under \"meshes\""));
      if (j.contains("mesh")) b.mesh = r.read_mesh_at(j.at("mesh"), ptr + "/mesh", &b.mesh_file);
      if (j.contains("meshes")) {
        // Several closed surfaces (e.g. tibia and fibula) as one rigid body: their union.
        TriMesh all;
        const auto& files = j.at("meshes");
        for (size_t k = 0; k < files.size(); ++k) {
          std::filesystem::path resolved;
          const TriMesh part = r.read_mesh_at(files[k], ptr + "/meshes/" + std::to_string(k), &resolved);
          const auto nv = all.V.rows(), nf = all.F.rows();
          all.V.conservativeResize(nv + part.V.rows(), 3);
          all.V.bottomRows(part.V.rows()) = part.V;
          all.F.conservativeResize(nf + part.F.rows(), 3);
          all.F.bottomRows(part.F.rows()) = part.F.array() + static_cast<int>(nv);
          b.mesh_file += (k ? ";" : "") + resolved.string();
        }
        b.mesh = std::move(all);
      }
      if (j.contains("mass")) b.mass_kg = j.at("mass").get<double>();
      if (j.contains("center_of_mass")) b.center_of_mass = r.unit * get_vec3(j.at("center_of_mass"));
      if (j.contains("inertia")) {
        const auto& I = j.at("inertia");  // Ixx, Iyy, Izz, Ixy, Ixz, Iyz (kg m²)
        Mat3 M;
        M << I[0], I[3], I[4], I[3], I[1], I[5], I[4], I[5], I[2];
        b.inertia = M;
      }
      b.density_kg_per_m3 = j.value("density", b.density_kg_per_m3);
      spec.bodies.push_back(std::move(b));
    }
    const auto& joints = doc.at("joints");
    for (size_t i = 0; i < joints.size(); ++i) {
      const json& j = joints[i];
      SceneJointSpec js;
      js.name = j.at("name");
      js.type = j.at("type");
      js.parent = j.at("parent");
      js.child = j.at("child");
      js.X_parent_F = r.get_frame(j, "location_in_parent", "orientation_in_parent");
      js.X_child_M = r.get_frame(j, "location_in_child", "orientation_in_child");
      if (j.contains("axis")) js.axis = get_vec3(j.at("axis"));
      for (const auto& c : j.value("coordinates", json::array())) {
        SceneCoordinateSpec cs;
        cs.name = c.at("name");
        cs.default_value = c.value("default", 0.0);
        if (c.contains("range")) {
          cs.range_min = c["range"][0];
          cs.range_max = c["range"][1];
        }
        js.coordinates.push_back(cs);
      }
      spec.joints.push_back(std::move(js));
    }
    const json muscles = doc.value("muscles", json::array());
    for (size_t i = 0; i < muscles.size(); ++i) {
      const json& j = muscles[i];
      const std::string ptr = "/muscles/" + std::to_string(i);
      MuscleSpec m;
      m.name = j.at("name");
      m.representation = j.value("representation", m.representation);
      if (j.contains("mesh")) m.mesh = r.read_mesh_at(j.at("mesh"), ptr + "/mesh", &m.mesh_file);
      m.origin = r.get_attachment(j.at("origin"));
      m.insertion = r.get_attachment(j.at("insertion"));
      for (const auto& v : j.value("via_points", json::array()))
        m.via_points.push_back({v.at("body"), r.unit * get_vec3(v.at("point"))});
      if (j.contains("actuator")) {
        const json& a = j.at("actuator");
        m.actuator.type = a.value("type", m.actuator.type);
        m.actuator.model = a.value("model", m.actuator.model);
        m.actuator.max_isometric_force_N = a.value("max_isometric_force", m.actuator.max_isometric_force_N);
        m.actuator.optimal_fiber_length_m = a.value("optimal_fiber_length", m.actuator.optimal_fiber_length_m);
        m.actuator.tendon_slack_length_m = a.value("tendon_slack_length", m.actuator.tendon_slack_length_m);
        m.actuator.pennation_at_optimal_rad = a.value("pennation_angle", m.actuator.pennation_at_optimal_rad);
        m.actuator.rigid_tendon = a.value("rigid_tendon", m.actuator.rigid_tendon);
      }
      m.activation = j.value("activation", m.activation);
      m.fibre_template = j.value("fibre_template", std::string());
      const json options = j.value("options", json::object());  // items() must not outlive it
      for (const auto& [key, value] : options.items()) {
        if (!value.is_number())
          throw_bad_input("muscle options must be numbers", r.at(ptr + "/options/" + escape_json_pointer(key)));
        m.options[key] = value.get<double>();
      }
      spec.muscles.push_back(std::move(m));
    }
  }
  if (doc.contains("motion")) {
    MotionSpec motion;
    std::filesystem::path p(doc["motion"].at("file").get<std::string>());
    if (p.is_relative()) p = r.folder / p;
    if (!std::filesystem::exists(p))
      throw_bad_input("motion file '" + p.string() + "' does not exist",
                      r.at("/motion/file", "paths are relative to the scene file's folder"));
    motion.file = p;
    motion.frame_rate_hz = doc["motion"].value("frame_rate", motion.frame_rate_hz);
    spec.motion = motion;
  }
  for (const auto& w : doc.value("outputs", json::array())) spec.outputs.push_back({w.get<std::string>()});
  return spec;
}

SceneSpec load_scene(const std::filesystem::path& path, const Registry& registry) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw_bad_input("cannot open the scene file", {.file = path.string(), .suggestion = "check the path"});
  std::ostringstream text;
  text << in.rdbuf();
  return parse_scene(text.str(), path, registry);
}

}  // namespace fascicle
