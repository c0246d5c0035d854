// compile(SceneSpec) → Model: name resolution, joint ordering, mass properties, frames.
#include "fascicle/scene/model.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/core/parallel.hpp"
#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/scene/names.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace fascicle {
namespace {

template <class T>
int find_by_name(const std::vector<T>& items, const std::string& name) {
  for (size_t i = 0; i < items.size(); ++i)
    if (items[i].name == name) return static_cast<int>(i);
  return -1;
}

std::vector<std::string> body_names(const std::vector<Body>& bodies) {
  std::vector<std::string> names;
  for (const auto& b : bodies) names.push_back(b.name);
  return names;
}

BodyIndex resolve_body(const std::vector<Body>& bodies, const std::string& name,
                       const std::string& object, const std::string& role) {
  const int i = find_by_name(bodies, name);
  if (i < 0)
    throw_bad_input(role + " refers to unknown body '" + name + "'",
                    {.object = object, .suggestion = make_name_suggestion(name, body_names(bodies))});
  return BodyIndex{i};
}

Body compile_body(const SceneBodySpec& spec) {
  Body body;
  body.name = spec.name;
  body.mesh_is_obstacle = spec.mesh_is_obstacle;
  if (spec.mesh && !spec.mesh_is_obstacle) {
    body.mesh = *spec.mesh;  // drawn only
  } else if (spec.mesh) {
    body.mesh = *spec.mesh;
    const MassProperties mp = [&] {
      try {
        return calc_mass_properties(body.mesh, spec.density_kg_per_m3);
      } catch (const Error& e) {
        throw e.with_object(spec.name);
      }
    }();
    if (!(mp.volume_m3 > 0.0)) {
      throw_bad_input("body mesh encloses a non-positive volume (" + std::to_string(mp.volume_m3) +
                          " m³): it is open or oriented inward",
                      {.file = spec.mesh_file.string(), .object = spec.name,
                       .suggestion = "repair it with `fascicle mesh repair`"});
    }
    body.mesh_volume_m3 = mp.volume_m3;
    body.mass_kg = mp.mass_kg;
    body.center_of_mass = mp.centroid;
    body.inertia = mp.inertia;
  }
  if (spec.mass_kg) {
    if (!(*spec.mass_kg >= 0.0)) throw_bad_input("body mass must be ≥ 0", {.object = spec.name});
    // Given mass with a mesh: scale the mesh inertia to it (uniform density assumed).
    if (body.mass_kg > 0.0) body.inertia *= *spec.mass_kg / body.mass_kg;
    body.mass_kg = *spec.mass_kg;
  }
  if (spec.center_of_mass) body.center_of_mass = *spec.center_of_mass;
  if (spec.inertia) body.inertia = *spec.inertia;
  return body;
}

// Orders the joints parents-first; every body except ground is the child of exactly one joint.
std::vector<int> order_joints(const std::vector<Joint>& joints, int num_bodies) {
  std::vector<int> child_of(num_bodies, -1);
  for (size_t j = 0; j < joints.size(); ++j) {
    const int c = joints[j].child.v;
    if (c == 0) throw_bad_input("ground cannot be a joint's child", {.object = joints[j].name});
    if (child_of[c] >= 0)
      throw_bad_input("body is the child of two joints ('" + joints[child_of[c]].name + "' and '" +
                          joints[j].name + "')",
                      {.object = joints[j].name, .suggestion = "each body has one parent joint"});
    child_of[c] = static_cast<int>(j);
  }
  std::vector<int> order;
  std::vector<bool> placed(num_bodies, false);
  placed[0] = true;
  bool progress = true;
  while (order.size() < joints.size() && progress) {
    progress = false;
    for (size_t j = 0; j < joints.size(); ++j) {
      const Joint& joint = joints[j];
      if (!placed[joint.child.v] && placed[joint.parent.v]) {
        placed[joint.child.v] = true;
        order.push_back(static_cast<int>(j));
        progress = true;
      }
    }
  }
  if (order.size() < joints.size()) {
    for (const auto& joint : joints)
      if (!placed[joint.child.v])
        throw_bad_input("joint is not connected to ground (a cycle, or a chain without ground)",
                        {.object = joint.name});
  }
  return order;
}

Attachment compile_attachment(const AttachmentSpec& spec, const std::vector<Body>& bodies,
                              const std::vector<Transform>& X_ground_body, bool in_ground,
                              const std::string& muscle, const std::string& role) {
  Attachment a;
  a.body = resolve_body(bodies, spec.body, muscle, role);
  if (spec.points.empty())
    throw_bad_input(role + " has no landmark points", {.object = muscle});
  if (!(spec.radius_m >= 0.0) || !std::isfinite(spec.radius_m))
    throw_bad_input(role + " radius must be ≥ 0", {.object = muscle});
  const Transform X_body_ground = X_ground_body[a.body.v].inverse();
  a.p_body.resize(static_cast<Eigen::Index>(spec.points.size()), 3);
  for (size_t i = 0; i < spec.points.size(); ++i) {
    if (!spec.points[i].allFinite()) throw_bad_input(role + " point is not finite", {.object = muscle});
    const Vec3 p = in_ground ? Vec3(X_body_ground * spec.points[i]) : spec.points[i];
    a.p_body.row(static_cast<Eigen::Index>(i)) = p.transpose();
  }
  a.p_body_centroid = a.p_body.colwise().mean().transpose();
  a.radius_m = spec.radius_m;
  return a;
}

}  // namespace

