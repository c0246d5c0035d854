// Skeleton compilation onto Simbody and per-frame kinematics (see skeleton.hpp).
// Simbody is included only here; this file compiles as C++17 with NDEBUG undefined.
#include "fascicle/skeleton/skeleton.hpp"

#include <Simbody.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "fascicle/core/error.hpp"
#include "joint_mobilizers.hpp"

namespace fascicle {
namespace {

// A fascicle::Function of zero or one argument seen as a SimTK::Function.
class AxisFunction : public SimTK::Function {
 public:
  AxisFunction(fascicle::Function f, int nargs) : f_(std::move(f)), nargs_(nargs) {}
  SimTK::Real calcValue(const SimTK::Vector& x) const override {
    return calc_value(f_, nargs_ ? x[0] : 0.0);
  }
  SimTK::Real calcDerivative(const SimTK::Array_<int>& components,
                             const SimTK::Vector& x) const override {
    if (nargs_ == 0) return 0.0;
    const FunctionValue v = calc_function(f_, x[0]);
    if (components.size() == 1) return v.slope;
    if (components.size() == 2) return v.curvature;
    return 0.0;
  }
  int getArgumentSize() const override { return nargs_; }
  int getMaxDerivativeOrder() const override { return 2; }
  SimTK::Function* clone() const override { return new AxisFunction(f_, nargs_); }

 private:
  fascicle::Function f_;
  int nargs_;
};

// Coupler residual r(q_independent, q_dependent) = f(q_independent) − q_dependent.
class CouplerResidual : public SimTK::Function {
 public:
  explicit CouplerResidual(fascicle::Function f) : f_(std::move(f)) {}
  SimTK::Real calcValue(const SimTK::Vector& x) const override {
    return calc_value(f_, x[0]) - x[1];
  }
  SimTK::Real calcDerivative(const SimTK::Array_<int>& c, const SimTK::Vector& x) const override {
    if (c.size() == 1) return c[0] == 0 ? calc_slope(f_, x[0]) : -1.0;
    if (c.size() == 2 && c[0] == 0 && c[1] == 0) return calc_function(f_, x[0]).curvature;
    return 0.0;
  }
  int getArgumentSize() const override { return 2; }
  int getMaxDerivativeOrder() const override { return 2; }
  SimTK::Function* clone() const override { return new CouplerResidual(f_); }

 private:
  fascicle::Function f_;
};

SimTK::Vec3 to_simtk(const Vec3& v) { return SimTK::Vec3(v.x(), v.y(), v.z()); }
Vec3 to_eigen(const SimTK::Vec3& v) { return Vec3(v[0], v[1], v[2]); }

SimTK::Transform to_simtk(const Transform& X) {
  const Mat3 R = X.linear();
  SimTK::Mat33 m;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) m(i, j) = R(i, j);
  return SimTK::Transform(SimTK::Rotation(m, true), to_simtk(Vec3(X.translation())));
}

Transform to_eigen(const SimTK::Transform& X) {
  Transform out = Transform::Identity();
  Mat3 R;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) R(i, j) = X.R()[i][j];
  out.linear() = R;
  out.translation() = to_eigen(X.p());
  return out;
}

bool finite(const Transform& X) { return X.matrix().allFinite(); }

ErrorContext object_context(const std::string& object, const std::string& suggestion = {}) {
  ErrorContext c;
  c.object = object;
  c.suggestion = suggestion;
  return c;
}

// The six axes of a joint as a SpatialTransformSpec over its coordinate names.
SpatialTransformSpec standard_transform(const JointSpec& j) {
  SpatialTransformSpec st;
  const Vec3 ex = Vec3::UnitX(), ey = Vec3::UnitY(), ez = Vec3::UnitZ();
  st.axes[0].axis = ex;
  st.axes[1].axis = ey;
  st.axes[2].axis = ez;
  st.axes[3].axis = ex;
  st.axes[4].axis = ey;
  st.axes[5].axis = ez;
  const auto drive = [&](int axis, int coordinate) {
    st.axes[axis].coordinate = j.coordinates[coordinate].name;
    st.axes[axis].function = make_linear(1.0, 0.0);
  };
  switch (j.type) {
    case JointType::pin:  // rotation about z of F: put z first so the sequence is trivial
      st.axes[0].axis = ez;
      st.axes[1].axis = ex;
      st.axes[2].axis = ey;
      drive(0, 0);
      break;
    case JointType::slider: drive(3, 0); break;
    case JointType::universal: drive(0, 0); drive(1, 1); break;
    case JointType::ball:
    case JointType::gimbal: drive(0, 0); drive(1, 1); drive(2, 2); break;
    case JointType::planar:  // rotation about z of F, translations along x and y of F
      st.axes[0].axis = ez;
      st.axes[1].axis = ex;
      st.axes[2].axis = ey;
      drive(0, 0);
      drive(3, 1);
      drive(4, 2);
      break;
    case JointType::free:
      for (int i = 0; i < 6; ++i) drive(i, i);
      break;
    case JointType::weld:
    case JointType::custom:
    case JointType::ellipsoid:
    case JointType::scapulothoracic: break;
  }
  return st;
}

