// Muscle parameters from OpenSim model files (real gait2392 data and inline XML).
#include "fascicle/core/error.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/musculotendon/osim_parameters.hpp"
#include "test_support.hpp"

#include <gtest/gtest.h>
#include <pugixml.hpp>

#include <array>
#include <cmath>
#include <fstream>
#include <map>
#include <sstream>

using namespace fascicle;

namespace {
// name -> {F0, l0, lTs, alpha0} from architecture/gait2392_muscle_params.csv
std::map<std::string, std::array<double, 4>> read_param_table() {
  std::ifstream in(test::data_path("architecture/gait2392_muscle_params.csv"));
  std::map<std::string, std::array<double, 4>> out;
  std::string line;
  std::getline(in, line);
  while (std::getline(in, line)) {
    std::stringstream ss(line);
    std::string type, name, v;
    std::getline(ss, type, ',');
    std::getline(ss, name, ',');
    std::array<double, 4> a{};
    for (double& x : a) {
      std::getline(ss, v, ',');
      x = std::stod(v);
    }
    out[name] = a;
  }
  return out;
}

int parse_all(const std::string& file, MuscleModel expected, const auto& table) {
  pugi::xml_document doc;
  EXPECT_TRUE(doc.load_file(file.c_str()));
  int n = 0;
  for (const pugi::xpath_node& x : doc.select_nodes("//*[@name]")) {
    if (!is_osim_muscle_element(x.node())) continue;
    const MuscleParameters p = parse_osim_muscle(x.node(), file);
    EXPECT_EQ(p.model, expected);
    const auto it = table.find(p.name);
    if (it != table.end()) {
      EXPECT_DOUBLE_EQ(p.max_isometric_force_N, it->second[0]) << p.name;
      EXPECT_DOUBLE_EQ(p.optimal_fiber_length_m, it->second[1]) << p.name;
      EXPECT_DOUBLE_EQ(p.tendon_slack_length_m, it->second[2]) << p.name;
      EXPECT_DOUBLE_EQ(p.pennation_at_optimal_rad, it->second[3]) << p.name;
    } else {
      ADD_FAILURE() << p.name << " missing from the parameter table";
    }
    // Every gait2392 muscle compiles and has a finite equilibrium at its optimal-ish length.
    const Musculotendon m = compile_musculotendon(p);
    const MuscleOutputs o = calc_static_equilibrium(
        m, 0.5, p.tendon_slack_length_m * 1.02 + p.optimal_fiber_length_m);
    EXPECT_TRUE(std::isfinite(o.fiber_length_m)) << p.name;
    ++n;
  }
  return n;
}
}  // namespace

TEST(OsimParameters, Gait2392ThelenFileValuesWin) {
  const auto file = test::data_path("opensim/models/gait2392_thelen2003muscle.osim").string();
  const MuscleParameters p = read_osim_muscle(file, "glut_med1_r");
  EXPECT_EQ(p.model, MuscleModel::thelen2003);
  EXPECT_EQ(p.max_isometric_force_N, 819.0);
  EXPECT_EQ(p.optimal_fiber_length_m, 0.053499999999999999);
  EXPECT_EQ(p.tendon_slack_length_m, 0.078);
  EXPECT_EQ(p.thelen.FmaxTendonStrain, 0.033000000000000002);
  EXPECT_EQ(p.thelen.KshapeActive, 0.5);
  EXPECT_EQ(p.thelen.KshapePassive, 4.0);
  EXPECT_EQ(p.thelen.Af, 0.29999999999999999);
  EXPECT_EQ(p.thelen.Flen, 1.8);
  EXPECT_EQ(p.activation_time_constant_s, 0.01);
  EXPECT_EQ(p.deactivation_time_constant_s, 0.040000000000000001);
  EXPECT_EQ(parse_all(file, MuscleModel::thelen2003, read_param_table()), 92);
}

TEST(OsimParameters, Gait2392MillardCurvesAndDefaults) {
  const auto file = test::data_path("opensim/models/gait2392_millard2012muscle.osim").string();
  const MuscleParameters p = read_osim_muscle(file, "soleus_r");
  EXPECT_EQ(p.model, MuscleModel::millard2012);
  EXPECT_EQ(p.millard.minimum_value, 0.0);                 // from the file
  EXPECT_EQ(p.millard.fiber_damping, 0.1);                 // absent: OpenSim default
  EXPECT_EQ(p.activation_time_constant_s, 0.01);           // absent: Millard default
  EXPECT_EQ(p.millard.tendon_strain_at_one_norm_force, 0.049);
  EXPECT_EQ(parse_all(file, MuscleModel::millard2012, read_param_table()), 92);
}

TEST(OsimParameters, InlineElementsNamespacesDefaultsAndErrors) {
  pugi::xml_document doc;
  ASSERT_TRUE(doc.load_string(R"(<OpenSimDocument Version="30000"><Model><ForceSet><objects>
      <OpenSim::DeGrooteFregly2016Muscle name="m1">
        <max_isometric_force>500</max_isometric_force>
        <optimal_fiber_length>0.1</optimal_fiber_length>
        <tendon_slack_length>0.2</tendon_slack_length>
        <tendon_strain_at_one_norm_force>0.06</tendon_strain_at_one_norm_force>
      </OpenSim::DeGrooteFregly2016Muscle>
      <Millard2012EquilibriumMuscle name="m2">
        <optimal_fiber_length>0.1</optimal_fiber_length>
        <tendon_slack_length>0.2</tendon_slack_length>
        <FiberForceLengthCurve><strain_at_one_norm_force>0.5</strain_at_one_norm_force></FiberForceLengthCurve>
        <TendonForceLengthCurve><strain_at_one_norm_force>0.04</strain_at_one_norm_force></TendonForceLengthCurve>
      </Millard2012EquilibriumMuscle>
      <Thelen2003Muscle name="bad"><optimal_fiber_length>0.1x</optimal_fiber_length></Thelen2003Muscle>
      <Thelen2003Muscle name="neg"><tendon_slack_length>-0.2</tendon_slack_length></Thelen2003Muscle>
      </objects></ForceSet></Model></OpenSimDocument>)"));
  const pugi::xml_node objects = doc.select_node("//objects").node();
  auto it = objects.children().begin();
  const MuscleParameters d = parse_osim_muscle(*it++, "inline.osim");
  EXPECT_EQ(d.model, MuscleModel::degroote2016);
  EXPECT_EQ(d.max_isometric_force_N, 500.0);
  EXPECT_EQ(d.degroote.tendon_strain_at_one_norm_force, 0.06);
  EXPECT_EQ(d.activation_time_constant_s, 0.015);
  const MuscleParameters m = parse_osim_muscle(*it++, "inline.osim");
  EXPECT_EQ(m.max_isometric_force_N, 1000.0);  // C++ default kept
  EXPECT_NEAR(m.millard.fiber_stiffness_at_one_norm_force, 2.0 / 0.5, 1e-15);
  EXPECT_NEAR(m.millard.tendon_stiffness_at_one_norm_force, 1.375 / 0.04, 1e-12);
  try {
    parse_osim_muscle(*it++, "inline.osim");
    FAIL();
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("optimal_fiber_length"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("bad"), std::string::npos);
  }
  EXPECT_THROW(parse_osim_muscle(*it++, "inline.osim"), Error);
  EXPECT_THROW(read_osim_muscle(test::data_path("opensim/models/arm26.osim"), "no_such_muscle"), Error);
}
