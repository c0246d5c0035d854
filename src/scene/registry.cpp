// The registry, the built-in joint types and the Hill actuator.
#include "fascicle/scene/registry.hpp"

#include "fascicle/musculotendon/parameters.hpp"
#include "fascicle/scene/builtins.hpp"
#include "fascicle/scene/names.hpp"

#include <Eigen/Geometry>

namespace fascicle {

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

class WeldJoint final : public JointKinematics {
 public:
  int get_num_coordinates() const override { return 0; }
  bool is_rotational(int) const override { return false; }
  Transform calc_X_F_M(const double*) const override { return Transform::Identity(); }
};

class PinJoint final : public JointKinematics {
 public:
  explicit PinJoint(const Vec3& axis) : axis_(axis) {}
  int get_num_coordinates() const override { return 1; }
  bool is_rotational(int) const override { return true; }
  Transform calc_X_F_M(const double* q) const override {
    Transform X = Transform::Identity();
    X.linear() = Eigen::AngleAxisd(q[0], axis_).toRotationMatrix();
    return X;
  }

 private:
  Vec3 axis_;
};

class SliderJoint final : public JointKinematics {
 public:
  explicit SliderJoint(const Vec3& axis) : axis_(axis) {}
  int get_num_coordinates() const override { return 1; }
  bool is_rotational(int) const override { return false; }
  Transform calc_X_F_M(const double* q) const override {
    Transform X = Transform::Identity();
    X.translation() = q[0] * axis_;
    return X;
  }

 private:
  Vec3 axis_;
};

class FreeJoint final : public JointKinematics {
 public:
  int get_num_coordinates() const override { return 6; }
  bool is_rotational(int k) const override { return k < 3; }
  Transform calc_X_F_M(const double* q) const override {
    Transform X = Transform::Identity();
    X.linear() = (Eigen::AngleAxisd(q[0], Vec3::UnitX()) * Eigen::AngleAxisd(q[1], Vec3::UnitY()) *
                  Eigen::AngleAxisd(q[2], Vec3::UnitZ()))
                     .toRotationMatrix();
    X.translation() = Vec3(q[3], q[4], q[5]);
    return X;
  }
};

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

std::unique_ptr<const JointKinematics> make_weld_joint(const SceneJointSpec&) {
  return std::make_unique<WeldJoint>();
}
std::unique_ptr<const JointKinematics> make_pin_joint(const SceneJointSpec& spec) {
  return std::make_unique<PinJoint>(unit_axis(spec));
}
std::unique_ptr<const JointKinematics> make_slider_joint(const SceneJointSpec& spec) {
  return std::make_unique<SliderJoint>(unit_axis(spec));
}
std::unique_ptr<const JointKinematics> make_free_joint(const SceneJointSpec&) {
  return std::make_unique<FreeJoint>();
}

std::unique_ptr<const Actuator> make_hill_actuator(const MuscleSpec& spec) {
  const ActuatorSpec& a = spec.actuator;
  MuscleParameters p = default_muscle_parameters(parse_muscle_model(a.model));
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
  r.muscle_representations.add("blended_surface", make_blended_surface);
  r.muscle_representations.add("action_line", make_action_line_only);
  r.actuators.add("hill", make_hill_actuator);
  r.actuators.add("none", [](const MuscleSpec&) { return std::unique_ptr<const Actuator>(); });
  r.writers.add("paraview", make_paraview_writer);
  r.writers.add("sto", make_sto_writer);
  r.writers.add("csv", make_csv_writer);
  r.writers.add("summary", make_summary_writer);
}

Registry make_default_registry() {
  Registry r;
  register_builtins(r);
  return r;
}

}  // namespace fascicle