int expected_coordinates(JointType type) {
  switch (type) {
    case JointType::weld: return 0;
    case JointType::pin:
    case JointType::slider: return 1;
    case JointType::universal: return 2;
    case JointType::ball:
    case JointType::gimbal:
    case JointType::planar:
    case JointType::ellipsoid: return 3;
    case JointType::scapulothoracic: return 4;
    case JointType::free: return 6;
    case JointType::custom: return -1;
  }
  return -1;
}

// Replaces axes of a triple (rotations 0–2 or translations 3–5) that are zero or parallel to an
// earlier one of the triple, when their function is constant, by unit vectors completing an
// independent set (as OpenSim does for its CustomJoint); Simbody needs independent axes.
void make_axes_independent(SpatialTransformSpec& st, int first) {
  for (int i = first; i < first + 3; ++i) {
    Vec3& a = st.axes[i].axis;
    bool degenerate = !a.allFinite() || a.norm() < 1e-12;
    for (int k = first; k < i && !degenerate; ++k)
      degenerate = a.normalized().cross(st.axes[k].axis.normalized()).norm() < 1e-9;
    if (!degenerate) {
      a.normalize();
      continue;
    }
    if (!st.axes[i].coordinate.empty() || !is_constant(st.axes[i].function)) continue;  // rejected later
    for (const Vec3& candidate : {Vec3(Vec3::UnitX()), Vec3(Vec3::UnitY()), Vec3(Vec3::UnitZ())}) {
      bool ok = true;
      for (int k = first; k < i; ++k) ok = ok && candidate.cross(st.axes[k].axis).norm() > 1e-3;
      if (i == first + 2)  // the third must leave the first two: use their cross product
        ok = ok && std::abs(candidate.dot(st.axes[first].axis.cross(st.axes[first + 1].axis))) > 1e-3;
      if (ok) {
        a = candidate;
        break;
      }
    }
  }
}

}  // namespace

// ----------------------------------------------------------------------------------------------

struct Skeleton::Impl {
  SkeletonSpec spec;
  std::vector<BodySpec> bodies;  // 0 = ground
  std::vector<int> parent_body;
  std::unordered_map<std::string, int> body_index;
  std::vector<CoordinateInfo> coordinates;
  std::unordered_map<std::string, int> coordinate_index;
  std::vector<int> coupler_order;        // couplers in dependency order
  std::vector<int> coupler_dependent;    // coordinate index per coupler
  std::vector<int> coupler_independent;  // coordinate index per coupler
  // Simbody
  std::unique_ptr<SimTK::MultibodySystem> system;
  SimTK::SimbodyMatterSubsystem* matter = nullptr;
  std::vector<SimTK::MobilizedBodyIndex> mobod;    // per body
  std::vector<SimTK::MobilizedBodyIndex> coord_mobod;
  std::vector<int> coord_local_q;                  // index within its mobilizer
  std::vector<int> coord_q;                        // global QIndex (= UIndex for FunctionBased)
  SimTK::State default_state;
  VecX default_q;
};

struct SkeletonState::Impl {
  SimTK::State state;
  SimTK::Vector_<SimTK::SpatialVec> body_forces;
  SimTK::Vector mobility_forces;
};

