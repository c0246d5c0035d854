// The compiled scene: an immutable Model (bodies, joints, coordinates, muscles; names resolved to
// strong indices) built once by compile() and shared const across threads. Everything that changes
// per frame lives in State (state.hpp). Frames: X_A_B maps points given in B to A; body 0 is ground.
#pragma once

#include "fascicle/core/types.hpp"
#include "fascicle/geometry/mesh_query.hpp"
#include "fascicle/geometry/tri_mesh.hpp"
#include "fascicle/path/path_model.hpp"
#include "fascicle/scene/ids.hpp"
#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/scene_spec.hpp"

#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

namespace fascicle {

struct Body {
  std::string name;
  TriMesh mesh;                    // body frame, m (empty for ground and massless frames)
  double mass_kg = 0.0;
  Vec3 center_of_mass = Vec3::Zero();  // body frame
  Mat3 inertia = Mat3::Zero();     // kg m², about the centre of mass, body axes
  double mesh_volume_m3 = 0.0;     // enclosed volume of the mesh (0 without a mesh or obstacle)
  bool mesh_is_obstacle = true;    // false: display only (no rest_query, no mass properties)
  JointIndex joint;                // the joint whose child this body is (invalid for ground)
  // Closest-point / inside queries on the mesh placed in ground at the default pose (null without
  // a mesh): what muscles bound in the rest pose test against, moved by the body's motion.
  std::shared_ptr<const MeshQuery> rest_query;
  Eigen::AlignedBox3d rest_box;    // bounding box of that placed mesh (empty without a mesh)
};

struct Joint {
  std::string name;
  std::string type;
  BodyIndex parent;
  BodyIndex child;
  Transform X_parent_F = Transform::Identity();
  Transform X_child_M = Transform::Identity();
  int num_coordinates = 0;
};

struct Coordinate {
  std::string name;
  JointIndex joint;
  bool rotational = true;
  double default_value = 0.0;
  double range_min = -1e9;
  double range_max = 1e9;
  // Motion values outside the range are clamped (with a warning); false: kept, with a warning
  // (an OpenSim coordinate whose `clamped` is false). Scene coordinates are always clamped.
  bool clamped = true;
};

struct Attachment {
  BodyIndex body;
  Points3 p_body;              // landmark points, body frame
  Vec3 p_body_centroid = Vec3::Zero();
  double radius_m = 0.0;
};

struct ViaPoint {
  BodyIndex body;
  Vec3 p_body = Vec3::Zero();
};

struct Muscle {
  std::string name;
  std::string representation_name;
  TriMesh rest_mesh;           // ground frame at the default pose (may be empty)
  double rest_volume_m3 = 0.0;
  Attachment origin;
  Attachment insertion;
  std::vector<ViaPoint> via_points;
  int path = -1;               // index into Model::paths (wrapping path), -1: via points
  std::string actuator_type;
  ActuatorSpec actuator_spec;
  double activation = 0.5;
  std::string fibre_template;
  std::vector<Points3> rest_fibres;  // ground frame at the default pose (may be empty)
  std::map<std::string, double> options;
  std::unique_ptr<const Actuator> actuator;                 // null for "none"
  std::unique_ptr<const MuscleRepresentation> representation;
};

// Muscles solved together by one group representation (registry.muscle_groups).
struct MuscleGroup {
  std::string representation;
  std::vector<MuscleIndex> muscles;
  std::unique_ptr<const MuscleGroupRepresentation> group;
};

struct Model {
  std::string name;
  std::unique_ptr<const Skeleton> skeleton;  // poses the bodies (skeleton module, Simbody)
  std::vector<Body> bodies;              // [0] = ground
  std::vector<Joint> joints;             // parents before children
  std::vector<Coordinate> coordinates;   // in the skeleton's coordinate order
  std::vector<Muscle> muscles;           // representation null for members of a group
  std::vector<MuscleGroup> muscle_groups;
  PathSetModel paths;                    // compiled SceneSpec::paths (empty without)                    // compiled SceneSpec::paths (empty without)
  VecX default_q;                        // #coordinates
  std::vector<Transform> X_ground_body_default;  // at default_q

  // Cheap lookups (linear in the count; use at set-up, not per frame). Invalid index when absent.
  BodyIndex find_body(const std::string& name) const;
  CoordinateIndex find_coordinate(const std::string& name) const;
  MuscleIndex find_muscle(const std::string& name) const;

  const Body& get_body(BodyIndex b) const { return bodies.at(b.v); }
  const Muscle& get_muscle(MuscleIndex m) const { return muscles.at(m.v); }
  int num_bodies() const { return static_cast<int>(bodies.size()); }
  int num_muscles() const { return static_cast<int>(muscles.size()); }
  int num_coordinates() const { return static_cast<int>(coordinates.size()); }
};

// Builds the Model: resolves every name to an index (bad input naming the object and suggesting
// the nearest valid name), orders joints from ground outwards (each body must be the child of
// exactly one joint; cycles are an error), compiles the skeleton (joints through the registry's
// joint types), computes mass properties of closed body meshes
// (density × volume, centroid, inertia, seed 000 §5.1) where not given, expresses ground-frame
// geometry in body frames, and constructs the actuators and muscle representations through the
// registry. Returns a complete Model or throws fascicle::Error.
Model compile(const SceneSpec& spec, const Registry& registry);

// The pose of every body for coordinates q (#coordinates): X_ground_body (#bodies, [0] identity).
// One-off convenience; per-frame code uses calc_pose(model, state).
std::vector<Transform> calc_body_transforms(const Model& model, const VecX& q);

}  // namespace fascicle
