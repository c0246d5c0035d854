// The registry, the built-in joint types and the Hill actuator.
#include "fascicle/scene/registry.hpp"

#include "fascicle/musculotendon/parameters.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/names.hpp"

#include <algorithm>
#include <Eigen/Geometry>

namespace fascicle {

// "solid_dynamics" (src/scene/representation_solid_dynamics.cpp, docs/solid-dynamics.md): a group,
// so that the scene's solid muscles push each other apart.
std::unique_ptr<const MuscleGroupRepresentation> make_solid_dynamics_group(const Model& model,
                                                                           const std::vector<MuscleIndex>& muscles);

void throw_unknown_name(const std::string& kind, const std::string& name,
                        const std::vector<std::string>& valid, ErrorContext where) {
  if (where.suggestion.empty()) where.suggestion = make_name_suggestion(name, valid);
  throw_bad_input("unknown " + kind + " '" + name + "'", std::move(where));
}

namespace {

Vec3 unit_axis(const SceneJointSpec& spec) {
  const double n = spec.axis.norm();
  if (!(n > 1e-12) || !spec.axis.allFinite())
    throw_bad_input("joint axis must be a non-zero vector", {.object = spec.name});
  return spec.axis / n;
}

// The skeleton joint with the scene joint's names and frames, and its coordinates with the given
// motion types.
JointSpec make_joint(const SceneJointSpec& s, fascicle::JointType type, const std::vector<MotionType>& motions) {
  if (s.coordinates.size() != motions.size())
    throw_bad_input("joint type '" + s.type + "' has " + std::to_string(motions.size()) + " coordinates but " +
                        std::to_string(s.coordinates.size()) + " are given",
                    {.object = s.name});
  JointSpec j;
  j.name = s.name;
  j.type = type;
  j.parent = s.parent;
  j.child = s.child;
  j.X_parent_F = s.X_parent_F;
  j.X_child_M = s.X_child_M;
  for (size_t k = 0; k < motions.size(); ++k) {
    const SceneCoordinateSpec& c = s.coordinates[k];
    CoordinateSpec cs;
    cs.name = c.name;
    cs.motion_type = motions[k];
    cs.default_value = c.default_value;
    cs.range_min = c.range_min;
    cs.range_max = c.range_max;
    j.coordinates.push_back(cs);
  }
  return j;
}

// Rotates F and M by R (R·from = axis) so that the skeleton's fixed joint axis becomes `axis`.
void align_axis(JointSpec& j, const Vec3& from, const Vec3& axis) {
  const Mat3 R = Eigen::Quaterniond::FromTwoVectors(from, axis).toRotationMatrix();
  j.X_parent_F.linear() = j.X_parent_F.linear() * R;
  j.X_child_M.linear() = j.X_child_M.linear() * R;
}

class HillActuator final : public Actuator {
 public:
  explicit HillActuator(Musculotendon mtu) : mtu_(std::move(mtu)) {}
  MuscleOutputs calc_outputs(double activation, double musculotendon_length_m) const override {
    return calc_static_equilibrium(mtu_, activation, musculotendon_length_m, 0.0);
  }

 private:
  Musculotendon mtu_;
};

}  // namespace

JointSpec make_weld_joint(const SceneJointSpec& s) { return make_joint(s, fascicle::JointType::weld, {}); }

JointSpec make_pin_joint(const SceneJointSpec& s) {
  JointSpec j = make_joint(s, fascicle::JointType::pin, {MotionType::rotational});
  align_axis(j, Vec3::UnitZ(), unit_axis(s));
  return j;
}

JointSpec make_slider_joint(const SceneJointSpec& s) {
  JointSpec j = make_joint(s, fascicle::JointType::slider, {MotionType::translational});
  align_axis(j, Vec3::UnitX(), unit_axis(s));
  return j;
}

JointSpec make_free_joint(const SceneJointSpec& s) {
  using M = MotionType;
  return make_joint(s, fascicle::JointType::free,
                    {M::rotational, M::rotational, M::rotational, M::translational, M::translational, M::translational});
}

std::unique_ptr<const Actuator> make_hill_actuator(const MuscleSpec& spec) {
  const ActuatorSpec& a = spec.actuator;
  MuscleParameters p = a.parameters ? *a.parameters : default_muscle_parameters(parse_muscle_model(a.model));
  p.name = spec.name;
  p.max_isometric_force_N = a.max_isometric_force_N;
  p.optimal_fiber_length_m = a.optimal_fiber_length_m;
  p.tendon_slack_length_m = a.tendon_slack_length_m;
  p.pennation_at_optimal_rad = a.pennation_at_optimal_rad;
  p.rigid_tendon = a.rigid_tendon;
  return std::make_unique<HillActuator>(compile_musculotendon(p));
}

void register_builtins(Registry& r) {
  r.joint_types.add("weld", make_weld_joint);
  r.joint_types.add("pin", make_pin_joint);
  r.joint_types.add("hinge", make_pin_joint);
  r.joint_types.add("slider", make_slider_joint);
  r.joint_types.add("free", make_free_joint);
  r.muscle_representations.add("surface_first", make_surface_first);
  r.muscle_representations.add("surface-first", make_surface_first);
  r.muscle_groups.add("fibres_first", make_fibres_first);
  r.muscle_groups.add("fibres-first", make_fibres_first);
  r.muscle_representations.add("blended_surface", make_blended_surface);
  r.muscle_representations.add("action_line", make_action_line_only);
  r.muscle_groups.add("solid_dynamics", make_solid_dynamics_group);
  r.muscle_groups.add("solid-dynamics", make_solid_dynamics_group);
  r.actuators.add("hill", make_hill_actuator);
  r.actuators.add("none", [](const MuscleSpec&) { return std::unique_ptr<const Actuator>(); });
  r.writers.add("paraview", make_paraview_writer);
  r.writers.add("sto", make_sto_writer);
  r.writers.add("csv", make_csv_writer);
  r.writers.add("summary", make_summary_writer);
  r.writers.add("sketch", make_sketch_writer);
}

std::vector<std::string> Registry::get_representation_names() const {
  std::vector<std::string> names = muscle_representations.get_names();
  for (const auto& n : muscle_groups.get_names()) names.push_back(n);
  std::sort(names.begin(), names.end());
  return names;
}

void Registry::check_representation(const std::string& name, ErrorContext where) const {
  if (muscle_representations.find(name) || muscle_groups.find(name)) return;
  throw_unknown_name("muscle representation", name, get_representation_names(), std::move(where));
}

Registry make_default_registry() {
  Registry r;
  register_builtins(r);
  return r;
}

}  // namespace fascicle
