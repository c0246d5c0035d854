// Scene files: schema errors name the JSON path; a scene loads, compiles and runs; plug-ins.
#include "fascicle/core/error.hpp"
#include "fascicle/geometry/primitives.hpp"
#include "fascicle/io/mesh_io.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/scene_json.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <fstream>

namespace fs = std::filesystem;
using namespace fascicle;
using nlohmann::json;

namespace {

// A valid scene in millimetres: a thigh box and a shank box joined by a knee pin, one muscle.
json make_scene_json() {
  return json::parse(R"({
    "fascicle_scene": 1,
    "name": "knee",
    "units": "mm",
    "bodies": [
      {"name": "thigh", "mesh": "thigh.stl", "density": 1900},
      {"name": "shank", "mesh": "shank.stl"}
    ],
    "joints": [
      {"name": "hip_fixed", "type": "weld", "parent": "ground", "child": "thigh"},
      {"name": "knee", "type": "pin", "parent": "thigh", "child": "shank", "axis": [0, 0, -1],
       "coordinates": [{"name": "knee_flexion", "default": 0, "range": [0, 2.1]}]}
    ],
    "muscles": [
      {"name": "flexor", "representation": "blended_surface", "mesh": "belly.stl",
       "origin": {"body": "thigh", "points": [[-30, 100, 0]], "radius": 10},
       "insertion": {"body": "shank", "points": [[-30, -100, 0]]},
       "actuator": {"type": "hill", "model": "millard", "max_isometric_force": 800,
                    "optimal_fiber_length": 0.08, "tendon_slack_length": 0.10},
       "activation": 0.3, "fibre_template": "parallel"}
    ],
    "outputs": ["sto", "summary"]
  })");
}

// Writes the meshes (mm) the scene refers to and returns the folder.
fs::path write_scene_files(const std::string& name, const json& scene) {
  const fs::path dir = test::scratch_dir(name);
  TriMesh box = make_box(Vec3(20, 100, 20));
  box.V.col(1).array() += 100;
  write_mesh(dir / "thigh.stl", box);
  box.V.col(1).array() -= 200;
  write_mesh(dir / "shank.stl", box);
  TriMesh belly = make_ellipsoid(Vec3(12, 90, 12), 2);
  belly.V.col(0).array() -= 30;
  write_mesh(dir / "belly.stl", belly);
  std::ofstream(dir / "scene.json") << scene.dump(2);
  return dir;
}

// Loads the scene written in `dir` (its files already there) and returns the error it throws.
Error load_error_in(const fs::path& dir, const std::string& name) {
  try {
    load_scene(dir / "scene.json", make_default_registry());
  } catch (const Error& e) {
    return e;
  }
  ADD_FAILURE() << "no error for " << name;
  return Error(ErrorKind::internal, "none");
}

// Writes the scene's files, loads it and returns the error it throws.
Error load_error(const json& scene, const std::string& name) {
  return load_error_in(write_scene_files(name, scene), name);
}

}  // namespace

TEST(SceneJson, ValidSceneLoadsInMetresAndRuns) {
  const fs::path dir = write_scene_files("json_valid", make_scene_json());
  const Registry registry = make_default_registry();
  const SceneSpec spec = load_scene(dir / "scene.json", registry);
  ASSERT_EQ(spec.bodies.size(), 2u);
  EXPECT_NEAR(spec.bodies[0].mesh->V.col(1).maxCoeff(), 0.2, 1e-7);  // 200 mm (STL float32)
  EXPECT_NEAR(spec.muscles[0].origin.points[0].x(), -0.03, 1e-15);
  EXPECT_NEAR(spec.muscles[0].origin.radius_m, 0.01, 1e-15);
  EXPECT_EQ(spec.outputs.size(), 2u);
  const Model model = compile(spec, registry);
  EXPECT_NEAR(model.bodies[1].mass_kg, 1900 * 0.04 * 0.2 * 0.04, 1e-6);
  State state = make_state(model);
  forward(model, state);
  // Rest: lMT = 0.2 m > lTs + l0 = 0.18 m, so the unit is stretched and pulls.
  EXPECT_NEAR(state.muscles[0].musculotendon_length_m, 0.2, 1e-15);
  const double rest_force = state.muscles[0].hill.tendon_force_N;
  EXPECT_GT(rest_force, 0.0);
  state.q[0] = 1.0;  // flexion shortens this posterior muscle
  forward(model, state);
  EXPECT_LT(state.muscles[0].musculotendon_length_m, 0.2);
  EXPECT_LT(state.muscles[0].hill.tendon_force_N, rest_force);
}

TEST(SceneJson, UnknownKeyNamesPathAndSuggestsKey) {
  json s = make_scene_json();
  s["muscles"][0]["origin"]["radiuss"] = 3;
  const Error e = load_error(s, "json_unknown_key");
  EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  EXPECT_EQ(e.context().json_path, "/muscles/0/origin/radiuss");
  EXPECT_NE(e.context().suggestion.find("did you mean 'radius'"), std::string::npos);
  EXPECT_NE(std::string(e.what()).find("scene.json"), std::string::npos);
}

TEST(SceneJson, WrongTypeNamesPath) {
  json s = make_scene_json();
  s["joints"][1]["axis"] = "z";
  EXPECT_EQ(load_error(s, "json_wrong_type").context().json_path, "/joints/1/axis");
  s = make_scene_json();
  s["muscles"][0]["activation"] = 1.5;
  EXPECT_EQ(load_error(s, "json_out_of_range").context().json_path, "/muscles/0/activation");
  s = make_scene_json();
  s["bodies"][1].erase("name");
  EXPECT_EQ(load_error(s, "json_missing").context().json_path, "/bodies/1/name");
}