namespace {

void check_transform(const Transform& X, const std::string& what, const std::string& object) {
  if (!finite(X)) throw_bad_input(what + " is not finite", object_context(object));
  const Mat3 R = X.linear();
  if ((R.transpose() * R - Mat3::Identity()).norm() > 1e-6)
    throw_bad_input(what + " is not a rotation", object_context(object));
}

void add_coordinates(Skeleton::Impl& m, const JointSpec& j, int joint_index) {
  const int expected = expected_coordinates(j.type);
  if (expected >= 0 && static_cast<int>(j.coordinates.size()) != expected)
    throw_bad_input("a joint of this type needs " +
                        std::to_string(expected) + " coordinates, got " +
                        std::to_string(j.coordinates.size()),
                    object_context(j.name));
  for (const CoordinateSpec& c : j.coordinates) {
    if (c.name.empty()) throw_bad_input("a coordinate has no name", object_context(j.name));
    if (m.coordinate_index.count(c.name))
      throw_bad_input("coordinate name used twice", object_context(c.name, "rename one of them"));
    if (!std::isfinite(c.default_value) || std::isnan(c.range_min) || std::isnan(c.range_max) ||
        c.range_min > c.range_max)
      throw_bad_input("coordinate default or range is not valid", object_context(c.name));
    m.coordinate_index[c.name] = static_cast<int>(m.coordinates.size());
    CoordinateInfo info;
    info.spec = c;
    info.joint = joint_index;
    m.coordinates.push_back(info);
  }
}

// Builds one Simbody mobilizer; returns its index.
SimTK::MobilizedBodyIndex add_mobilizer(Skeleton::Impl& m, const JointSpec& j, int parent,
                                        const SimTK::Body::Rigid& body) {
  SimTK::MobilizedBody& parent_mobod = m.matter->updMobilizedBody(m.mobod[parent]);
  const SimTK::Transform X_PF = to_simtk(j.X_parent_F);
  const SimTK::Transform X_BM = to_simtk(j.X_child_M);
  if (j.type == JointType::weld) {
    SimTK::MobilizedBody::Weld weld(parent_mobod, X_PF, body, X_BM);
    return weld.getMobilizedBodyIndex();
  }
  if (j.type == JointType::ellipsoid || j.type == JointType::scapulothoracic) {
    const Vec3& r = j.ellipsoid_radii;
    if (!r.allFinite() || !(r.minCoeff() > 0.0))
      throw_bad_input("the ellipsoid radii must be positive and finite",
                      object_context(j.name, "give three positive radii (m)"));
    if (!j.winging_origin.allFinite() || !std::isfinite(j.winging_direction))
      throw_bad_input("the winging axis is not finite", object_context(j.name));
    return detail::add_ellipsoid_mobilizer(*m.matter, parent_mobod, X_PF, body, X_BM, j);
  }
  SpatialTransformSpec st = j.type == JointType::custom ? j.spatial_transform : standard_transform(j);
  make_axes_independent(st, 0);
  make_axes_independent(st, 3);
  for (int first : {0, 3}) {
    const Vec3 a = st.axes[first].axis, b = st.axes[first + 1].axis, c = st.axes[first + 2].axis;
    if (!(std::abs(a.normalized().dot(b.normalized().cross(c.normalized()))) > 1e-6))
      throw_bad_input(std::string("the ") + (first == 0 ? "rotation" : "translation") +
                          " axes of the spatial transform are not independent",
                      object_context(j.name, "give three non-coplanar axes"));
  }
  // Local q index of each of the joint's coordinates.
  std::unordered_map<std::string, int> local;
  for (std::size_t k = 0; k < j.coordinates.size(); ++k)
    local[j.coordinates[k].name] = static_cast<int>(k);
  std::vector<bool> used(j.coordinates.size(), false);
  std::vector<const SimTK::Function*> functions;
  std::vector<std::vector<int>> args;
  std::vector<SimTK::Vec3> axes;
  for (int i = 0; i < 6; ++i) {
    const TransformAxisSpec& a = st.axes[i];
    if (!a.axis.allFinite() || a.axis.norm() < 1e-12)
      throw_bad_input("transform axis " + std::to_string(i + 1) + " is zero or not finite",
                      object_context(j.name));
    std::vector<int> arg;
    if (!a.coordinate.empty()) {
      const auto it = local.find(a.coordinate);
      if (it == local.end())
        throw_bad_input("transform axis " + std::to_string(i + 1) + " uses coordinate '" +
                            a.coordinate + "' which is not a coordinate of this joint",
                        object_context(j.name));
      arg.push_back(it->second);
      used[it->second] = true;
    }
    functions.push_back(new AxisFunction(a.function, static_cast<int>(arg.size())));
    args.push_back(arg);
    axes.push_back(to_simtk(Vec3(a.axis.normalized())));
  }
  for (std::size_t k = 0; k < used.size(); ++k)
    if (!used[k])
      throw_bad_input("coordinate '" + j.coordinates[k].name + "' drives no transform axis",
                      object_context(j.name, "remove it or add it to the spatial transform"));
  if (j.coordinates.empty()) {
    // A custom joint with only constant axes: a weld at the constant transform.
    SimTK::Vector none(0);
    SimTK::Rotation R;
    SimTK::Vec3 p(0);
    for (int i = 0; i < 3; ++i)
      R = R * SimTK::Rotation(functions[i]->calcValue(none), SimTK::UnitVec3(axes[i]));
    for (int i = 3; i < 6; ++i) p += functions[i]->calcValue(none) * axes[i];
    for (const SimTK::Function* f : functions) delete f;
    SimTK::MobilizedBody::Weld weld(parent_mobod, X_PF * SimTK::Transform(R, p), body, X_BM);
    return weld.getMobilizedBodyIndex();
  }
  SimTK::MobilizedBody::FunctionBased fb(parent_mobod, X_PF, body, X_BM,
                                         static_cast<int>(j.coordinates.size()), functions, args,
                                         axes);
  return fb.getMobilizedBodyIndex();
}

void order_couplers(Skeleton::Impl& m) {
  const SkeletonSpec& spec = m.spec;
  const int n = static_cast<int>(spec.couplers.size());
  m.coupler_dependent.assign(n, -1);
  m.coupler_independent.assign(n, -1);
  for (int i = 0; i < n; ++i) {
    const CouplerSpec& c = spec.couplers[i];
    const auto dep = m.coordinate_index.find(c.dependent);
    const auto ind = m.coordinate_index.find(c.independent);
    if (dep == m.coordinate_index.end())
      throw_bad_input("unknown dependent coordinate '" + c.dependent + "'", object_context(c.name));
    if (ind == m.coordinate_index.end())
      throw_bad_input("unknown independent coordinate '" + c.independent + "'",
                      object_context(c.name));
    if (dep->second == ind->second)
      throw_bad_input("a coordinate cannot be coupled to itself", object_context(c.name));
    CoordinateInfo& info = m.coordinates[dep->second];
    if (info.dependent_on >= 0)
      throw_bad_input("coordinate '" + c.dependent + "' is the dependent of two couplers",
                      object_context(c.name));
    info.dependent_on = i;
    m.coupler_dependent[i] = dep->second;
    m.coupler_independent[i] = ind->second;
  }
  // Dependency order: a coupler runs after the coupler that sets its independent coordinate.
  std::vector<int> state(n, 0);  // 0 new, 1 visiting, 2 done
  std::function<void(int)> visit = [&](int i) {
    if (state[i] == 2) return;
    if (state[i] == 1)
      throw_bad_input("coordinate couplers form a cycle", object_context(spec.couplers[i].name));
    state[i] = 1;
    const int before = m.coordinates[m.coupler_independent[i]].dependent_on;
    if (before >= 0) visit(before);
    state[i] = 2;
    m.coupler_order.push_back(i);
  };
  for (int i = 0; i < n; ++i) visit(i);
}

}  // namespace

