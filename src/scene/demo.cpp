// The procedural right lower leg of `fascicle demo`. Dimensions (metres) follow an adult male of
// height H = 1.75 m:
//  - segment lengths from Winter DA, Biomechanics and Motor Control of Human Movement, 4th ed.,
//    Wiley 2009, Fig. 4.1: leg (knee–ankle) 0.246 H = 0.43 m, foot length 0.152 H = 0.27 m,
//    foot width 0.055 H = 0.10 m, ankle height 0.039 H = 0.07 m;
//  - distal femoral bicondylar width ≈ 85 mm and tibial plateau width ≈ 75 mm (typical adult male
//    values, e.g. Yoshioka et al. 1987, J Bone Joint Surg Am 69:873; Yue et al. 2011, Clin Orthop
//    469:1006); long-bone shaft diameters 25–30 mm (tibia) and ≈ 14 mm (fibula);
//  - muscle masses, optimal fibre lengths, pennation and PCSA from Ward SR et al. 2009, Clin Orthop
//    Relat Res 467:1074 (shared data architecture/ward2009_subset.csv); volume = mass / 1.056
//    g/cm³ (muscle density, Ward & Lieber 2005, J Biomech 38:2317); F0 = 60 N/cm² × PCSA
//    (specific tension of Rajagopal et al. 2016, IEEE TBME 63:2068).
// Shapes are smooth spindles (closed, outward oriented), not anatomical reconstructions.
#include "fascicle/scene/demo.hpp"

#include "fascicle/geometry/mass_properties.hpp"
#include "fascicle/geometry/primitives.hpp"

#include <cmath>
#include <functional>

namespace fascicle {
namespace {

constexpr double kDeg = M_PI / 180.0;

using Profile = std::function<double(double t)>;

// A closed bone along y from y0 to y1 (t = 0 at y0): elliptical cross-sections with half-widths
// a(t) along x (anterior) and b(t) along z (lateral), centred at (cx(t), cz(t)). The map from the
// unit spindle has a positive Jacobian, so the mesh stays closed and outward oriented.
TriMesh make_shaped_bone(double y0, double y1, const Profile& a, const Profile& b, const Profile& cx,
                         const Profile& cz, int segments = 32, int rings = 40) {
  TriMesh mesh = make_spindle(0.0, 1.0, segments, rings, [](double) { return 1.0; });
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    const double x = mesh.V(i, 0), y = mesh.V(i, 1), t = mesh.V(i, 2);
    // Rotation about x by −90° (spindle z → y, spindle y → −z), then the shaping.
    mesh.V.row(i) << cx(t) + a(t) * x, y0 + t * (y1 - y0), cz(t) - b(t) * y;
  }
  return mesh;
}

Profile constant(double v) {
  return [v](double) { return v; };
}
// A bump of height h centred at t = c with width w (Gaussian).
Profile bump(double base, double h, double c, double w) {
  return [=](double t) { return base + h * std::exp(-std::pow((t - c) / w, 2)); };
}
Profile sum(Profile f, Profile g) {
  return [=](double t) { return f(t) + g(t); };
}

TriMesh make_ellipsoid_at(const Vec3& centre, const Vec3& radii, int subdivisions = 3) {
  TriMesh mesh = make_ellipsoid(radii, subdivisions);
  mesh.V.rowwise() += centre.transpose();
  return mesh;
}

// A fusiform belly between p0 (proximal) and p1 (distal), elliptical section (half-widths ratio
// `flat` between the lateral and the anterior axis), scaled to enclose `volume_m3`. Also returns
// `n_fibres` rest fibres parallel to the belly axis at half the local radius.
struct Belly {
  TriMesh mesh;
  std::vector<Points3> fibres;
};

Belly make_belly(const Vec3& p0, const Vec3& p1, double volume_m3, double flat, int resolution, int n_fibres) {
  const double length = (p1 - p0).norm();
  const auto profile = [](double t) { return std::pow(std::sin(M_PI * t), 0.6); };
  TriMesh unit = make_spindle(0.0, length, 24 * resolution, 30 * resolution, profile);
  // Elliptical section: x (anterior) × 1, y (lateral) × flat.
  unit.V.col(1) *= flat;
  const double v1 = calc_mass_properties(unit).volume_m3;
  const double r = std::sqrt(volume_m3 / v1);
  unit.V.col(0) *= r;
  unit.V.col(1) *= r;
  // Frame of the belly: z along p1 − p0, x as close to anterior as possible, y lateral.
  const Vec3 ez = (p1 - p0).normalized();
  const Vec3 ex = (Vec3::UnitX() - Vec3::UnitX().dot(ez) * ez).normalized();
  const Vec3 ey = ez.cross(ex);
  Mat3 R;
  R << ex, ey, ez;
  Belly belly;
  belly.mesh.F = unit.F;
  belly.mesh.V = ((unit.V * R.transpose()).rowwise() + p0.transpose()).eval();
  const int samples = 21;
  for (int k = 0; k < n_fibres; ++k) {
    const double phi = 2.0 * M_PI * k / n_fibres;
    Points3 f(samples, 3);
    for (int s = 0; s < samples; ++s) {
      const double t = 0.05 + 0.9 * s / (samples - 1);
      const double rad = 0.5 * r * profile(t);
      const Vec3 local(rad * std::cos(phi), flat * rad * std::sin(phi), t * length);
      f.row(s) = (R * local + p0).transpose();
    }
    belly.fibres.push_back(f);
  }
  return belly;
}

SceneBodySpec make_bone(const std::string& name, TriMesh mesh) {
  SceneBodySpec b;
  b.name = name;
  b.mesh = std::move(mesh);
  b.mesh_file = "procedural:" + name;
  return b;
}

SceneJointSpec make_joint(const std::string& name, const std::string& type, const std::string& parent,
                     const std::string& child, const Vec3& p_parent, const Vec3& axis,
                     std::vector<SceneCoordinateSpec> coordinates = {}) {
  SceneJointSpec j;
  j.name = name;
  j.type = type;
  j.parent = parent;
  j.child = child;
  j.X_parent_F.translation() = p_parent;
  j.axis = axis;
  j.coordinates = std::move(coordinates);
  return j;
}

struct WardRow {
  double pcsa_cm2, mass_g, fibre_cm, pennation_deg;
};

}  // namespace