TEST(SceneJson, DanglingBodyReferenceSuggestsNearestBody) {
  json s = make_scene_json();
  s["muscles"][0]["insertion"]["body"] = "shnk";
  const Error e = load_error(s, "json_dangling");
  EXPECT_EQ(e.context().json_path, "/muscles/0/insertion/body");
  EXPECT_NE(e.context().suggestion.find("did you mean 'shank'"), std::string::npos);
  s = make_scene_json();
  s["joints"][1]["type"] = "hing";
  const Error t = load_error(s, "json_bad_type");
  EXPECT_EQ(t.context().json_path, "/joints/1/type");
  EXPECT_NE(t.context().suggestion.find("'hinge'"), std::string::npos);
}

TEST(SceneJson, MissingMeshFileNamesPathAndFile) {
  json s = make_scene_json();
  s["bodies"][1]["mesh"] = "shin.stl";
  const Error e = load_error(s, "json_missing_mesh");
  EXPECT_EQ(e.context().json_path, "/bodies/1/mesh");
  EXPECT_NE(std::string(e.what()).find("shin.stl"), std::string::npos);
}

// Mesh files are read ahead in parallel (prefetch); a file that cannot be read is still reported
// at the first place the scene names it, in parse order, and a file named twice is read once.
TEST(SceneJson, CorruptMeshFileIsReportedWhereTheSceneFirstNamesIt) {
  const auto error_for = [](json s, const std::string& name) {
    const fs::path dir = write_scene_files(name, s);
    std::ofstream(dir / "broken.stl", std::ios::binary) << "solid broken\n  facet normal 0 0 1\n    outer loop\n";
    return load_error_in(dir, name);
  };
  json s = make_scene_json();
  s["bodies"][1]["mesh"] = "broken.stl";
  s["muscles"][0]["mesh"] = "broken.stl";
  const Error twice = error_for(s, "json_corrupt_mesh_twice");
  EXPECT_EQ(twice.kind(), ErrorKind::bad_input);
  EXPECT_EQ(twice.context().json_path, "/bodies/1/mesh");
  EXPECT_NE(std::string(twice.what()).find("broken.stl"), std::string::npos);
  s = make_scene_json();
  s["muscles"][0]["mesh"] = "broken.stl";
  const Error muscle = error_for(s, "json_corrupt_mesh_muscle");
  EXPECT_EQ(muscle.kind(), ErrorKind::bad_input);
  EXPECT_EQ(muscle.context().json_path, "/muscles/0/mesh");
}

TEST(SceneJson, MalformedJsonIsBadInput) {
  try {
    parse_scene("{\"fascicle_scene\": 1, ", "broken.json", make_default_registry());
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_EQ(e.context().file, "broken.json");
  }
}

namespace {

// A muscle representation defined only in this test: the surface is the rest mesh translated by
// the action line's midpoint displacement, with a volume of exactly the rest volume.
class MidpointShift final : public MuscleRepresentation {
 public:
  explicit MidpointShift(Vec3 rest_mid) : rest_mid_(std::move(rest_mid)) {}
  void calc_geometry(const Model& model, MuscleIndex m, const State&, RepresentationState*,
                     MuscleFrame& out) const override {
    const Points3& line = out.action_line;
    const Vec3 mid = 0.5 * (line.row(0) + line.row(line.rows() - 1)).transpose();
    out.surface = model.get_muscle(m).rest_mesh.V.rowwise() + (mid - rest_mid_).transpose();
    out.volume_m3 = model.get_muscle(m).rest_volume_m3;
    out.relative_volume_change = 0.0;
  }

 private:
  Vec3 rest_mid_;
};

}  // namespace

TEST(SceneRegistry, NewMuscleRepresentationUsableFromSceneWithoutCoreChanges) {
  Registry registry = make_default_registry();
  EXPECT_THROW(registry.muscle_representations.add("blended_surface", make_blended_surface), Error);
  registry.muscle_representations.add("midpoint_shift", [](const Model& model, MuscleIndex m) {
    const Muscle& muscle = model.get_muscle(m);
    const auto& X = model.X_ground_body_default;
    const Vec3 mid = 0.5 * (X[muscle.origin.body.v] * muscle.origin.p_body_centroid +
                            X[muscle.insertion.body.v] * muscle.insertion.p_body_centroid);
    return std::unique_ptr<const MuscleRepresentation>(std::make_unique<MidpointShift>(mid));
  });
  json s = make_scene_json();
  s["muscles"][0]["representation"] = "midpoint_shift";
  const fs::path dir = write_scene_files("json_plugin", s);
  // Without the plug-in the name is rejected at its JSON path...
  try {
    load_scene(dir / "scene.json", make_default_registry());
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.context().json_path, "/muscles/0/representation");
  }
  // ...with it, the scene loads and the driver uses it.
  const Model model = compile(load_scene(dir / "scene.json", registry), registry);
  EXPECT_EQ(model.muscles[0].representation_name, "midpoint_shift");
  State state = make_state(model);
  state.q[0] = M_PI / 2;
  forward(model, state);
  // Insertion (−0.03, −0.1) about −z by 90°: (−0.1, 0.03); origin (−0.03, 0.1).
  const Vec3 mid_now(-0.065, 0.065, 0.0), mid_rest(-0.03, 0.0, 0.0);
  const Vec3 shift = (state.muscles[0].surface.row(0) - model.muscles[0].rest_mesh.V.row(0)).transpose();
  EXPECT_NEAR((shift - (mid_now - mid_rest)).norm(), 0.0, 1e-12);
}