BodyIndex Model::find_body(const std::string& n) const { return BodyIndex{find_by_name(bodies, n)}; }
CoordinateIndex Model::find_coordinate(const std::string& n) const {
  return CoordinateIndex{find_by_name(coordinates, n)};
}
MuscleIndex Model::find_muscle(const std::string& n) const { return MuscleIndex{find_by_name(muscles, n)}; }

std::vector<Transform> calc_body_transforms(const Model& model, const VecX& q) {
  if (q.size() != model.num_coordinates())
    throw_internal("calc_body_transforms: q has " + std::to_string(q.size()) + " values, expected " +
                   std::to_string(model.num_coordinates()));
  SkeletonState state(*model.skeleton);
  calc_pose(*model.skeleton, q, state);
  return state.get_body_transforms();
}

namespace {

// The skeleton of the scene: bodies with their mass properties, joints from the registry.
SkeletonSpec make_skeleton_spec(const Model& model, const std::vector<JointSpec>& joints) {
  SkeletonSpec s;
  s.name = model.name;
  for (size_t b = 1; b < model.bodies.size(); ++b) {
    const Body& body = model.bodies[b];
    BodySpec bs;
    bs.name = body.name;
    bs.mass = body.mass_kg;
    bs.com = body.center_of_mass;
    bs.inertia = body.inertia;
    s.bodies.push_back(bs);
  }
  s.joints = joints;
  return s;
}

// An attachment area (radius > 0) on a body with an obstacle mesh must lie on that bone: some
// landmark within max(radius, 1 cm) of its surface at the default pose.
void check_attachment_on_bone(const Model& model, const Attachment& a, const std::string& muscle, const char* which) {
  const Body& body = model.bodies[a.body.v];
  if (!(a.radius_m > 0.0) || !body.rest_query) return;
  const Transform& X = model.X_ground_body_default[a.body.v];
  double nearest = std::numeric_limits<double>::infinity();
  for (Eigen::Index k = 0; k < a.p_body.rows(); ++k)
    nearest = std::min(nearest, body.rest_query->calc_closest_point(X * Vec3(a.p_body.row(k).transpose())).distance);
  const double allowed = std::max(a.radius_m, 0.01);
  if (nearest > allowed)
    throw_bad_input(std::string(which) + " attachment area lies on no bone: its landmarks are " +
                        std::to_string(std::lround(nearest * 1e3)) + " mm from body '" + body.name + "'",
                    {.object = muscle, .suggestion = "put the landmarks on the bone's surface (within " +
                                                     std::to_string(std::lround(allowed * 1e3)) +
                                                     " mm), or attach the muscle to the body it touches"});
}

const char* get_joint_type_name(JointType type) {
  switch (type) {
    case JointType::weld: return "weld";
    case JointType::pin: return "pin";
    case JointType::slider: return "slider";
    case JointType::universal: return "universal";
    case JointType::ball: return "ball";
    case JointType::free: return "free";
    case JointType::custom: return "custom";
    case JointType::gimbal: return "gimbal";
    case JointType::planar: return "planar";
    case JointType::ellipsoid: return "ellipsoid";
    case JointType::scapulothoracic: return "scapulothoracic";
  }
  return "custom";
}

// The coordinates of the compiled skeleton, in its order, and the default pose.
void add_coordinates(Model& model, bool clamp_all) {
  for (int c = 0; c < model.skeleton->num_coordinates(); ++c) {
    const CoordinateInfo& info = model.skeleton->get_coordinate(c);
    Coordinate coord;
    coord.name = info.spec.name;
    coord.rotational = info.spec.motion_type != MotionType::translational;
    coord.default_value = info.spec.default_value;
    coord.range_min = info.spec.range_min;
    coord.range_max = info.spec.range_max;
    coord.clamped = clamp_all || info.spec.clamped;
    const std::string& joint_name = model.skeleton->get_joints().at(info.joint).name;
    coord.joint = JointIndex{find_by_name(model.joints, joint_name)};
    if (!(coord.range_min <= coord.range_max) || coord.default_value < coord.range_min ||
        coord.default_value > coord.range_max)
      throw_bad_input("coordinate default lies outside its range (or the range is empty)", {.object = coord.name});
    model.coordinates.push_back(coord);
  }
  model.default_q = model.skeleton->get_default_q();
}

// Bodies and joints described by the scene (joint types from the registry).
void compile_scene_skeleton(const SceneSpec& spec, const Registry& registry, Model& model) {
  const bool in_ground = spec.geometry_frame == GeometryFrame::ground;
  for (const SceneBodySpec& b : spec.bodies) {
    if (b.name.empty() || b.name == "ground")
      throw_bad_input("a body needs a unique name other than 'ground'", {.object = b.name});
    if (find_by_name(model.bodies, b.name) >= 0)
      throw_bad_input("duplicate body name", {.object = b.name});
    model.bodies.push_back(compile_body(b));
  }

  // Joints: skeleton joints from the registry's joint types, then the Model's joint list in
  // parents-first order and the coordinates in the skeleton's order.
  std::vector<Joint> joints;
  std::vector<JointSpec> skeleton_joints;
  for (const SceneJointSpec& js : spec.joints) {
    Joint j;
    j.name = js.name;
    j.type = js.type;
    j.parent = resolve_body(model.bodies, js.parent, js.name, "joint parent");
    j.child = resolve_body(model.bodies, js.child, js.name, "joint child");
    j.X_parent_F = js.X_parent_F;
    j.X_child_M = js.X_child_M;
    const JointFactory& factory = registry.joint_types.get(js.type, {.object = js.name});
    skeleton_joints.push_back(factory(js));
    j.num_coordinates = static_cast<int>(skeleton_joints.back().coordinates.size());
    joints.push_back(std::move(j));
  }
  const std::vector<int> order = order_joints(joints, model.num_bodies());
  for (int jo : order) {
    model.bodies[joints[jo].child.v].joint = JointIndex{static_cast<int32_t>(model.joints.size())};
    model.joints.push_back(std::move(joints[jo]));
  }
  for (size_t b = 1; b < model.bodies.size(); ++b)
    if (!model.bodies[b].joint.valid())
      throw_bad_input("body has no joint connecting it to the skeleton", {.object = model.bodies[b].name,
                      .suggestion = "add a joint with this body as child ('weld' to fix it)"});
  model.skeleton = std::make_unique<const Skeleton>(fascicle::compile(make_skeleton_spec(model, skeleton_joints)));
  add_coordinates(model, true);

  // Body meshes given in ground at the default pose: move them into their body frames.
  if (in_ground) {
    const std::vector<Transform> X_default = calc_body_transforms(model, model.default_q);
    for (size_t b = 1; b < model.bodies.size(); ++b) {
      Body& body = model.bodies[b];
      if (body.mesh.V.rows() == 0) continue;
      const Transform X_body_ground = X_default[b].inverse();
      body.mesh.V = ((body.mesh.V * X_body_ground.linear().transpose()).rowwise() +
                     X_body_ground.translation().transpose()).eval();
      const Mat3 R = X_body_ground.linear();
      if (!spec.bodies[b - 1].center_of_mass) body.center_of_mass = X_body_ground * body.center_of_mass;
      if (!spec.bodies[b - 1].inertia) body.inertia = R * body.inertia * R.transpose();
    }
    // The mass properties are now in body frames: rebuild the skeleton with them.
    model.skeleton = std::make_unique<const Skeleton>(fascicle::compile(make_skeleton_spec(model, skeleton_joints)));
  }
}

// A ready skeleton (an OpenSim model's): its bodies, joints and coordinates; the scene's bodies
// only add meshes, given in body frames.
void compile_given_skeleton(const SceneSpec& spec, Model& model) {
  if (!spec.joints.empty())
    throw_usage("a scene with a ready skeleton cannot also list joints");
  if (spec.geometry_frame != GeometryFrame::body)
    throw_usage("a scene with a ready skeleton gives its meshes in body frames");
  model.skeleton = std::make_unique<const Skeleton>(fascicle::compile(*spec.skeleton));
  const Skeleton& sk = *model.skeleton;
  for (int b = 1; b < sk.num_bodies(); ++b) {
    const BodySpec& bs = sk.get_body(b);
    Body body;
    body.name = bs.name;
    body.mass_kg = bs.mass;
    body.center_of_mass = bs.com;
    body.inertia = bs.inertia;
    model.bodies.push_back(std::move(body));
  }
  for (const SceneBodySpec& b : spec.bodies) {
    const int index = sk.find_body(b.name);
    if (index < 1)
      throw_bad_input("mesh for a body the skeleton does not have", {.object = b.name});
    if (!b.mesh) continue;
    Body& body = model.bodies[index];
    body.mesh = *b.mesh;
    body.mesh_is_obstacle = b.mesh_is_obstacle;
    if (b.mesh_is_obstacle) body.mesh_volume_m3 = calc_mass_properties(body.mesh).volume_m3;
  }
  for (const JointSpec& js : sk.get_joints()) {
    Joint j;
    j.name = js.name;
    j.type = get_joint_type_name(js.type);
    j.parent = BodyIndex{sk.find_body(js.parent)};
    j.child = BodyIndex{sk.find_body(js.child)};
    j.X_parent_F = js.X_parent_F;
    j.X_child_M = js.X_child_M;
    j.num_coordinates = static_cast<int>(js.coordinates.size());
    model.bodies[j.child.v].joint = JointIndex{static_cast<int32_t>(model.joints.size())};
    model.joints.push_back(std::move(j));
  }
  add_coordinates(model, false);
}

}  // namespace