Skeleton compile(const SkeletonSpec& spec) {
  auto m = std::make_unique<Skeleton::Impl>();
  m->spec = spec;
  // Bodies: ground first.
  BodySpec ground;
  ground.name = "ground";
  ground.meshes = spec.ground_meshes;
  m->bodies.push_back(ground);
  for (const BodySpec& b : spec.bodies) {
    if (b.name == "ground") {
      m->bodies[0].meshes.insert(m->bodies[0].meshes.end(), b.meshes.begin(), b.meshes.end());
      continue;
    }
    if (b.name.empty()) throw_bad_input("a body has no name");
    if (!(b.mass >= 0.0) || !std::isfinite(b.mass) || !b.com.allFinite() || !b.inertia.allFinite())
      throw_bad_input("mass, centre of mass or inertia is negative or not finite",
                      object_context(b.name));
    m->bodies.push_back(b);
  }
  for (std::size_t i = 0; i < m->bodies.size(); ++i) {
    if (m->body_index.count(m->bodies[i].name))
      throw_bad_input("body name used twice", object_context(m->bodies[i].name));
    m->body_index[m->bodies[i].name] = static_cast<int>(i);
  }
  const int nb = static_cast<int>(m->bodies.size());
  // Joints: each body is the child of one joint; build in tree order from the ground.
  std::vector<int> joint_of_child(nb, -1);
  for (std::size_t k = 0; k < spec.joints.size(); ++k) {
    const JointSpec& j = spec.joints[k];
    const auto p = m->body_index.find(j.parent);
    const auto c = m->body_index.find(j.child);
    if (p == m->body_index.end())
      throw_bad_input("unknown parent body '" + j.parent + "'", object_context(j.name));
    if (c == m->body_index.end())
      throw_bad_input("unknown child body '" + j.child + "'", object_context(j.name));
    if (c->second == 0) throw_bad_input("the ground cannot be a joint's child", object_context(j.name));
    if (joint_of_child[c->second] >= 0)
      throw_bad_input("body '" + j.child + "' is the child of two joints (closed loops are not "
                      "supported)", object_context(j.name));
    check_transform(j.X_parent_F, "the joint frame in the parent", j.name);
    check_transform(j.X_child_M, "the joint frame in the child", j.name);
    joint_of_child[c->second] = static_cast<int>(k);
  }
  for (int b = 1; b < nb; ++b)
    if (joint_of_child[b] < 0)
      throw_bad_input("body has no joint connecting it to the skeleton",
                      object_context(m->bodies[b].name, "add a joint (a weld if it is fixed)"));
  // Coordinates in joint order as given in the spec.
  for (std::size_t k = 0; k < spec.joints.size(); ++k) add_coordinates(*m, spec.joints[k], static_cast<int>(k));

  m->system = std::make_unique<SimTK::MultibodySystem>();
  m->matter = new SimTK::SimbodyMatterSubsystem(*m->system);  // owned by the system
  SimTK::GeneralForceSubsystem forces(*m->system);
  SimTK::Force::Gravity gravity(forces, *m->matter, to_simtk(spec.gravity));
  m->mobod.assign(nb, SimTK::MobilizedBodyIndex());
  m->parent_body.assign(nb, -1);
  m->mobod[0] = SimTK::GroundIndex;
  // Breadth-first from the ground so parents exist before children.
  std::vector<int> queue{0};
  std::vector<bool> placed(nb, false);
  placed[0] = true;
  for (std::size_t head = 0; head < queue.size(); ++head) {
    const int parent = queue[head];
    for (int child = 1; child < nb; ++child) {
      if (placed[child]) continue;
      const JointSpec& j = spec.joints[joint_of_child[child]];
      if (m->body_index[j.parent] != parent) continue;
      const BodySpec& b = m->bodies[child];
      SimTK::Inertia I_com(SimTK::Mat33(b.inertia(0, 0), b.inertia(0, 1), b.inertia(0, 2),
                                        b.inertia(1, 0), b.inertia(1, 1), b.inertia(1, 2),
                                        b.inertia(2, 0), b.inertia(2, 1), b.inertia(2, 2)));
      const SimTK::Inertia I_origin = I_com.shiftFromMassCenter(to_simtk(b.com), b.mass);
      const SimTK::Body::Rigid body(SimTK::MassProperties(b.mass, to_simtk(b.com), I_origin));
      try {
        m->mobod[child] = add_mobilizer(*m, j, parent, body);
      } catch (const SimTK::Exception::Base& e) {
        throw_bad_input(std::string("Simbody rejected the joint: ") + e.getMessageText(),
                        object_context(j.name));
      }
      m->parent_body[child] = parent;
      placed[child] = true;
      queue.push_back(child);
    }
  }
  for (int b = 1; b < nb; ++b)
    if (!placed[b])
      throw_bad_input("body is not connected to the ground (its joints form a loop)",
                      object_context(m->bodies[b].name));
  // Coordinate → mobilizer q.
  const int nc = static_cast<int>(m->coordinates.size());
  m->coord_mobod.resize(nc);
  m->coord_local_q.resize(nc);
  for (int i = 0; i < nc; ++i) {
    const JointSpec& j = spec.joints[m->coordinates[i].joint];
    m->coord_mobod[i] = m->mobod[m->body_index[j.child]];
    int k = 0;
    while (j.coordinates[k].name != m->coordinates[i].spec.name) ++k;
    m->coord_local_q[i] = k;
  }
  order_couplers(*m);
  for (std::size_t c = 0; c < spec.couplers.size(); ++c) {
    std::vector<SimTK::MobilizedBodyIndex> bodies{m->coord_mobod[m->coupler_independent[c]],
                                                  m->coord_mobod[m->coupler_dependent[c]]};
    std::vector<SimTK::MobilizerQIndex> qs{
        SimTK::MobilizerQIndex(m->coord_local_q[m->coupler_independent[c]]),
        SimTK::MobilizerQIndex(m->coord_local_q[m->coupler_dependent[c]])};
    SimTK::Constraint::CoordinateCoupler(*m->matter, new CouplerResidual(spec.couplers[c].function),
                                         bodies, qs);
  }
  try {
    m->default_state = m->system->realizeTopology();
    m->system->realizeModel(m->default_state);
  } catch (const SimTK::Exception::Base& e) {
    throw_bad_input(std::string("Simbody could not build the skeleton: ") + e.getMessageText(),
                    object_context(spec.name));
  }
  m->coord_q.resize(nc);
  for (int i = 0; i < nc; ++i) {
    const SimTK::MobilizedBody& mb = m->matter->getMobilizedBody(m->coord_mobod[i]);
    m->coord_q[i] = static_cast<int>(mb.getFirstQIndex(m->default_state)) + m->coord_local_q[i];
    if (static_cast<int>(mb.getFirstUIndex(m->default_state)) + m->coord_local_q[i] != m->coord_q[i])
      throw_internal("q and u indices differ for a function-based mobilizer");
  }
  m->default_q.resize(nc);
  for (int i = 0; i < nc; ++i) m->default_q[i] = m->coordinates[i].spec.default_value;
  for (const int c : m->coupler_order)
    m->default_q[m->coupler_dependent[c]] =
        calc_value(spec.couplers[c].function, m->default_q[m->coupler_independent[c]]);
  return Skeleton(std::move(m));
}

