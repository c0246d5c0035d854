// SceneSpec: the editable description of a scene — what a scene JSON file holds (docs/
// scene-format.md) or what code builds (the demo). compile() (model.hpp) turns it into an immutable
// Model. Units are SI; angles in radians; meshes and points are in metres after loading.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/tri_mesh.hpp"
#include "fascicle/musculotendon/parameters.hpp"
#include "fascicle/path/path_spec.hpp"
#include "fascicle/skeleton/skeleton.hpp"

#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

namespace fascicle {

// Where the geometry of the file is expressed: in each object's body frame, or in ground at the
// default pose (as segmentations such as the Visible Human are).
enum class GeometryFrame { body, ground };

struct SceneBodySpec {
  std::string name;
  std::optional<TriMesh> mesh;         // closed surface (m); may be absent (massless frame)
  std::filesystem::path mesh_file;     // informational: where the mesh came from
  std::optional<double> mass_kg;       // given, or density × volume of the mesh
  std::optional<Vec3> center_of_mass;  // body frame; given, or the mesh centroid
  std::optional<Mat3> inertia;         // kg m², about the centre of mass; given or from the mesh
  double density_kg_per_m3 = 1900.0;   // whole-bone density (cortical + trabecular), see docs
  // false: the mesh is drawn but is not an obstacle and gives no mass properties (an open or
  // non-manifold display mesh, as many OpenSim bone files are).
  bool mesh_is_obstacle = true;
};

struct SceneCoordinateSpec {
  std::string name;
  double default_value = 0.0;   // rad (rotational) or m (translational)
  double range_min = -1e9;
  double range_max = 1e9;
};

// A joint connects a parent body (or "ground") to a child body. Its frame F is fixed on the parent
// (X_parent_F) and M on the child (X_child_M); the joint type gives X_F_M(q).
struct SceneJointSpec {
  std::string name;
  std::string type;              // registered joint type: "weld", "pin", "free", ...
  std::string parent;            // body name or "ground"
  std::string child;
  Transform X_parent_F = Transform::Identity();
  Transform X_child_M = Transform::Identity();
  Vec3 axis = Vec3::UnitZ();     // pin: rotation axis in F (= M)
  std::vector<SceneCoordinateSpec> coordinates;
};

// An origin or insertion: landmark points on a body (their centroid is the end of the action
// line) and the radius of the attachment area: muscle surface vertices within `radius_m` of the
// landmarks move rigidly with the body.
struct AttachmentSpec {
  std::string body;
  std::vector<Vec3> points;      // in the body frame (or ground, see GeometryFrame)
  double radius_m = 0.0;
};

struct ViaPointSpec {
  std::string body;
  Vec3 point = Vec3::Zero();
};

// Hill musculotendon parameters as a scene gives them (the musculotendon module's defaults apply
// for the rest). An actuator type of "none" skips the force computation.
struct ActuatorSpec {
  std::string type = "hill";
  std::string model = "millard";
  double max_isometric_force_N = 1000.0;
  double optimal_fiber_length_m = 0.1;
  double tendon_slack_length_m = 0.2;
  double pennation_at_optimal_rad = 0.0;
  bool rigid_tendon = false;
  // Every parameter (curves, time constants) when known, e.g. from an OpenSim model; the numbers
  // above must then equal its fields.
  std::optional<MuscleParameters> parameters;
};

struct MuscleSpec {
  std::string name;
  std::string representation = "blended_surface";  // registered muscle representation
  std::optional<TriMesh> mesh;                       // closed belly surface (m)
  std::filesystem::path mesh_file;
  AttachmentSpec origin;
  AttachmentSpec insertion;
  std::vector<ViaPointSpec> via_points;
  // Index into SceneSpec::paths: the action line is that path (via points, wrapping; OpenSim's
  // GeometryPath) instead of origin → via points → insertion. -1: none.
  int path = -1;
  ActuatorSpec actuator;
  double activation = 0.5;                           // constant activation in [0, 1]
  std::string fibre_template;                        // e.g. "parallel", "pennate", "bipennate"
  std::vector<Points3> rest_fibres;                  // optional fibre polylines (ground, default pose)
  std::map<std::string, double> options;             // representation-specific numbers
};

struct MotionSpec {
  std::filesystem::path file;        // .mot/.sto/.csv of coordinate values over time
  double frame_rate_hz = 50.0;       // resampling rate
};

struct WriterSpec {
  std::string type;                  // registered writer: "paraview", "sto", "csv", ...
};

struct SceneSpec {
  std::string name = "scene";
  std::filesystem::path source;      // the JSON file it was read from (for messages)
  GeometryFrame geometry_frame = GeometryFrame::body;
  std::vector<SceneBodySpec> bodies;
  std::vector<SceneJointSpec> joints;
  std::vector<MuscleSpec> muscles;
  std::optional<MotionSpec> motion;
  std::vector<WriterSpec> outputs;   // empty: paraview + sto + csv
  // A ready skeleton (e.g. an OpenSim model's, osim module): then `joints` must be empty, the
  // bodies and coordinates are the skeleton's, `bodies` only add meshes (by name, body frame),
  // and geometry_frame must be `body`.
  std::optional<SkeletonSpec> skeleton;
  std::optional<PathSetSpec> paths;  // muscle paths (MuscleSpec::path), with the skeleton's names
};

}  // namespace fascicle