DemoScene make_demo_leg(double samples_hz, int muscle_resolution) {
  DemoScene demo;
  SceneSpec& s = demo.spec;
  s.name = "demo_right_lower_leg";
  s.geometry_frame = GeometryFrame::ground;  // everything below is given at the default pose

  // Distal femur: shaft (half-widths 14 mm) flaring into the condyles (AP 60 mm, ML 85 mm).
  s.bodies.push_back(make_bone("femur",
      make_shaped_bone(-0.025, 0.20, bump(0.014, 0.016, 0.1, 0.3), bump(0.015, 0.0275, 0.08, 0.28),
                       bump(0.0, -0.006, 0.1, 0.3), constant(0.0))));
  // Tibia: plateau 75 mm ML below the knee, shaft, distal metaphysis; 0.39 m long.
  s.bodies.push_back(make_bone("tibia",
      make_shaped_bone(-0.42, -0.03, sum(bump(0.014, 0.008, 0.0, 0.15), bump(0.0, 0.012, 1.0, 0.12)),
                       sum(bump(0.013, 0.012, 0.0, 0.15), bump(0.0, 0.0245, 1.0, 0.12)),
                       constant(0.0), bump(0.0, -0.004, 0.0, 0.2))));
  // Fibula: lateral and posterior of the tibia; head and lateral malleolus.
  s.bodies.push_back(make_bone("fibula",
      make_shaped_bone(-0.445, -0.07, sum(bump(0.006, 0.005, 0.05, 0.1), bump(0.0, 0.006, 0.95, 0.1)),
                       sum(bump(0.006, 0.004, 0.05, 0.1), bump(0.0, 0.006, 0.95, 0.1)),
                       constant(-0.012), constant(0.040), 20, 40)));
  // Talus (under the tibia), calcaneus (heel, posterior tip 62 mm behind the ankle) and the rest of
  // the foot (toe tip 200 mm in front of the ankle): foot length 0.26 m, width ≈ 0.09 m.
  const Vec3 ankle(0.0, -0.43, 0.0);
  s.bodies.push_back(make_bone("talus", make_ellipsoid_at(ankle + Vec3(0.005, -0.012, 0.0), Vec3(0.028, 0.016, 0.021))));
  s.bodies.push_back(make_bone("calcaneus", make_ellipsoid_at(ankle + Vec3(-0.02, -0.046, 0.003), Vec3(0.042, 0.022, 0.02))));
  s.bodies.push_back(make_bone("foot", make_ellipsoid_at(ankle + Vec3(0.10, -0.05, 0.005), Vec3(0.10, 0.016, 0.045))));

  // Joints: femur fixed; knee and ankle hinges about the mediolateral axis (knee flexion and ankle
  // dorsiflexion positive: the knee axis points medially, the ankle axis laterally).
  s.joints.push_back(make_joint("ground_femur", "weld", "ground", "femur", Vec3::Zero(), Vec3::UnitZ()));
  s.joints.push_back(make_joint("knee", "pin", "femur", "tibia", Vec3::Zero(), -Vec3::UnitZ(),
                                {{"knee_flexion", 0.0, 0.0, 120.0 * kDeg}}));
  s.joints.push_back(make_joint("tibia_fibula", "weld", "tibia", "fibula", Vec3::Zero(), Vec3::UnitZ()));
  s.joints.push_back(make_joint("ankle", "pin", "tibia", "talus", ankle, Vec3::UnitZ(),
                                {{"ankle_angle", 0.0, -50.0 * kDeg, 40.0 * kDeg}}));
  s.joints.push_back(make_joint("subtalar_fixed", "weld", "talus", "calcaneus", Vec3::Zero(), Vec3::UnitZ()));
  s.joints.push_back(make_joint("midfoot_fixed", "weld", "talus", "foot", Vec3::Zero(), Vec3::UnitZ()));
  // Body frames: tibia and fibula coincide with the femur's at q = 0; talus, calcaneus and foot
  // frames are at the ankle centre (their joint frames F, with X_child_M = identity).
  // Muscles (Ward et al. 2009 rows: PCSA cm², mass g, fibre length cm, pennation °).
  const Vec3 achilles = ankle + Vec3(-0.062, -0.035, 0.0);
  struct Def {
    std::string name, origin_body, insertion_body, via_body, fibre_template;
    std::vector<Vec3> origin_points;
    Vec3 insertion_point, via_point, belly_top, belly_bottom;
    double flat;
    WardRow ward;
  };
  const std::vector<Def> defs = {
      {"soleus", "tibia", "calcaneus", "", "bipennate",
       {{-0.022, -0.085, -0.005}, {-0.018, -0.08, 0.035}},  // posterior tibia, fibular head
       achilles, Vec3::Zero(), {-0.038, -0.085, 0.008}, {-0.05, -0.34, 0.0}, 1.5,
       {51.8, 275.8, 4.40, 28.3}},
      {"medial_gastrocnemius", "femur", "calcaneus", "tibia", "pennate",
       {{-0.028, 0.025, -0.027}}, achilles, {-0.075, -0.12, -0.022}, {-0.045, 0.015, -0.025},
       {-0.07, -0.22, -0.012}, 1.3, {21.1, 113.5, 5.10, 9.9}},
      {"lateral_gastrocnemius", "femur", "calcaneus", "tibia", "pennate",
       {{-0.028, 0.025, 0.027}}, achilles, {-0.072, -0.12, 0.022}, {-0.045, 0.015, 0.025},
       {-0.068, -0.19, 0.012}, 1.2, {9.7, 62.2, 5.88, 12.0}},
      {"tibialis_anterior", "tibia", "foot", "tibia", "bipennate",
       {{0.012, -0.09, 0.026}},  // lateral condyle / proximal lateral tibia
       ankle + Vec3(0.07, -0.03, -0.025),  // medial cuneiform / first metatarsal base
       {0.03, -0.40, -0.005}, {0.02, -0.09, 0.026}, {0.028, -0.31, 0.012}, 1.2,
       {10.9, 80.1, 6.83, 9.6}},
  };
  for (const Def& d : defs) {
    MuscleSpec m;
    m.name = d.name;
    m.representation = "surface_first";
    m.fibre_template = d.fibre_template;
    const double volume = d.ward.mass_g / 1.056 * 1e-6;  // m³
    Belly belly = make_belly(d.belly_top, d.belly_bottom, volume, d.flat, muscle_resolution, 8);
    m.mesh = std::move(belly.mesh);
    m.mesh_file = "procedural:" + d.name;
    m.rest_fibres = std::move(belly.fibres);
    m.origin = {d.origin_body, d.origin_points, 0.02};
    m.insertion = {d.insertion_body, {d.insertion_point}, 0.015};
    if (!d.via_body.empty()) m.via_points.push_back({d.via_body, d.via_point});
    m.actuator.type = "hill";
    m.actuator.model = "millard";
    m.actuator.max_isometric_force_N = 60.0 * d.ward.pcsa_cm2;
    m.actuator.optimal_fiber_length_m = d.ward.fibre_cm * 0.01;
    m.actuator.pennation_at_optimal_rad = d.ward.pennation_deg * kDeg;
    // Tendon slack length: the rest pose (knee 0, ankle 0) puts the fibres at optimal length with
    // a slack tendon: lTs = lMT(rest) − l0 cos α0.
    double l_rest = 0.0;
    std::vector<Vec3> line = {Vec3::Zero()};
    for (const Vec3& p : d.origin_points) line[0] += p / static_cast<double>(d.origin_points.size());
    if (!d.via_body.empty()) line.push_back(d.via_point);
    line.push_back(d.insertion_point);
    for (size_t k = 0; k + 1 < line.size(); ++k) l_rest += (line[k + 1] - line[k]).norm();
    m.actuator.tendon_slack_length_m = l_rest - m.actuator.optimal_fiber_length_m * std::cos(m.actuator.pennation_at_optimal_rad);
    m.activation = 0.2;
    s.muscles.push_back(std::move(m));
  }

  // Motion: 2 s, knee 0 → 60° → 0, ankle −20° → +30° → −20° (cosine profiles).
  const int n = static_cast<int>(std::lround(2.0 * samples_hz)) + 1;
  Table& t = demo.motion;
  t.name = "demo_motion";
  t.labels = {"knee_flexion", "ankle_angle"};
  t.in_degrees = true;
  t.time.resize(n);
  t.data.resize(n, 2);
  for (int i = 0; i < n; ++i) {
    const double time = 2.0 * i / (n - 1);
    const double c = 0.5 - 0.5 * std::cos(M_PI * time);  // 0 → 1 → 0 over 2 s
    t.time[i] = time;
    t.data(i, 0) = 60.0 * c;
    t.data(i, 1) = -20.0 + 50.0 * c;
  }
  return demo;
}

}  // namespace fascicle