// ----------------------------------------------------------------------------------------------

Skeleton::Skeleton(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Skeleton::~Skeleton() = default;
Skeleton::Skeleton(Skeleton&&) noexcept = default;
Skeleton& Skeleton::operator=(Skeleton&&) noexcept = default;

const SkeletonSpec& Skeleton::get_spec() const { return impl_->spec; }
int Skeleton::num_bodies() const { return static_cast<int>(impl_->bodies.size()); }
const std::string& Skeleton::get_body_name(int b) const { return impl_->bodies.at(b).name; }
const BodySpec& Skeleton::get_body(int b) const { return impl_->bodies.at(b); }
int Skeleton::find_body(const std::string& name) const {
  const auto it = impl_->body_index.find(name);
  return it == impl_->body_index.end() ? -1 : it->second;
}
int Skeleton::num_coordinates() const { return static_cast<int>(impl_->coordinates.size()); }
const CoordinateInfo& Skeleton::get_coordinate(int c) const { return impl_->coordinates.at(c); }
int Skeleton::find_coordinate(const std::string& name) const {
  const auto it = impl_->coordinate_index.find(name);
  return it == impl_->coordinate_index.end() ? -1 : it->second;
}
const std::vector<JointSpec>& Skeleton::get_joints() const { return impl_->spec.joints; }
int Skeleton::get_parent_body(int body) const { return impl_->parent_body.at(body); }
VecX Skeleton::get_default_q() const { return impl_->default_q; }

SkeletonState::SkeletonState(const Skeleton& skeleton) : impl_(std::make_unique<Impl>()) {
  const Skeleton::Impl& m = skeleton.impl();
  impl_->state = m.default_state;
  m.system->realize(impl_->state, SimTK::Stage::Instance);
  impl_->body_forces.resize(static_cast<int>(m.matter->getNumBodies()));
  q_ = m.default_q;
  qdot_ = VecX::Zero(q_.size());
  X_ground_body_.assign(m.bodies.size(), Transform::Identity());
  coupling_ = MatX::Identity(q_.size(), q_.size());
}
SkeletonState::~SkeletonState() = default;
SkeletonState::SkeletonState(SkeletonState&&) noexcept = default;
SkeletonState& SkeletonState::operator=(SkeletonState&&) noexcept = default;
SkeletonState::SkeletonState(const SkeletonState& o)
    : impl_(std::make_unique<Impl>(*o.impl_)),
      stage_(o.stage_),
      q_(o.q_),
      qdot_(o.qdot_),
      X_ground_body_(o.X_ground_body_),
      coupling_(o.coupling_) {}

const Transform& SkeletonState::get_body_transform(int body) const {
  if (stage_ < SkeletonStage::pose) throw_usage("the skeleton state has no pose: call calc_pose first");
  return X_ground_body_.at(body);
}
const std::vector<Transform>& SkeletonState::get_body_transforms() const {
  if (stage_ < SkeletonStage::pose) throw_usage("the skeleton state has no pose: call calc_pose first");
  return X_ground_body_;
}

void calc_pose(const Skeleton& skeleton, const VecX& q_in, SkeletonState& s,
               const PoseOptions& options) {
  const Skeleton::Impl& m = skeleton.impl();
  const int nc = skeleton.num_coordinates();
  if (q_in.size() != nc)
    throw_bad_input("pose has " + std::to_string(q_in.size()) + " values but the skeleton has " +
                    std::to_string(nc) + " coordinates");
  VecX q = q_in;
  for (int i = 0; i < nc; ++i) {
    const CoordinateSpec& c = m.coordinates[i].spec;
    if (m.coordinates[i].dependent_on >= 0) continue;
    if (!std::isfinite(q[i]))
      throw_bad_input("coordinate value is not finite", object_context(c.name));
    if (options.apply_locks && c.locked) q[i] = c.default_value;
    if (options.clamp && c.clamped) q[i] = std::clamp(q[i], c.range_min, c.range_max);
  }
  // Assembly of the couplers and their coupling matrix.
  s.coupling_.setIdentity(nc, nc);
  for (const int c : m.coupler_order) {
    const int dep = m.coupler_dependent[c];
    const int ind = m.coupler_independent[c];
    const FunctionValue v = calc_function(m.spec.couplers[c].function, q[ind]);
    q[dep] = v.value;
    s.coupling_.row(dep) = v.slope * s.coupling_.row(ind);
  }
  for (const int c : m.coupler_order) s.coupling_.col(m.coupler_dependent[c]).setZero();
  SimTK::State& st = s.impl_->state;
  SimTK::Vector& Q = st.updQ();
  for (int i = 0; i < nc; ++i) Q[m.coord_q[i]] = q[i];
  m.system->realize(st, SimTK::Stage::Position);
  for (std::size_t b = 1; b < m.bodies.size(); ++b)
    s.X_ground_body_[b] = to_eigen(m.matter->getMobilizedBody(m.mobod[b]).getBodyTransform(st));
  s.q_ = q;
  s.qdot_.setZero(nc);
  s.stage_ = SkeletonStage::pose;
}

void calc_velocity(const Skeleton& skeleton, const VecX& qdot, SkeletonState& s) {
  const Skeleton::Impl& m = skeleton.impl();
  if (s.stage_ < SkeletonStage::pose) throw_usage("calc_velocity needs a posed state");
  if (qdot.size() != skeleton.num_coordinates())
    throw_bad_input("speeds have the wrong size");
  // Independent speeds, then dependent ones by the chain rule through the coupling matrix.
  VecX independent = qdot;
  for (const int c : m.coupler_order) independent[m.coupler_dependent[c]] = 0.0;
  const VecX u = s.coupling_ * independent;
  SimTK::State& st = s.impl_->state;
  SimTK::Vector& U = st.updU();
  for (int i = 0; i < u.size(); ++i) U[m.coord_q[i]] = u[i];
  m.system->realize(st, SimTK::Stage::Velocity);
  s.qdot_ = u;
  s.stage_ = SkeletonStage::velocity;
}

Vec3 calc_station_location(const SkeletonState& s, int body, const Vec3& p_body) {
  return s.get_body_transform(body) * p_body;
}

Vec3 calc_station_velocity(const Skeleton& skeleton, const SkeletonState& s, int body,
                           const Vec3& p_body) {
  if (s.stage() < SkeletonStage::velocity) throw_usage("calc_station_velocity needs calc_velocity");
  const Skeleton::Impl& m = skeleton.impl();
  return to_eigen(m.matter->getMobilizedBody(m.mobod.at(body))
                      .findStationVelocityInGround(s.impl().state, to_simtk(p_body)));
}

Vec3 calc_station_bias_acceleration(const Skeleton& skeleton, const SkeletonState& s, int body,
                                    const Vec3& p_body) {
  if (s.stage() < SkeletonStage::velocity)
    throw_usage("calc_station_bias_acceleration needs calc_velocity");
  const Skeleton::Impl& m = skeleton.impl();
  return to_eigen(m.matter->calcBiasForStationJacobian(s.impl().state, m.mobod.at(body),
                                                       to_simtk(p_body)));
}

VecX calc_generalized_forces(const Skeleton& skeleton, const SkeletonState& s,
                             const std::vector<PointForce>& forces, VecX* uncoupled) {
  if (s.stage() < SkeletonStage::pose) throw_usage("calc_generalized_forces needs a posed state");
  const Skeleton::Impl& m = skeleton.impl();
  const SimTK::State& st = s.impl().state;
  // Body spatial forces about each body origin, in ground: moment r × f and force f.
  SimTK::Vector_<SimTK::SpatialVec> F(static_cast<int>(m.matter->getNumBodies()),
                                      SimTK::SpatialVec(SimTK::Vec3(0), SimTK::Vec3(0)));
  for (const PointForce& pf : forces) {
    if (pf.body <= 0) continue;  // forces on the ground do no work
    const Transform& X = s.get_body_transform(pf.body);
    const Vec3 r = X.linear() * pf.p_body;
    const int mb = m.mobod.at(pf.body);
    F[mb][0] += to_simtk(Vec3(r.cross(pf.f_ground)));
    F[mb][1] += to_simtk(pf.f_ground);
  }
  SimTK::Vector f;
  m.matter->multiplyBySystemJacobianTranspose(st, F, f);
  const int nc = skeleton.num_coordinates();
  VecX tau(nc);
  for (int i = 0; i < nc; ++i) tau[i] = f[m.coord_q[i]];
  if (uncoupled) *uncoupled = tau;
  return s.get_coupling().transpose() * tau;
}

void calc_body_jacobians(const Skeleton& skeleton, const SkeletonState& s,
                         std::vector<Eigen::Matrix<double, 6, Eigen::Dynamic>>& J) {
  if (s.stage() < SkeletonStage::pose) throw_usage("calc_body_jacobians needs a posed state");
  const Skeleton::Impl& m = skeleton.impl();
  const SimTK::State& st = s.impl().state;
  const int nb = skeleton.num_bodies();
  const int nc = skeleton.num_coordinates();
  J.resize(nb);
  for (int b = 0; b < nb; ++b) J[b].setZero(6, nc);
  // A unit speed of coordinate j moves the child body B of its joint, and the whole subtree of B
  // with it, rigidly: one twist (ω, velocity of the point at the ground origin) for all of them.
  // Simbody's hinge column gives B's spatial velocity per unit u (ω; velocity of B's origin).
  for (int j = 0; j < nc; ++j) {
    const SimTK::MobilizedBody& mb = m.matter->getMobilizedBody(m.coord_mobod[j]);
    const SimTK::SpatialVec H = mb.getHCol(st, SimTK::MobilizerUIndex(m.coord_local_q[j]));
    const int body = m.body_index.at(m.spec.joints[m.coordinates[j].joint].child);
    const Vec3 w = to_eigen(H[0]);
    const Vec3 v0 = to_eigen(H[1]) - w.cross(Vec3(s.get_body_transform(body).translation()));
    for (int d = 1; d < nb; ++d) {
      int a = d;
      while (a > 0 && a != body) a = m.parent_body[a];
      if (a != body) continue;
      J[d].col(j).head<3>() = w;
      J[d].col(j).tail<3>() = v0;
    }
  }
  // Coupling: a dependent coordinate moves with its independent ones (J·C, C sparse).
  const MatX& C = s.get_coupling();
  for (const int c : m.coupler_order) {
    const int dep = m.coupler_dependent[c];
    for (int b = 1; b < nb; ++b) {
      if (J[b].col(dep).isZero(0.0)) continue;
      for (int k = 0; k < nc; ++k)
        if (k != dep && C(dep, k) != 0.0) J[b].col(k) += C(dep, k) * J[b].col(dep);
    }
  }
  for (const int c : m.coupler_order)
    for (int b = 1; b < nb; ++b) J[b].col(m.coupler_dependent[c]).setZero();
}

double calc_constraint_error(const Skeleton& skeleton, const SkeletonState& s) {
  if (s.stage() < SkeletonStage::pose) throw_usage("calc_constraint_error needs a posed state");
  const SimTK::Vector& err = s.impl().state.getQErr();
  (void)skeleton;
  double e = 0.0;
  for (int i = 0; i < err.size(); ++i) e = std::max(e, std::abs(err[i]));
  return e;
}

}  // namespace fascicle