Model compile(const SceneSpec& spec, const Registry& registry) {
  Model model;
  model.name = spec.name;
  const bool in_ground = spec.geometry_frame == GeometryFrame::ground;

  // Bodies (ground first), joints, the skeleton, coordinates.
  model.bodies.push_back(Body{.name = "ground"});
  if (spec.skeleton)
    compile_given_skeleton(spec, model);
  else
    compile_scene_skeleton(spec, registry, model);
  model.X_ground_body_default = calc_body_transforms(model, model.default_q);
  if (spec.paths) {
    PathNames names;
    for (const Body& b : model.bodies) names.bodies.push_back(b.name);
    for (const Coordinate& c : model.coordinates) names.coordinates.push_back(c.name);
    model.paths = compile_paths(*spec.paths, names);
  }

  // Bone queries in the default pose (ground frame), for representations that keep muscles out of
  // bones. Built in parallel: an Embree scene per body mesh.
  parallel_for(model.bodies.size(), [&](size_t b) {
    Body& body = model.bodies[b];
    if (body.mesh.V.rows() == 0 || !body.mesh_is_obstacle) return;  // drawn only: no queries
    const Transform& X = model.X_ground_body_default[b];
    TriMesh placed{((body.mesh.V * X.linear().transpose()).rowwise() + X.translation().transpose()).eval(),
                   body.mesh.F};
    for (Eigen::Index i = 0; i < placed.V.rows(); ++i) body.rest_box.extend(placed.V.row(i).transpose());
    body.rest_query = std::make_shared<const MeshQuery>(placed);
  });

  // Muscles: attachments, via points, actuator, then the representation (needs the rest of the Model).
  for (const MuscleSpec& ms : spec.muscles) {
    if (ms.name.empty() || find_by_name(model.muscles, ms.name) >= 0)
      throw_bad_input("muscle names must be unique and non-empty", {.object = ms.name});
    Muscle m;
    m.name = ms.name;
    m.representation_name = ms.representation;
    registry.check_representation(ms.representation, {.object = ms.name});
    m.origin = compile_attachment(ms.origin, model.bodies, model.X_ground_body_default, in_ground, ms.name, "origin");
    m.insertion = compile_attachment(ms.insertion, model.bodies, model.X_ground_body_default, in_ground, ms.name,
                                     "insertion");
    check_attachment_on_bone(model, m.origin, ms.name, "origin");
    check_attachment_on_bone(model, m.insertion, ms.name, "insertion");
    if (ms.path >= 0 && ms.path >= static_cast<int>(model.paths.paths.size()))
      throw_bad_input("muscle refers to a path the scene does not have", {.object = ms.name});
    m.path = ms.path;
    for (const ViaPointSpec& v : ms.via_points) {
      ViaPoint vp;
      vp.body = resolve_body(model.bodies, v.body, ms.name, "via point");
      vp.p_body = in_ground ? Vec3(model.X_ground_body_default[vp.body.v].inverse() * v.point) : v.point;
      m.via_points.push_back(vp);
    }
    if (ms.mesh) {
      m.rest_mesh = *ms.mesh;
      try {
        m.rest_volume_m3 = calc_mass_properties(m.rest_mesh).volume_m3;
      } catch (const Error& e) {
        throw e.with_object(ms.name);
      }
      if (!(m.rest_volume_m3 > 0.0))
        throw_bad_input("muscle mesh encloses a non-positive volume: it is open or oriented inward",
                        {.file = ms.mesh_file.string(), .object = ms.name});
    }
    if (!(ms.activation >= 0.0 && ms.activation <= 1.0))
      throw_bad_input("activation must lie in [0, 1]", {.object = ms.name});
    m.activation = ms.activation;
    m.actuator_type = ms.actuator.type;
    m.actuator_spec = ms.actuator;
    try {
      m.actuator = registry.actuators.get(ms.actuator.type, {.object = ms.name})(ms);
    } catch (const Error& e) {
      throw e.with_object(ms.name);
    }
    m.fibre_template = ms.fibre_template;
    m.rest_fibres = ms.rest_fibres;
    m.options = ms.options;
    model.muscles.push_back(std::move(m));
  }
  // Representations bind each muscle in the rest pose (for surface_first: a sparse factorisation
  // and bone-depth queries per muscle), independently: in parallel over muscles.
  std::vector<std::unique_ptr<const MuscleRepresentation>> reps(spec.muscles.size());
  parallel_for(spec.muscles.size(), [&](size_t i) {
    if (!registry.muscle_representations.find(spec.muscles[i].representation)) return;  // a group's
    const auto& factory = registry.muscle_representations.get(spec.muscles[i].representation);
    try {
      reps[i] = factory(model, MuscleIndex{static_cast<int32_t>(i)});
    } catch (const Error& e) {
      throw e.with_object(spec.muscles[i].name);
    }
  });
  for (size_t i = 0; i < reps.size(); ++i) model.muscles[i].representation = std::move(reps[i]);
  // Group representations: one per name, with all its muscles, in scene order. Names that differ
  // only in '-' versus '_' are spellings of one group (the registered aliases "solid_dynamics" /
  // "solid-dynamics", "fibres_first" / "fibres-first"): a scene mixing them gets one group, whose
  // muscles interact, built by the '_' spelling's factory when that one is registered.
  const auto canonical = [](std::string s) {
    std::replace(s.begin(), s.end(), '-', '_');
    return s;
  };
  std::vector<std::string> grouped;
  for (const std::string& registered : registry.muscle_groups.get_names()) {
    const std::string key = canonical(registered);
    if (std::find(grouped.begin(), grouped.end(), key) != grouped.end()) continue;
    grouped.push_back(key);
    const std::string name = registry.muscle_groups.find(key) ? key : registered;
    MuscleGroup g;
    g.representation = name;
    for (size_t i = 0; i < spec.muscles.size(); ++i)
      if (canonical(spec.muscles[i].representation) == key && registry.muscle_groups.find(spec.muscles[i].representation))
        g.muscles.push_back(MuscleIndex{static_cast<int32_t>(i)});
    if (g.muscles.empty()) continue;
    g.group = registry.muscle_groups.get(name)(model, g.muscles);
    for (size_t k = 0; k < g.muscles.size(); ++k)
      if (const TriMesh* surface = g.group->get_rest_surface(static_cast<int>(k))) {
        Muscle& m = model.muscles[g.muscles[k].v];
        m.rest_mesh = *surface;
        m.rest_volume_m3 = calc_mass_properties(m.rest_mesh).volume_m3;
      }
    model.muscle_groups.push_back(std::move(g));
  }
  return model;
}

}  // namespace fascicle
