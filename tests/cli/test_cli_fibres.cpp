// End-to-end tests of `fascicle fibres`.
#include "test_support.hpp"

#include <nlohmann/json.hpp>

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace {

struct FibresCliRun {
  int code;
  std::string out;
};

FibresCliRun run_fibres_cli(const std::string& args) {
  const auto r =
      fascicle::test::run_command(std::string(FASCICLE_CLI_PATH) + " -q fibres " + args + " 2>&1");
  return {r.exit_code, r.output};
}

std::string ta_mesh() {
  return fascicle::test::data_path("bolsterlee_dti/TA.stl").string();
}

}  // namespace

TEST(CliFibres, TemplateMethodWritesFibresAndReport) {
  const auto dir = fascicle::test::scratch_dir("cli_fibres_template");
  const auto vtp = (dir / "ta.vtp").string(), json = (dir / "ta.json").string();
  const FibresCliRun r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --template parallel "
                                        "--method template --count 40 --resolution 9 --out " +
                                        vtp + " --report " + json);
  ASSERT_EQ(r.code, 0) << r.out;
  ASSERT_TRUE(std::filesystem::exists(vtp));
  std::ifstream in(json);
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["fibre_count"].get<int>(), 40);
  EXPECT_EQ(j["method"].get<std::string>(), "template");
  // The TA belly is about 27 cm long; its volume about 100-200 cm^3.
  EXPECT_GT(j["mean_fibre_length_m"].get<double>(), 0.15);
  EXPECT_LT(j["mean_fibre_length_m"].get<double>(), 0.35);
  EXPECT_GT(j["volume_m3"].get<double>(), 50e-6);
  EXPECT_LT(j["volume_m3"].get<double>(), 400e-6);
  double share = 0.0;
  for (const auto& f : j["fibres"]) share += f["volume_share"].get<double>();
  EXPECT_NEAR(share, 1.0, 1e-9);
}

TEST(CliFibres, BadInputsGiveClearErrors) {
  const auto dir = fascicle::test::scratch_dir("cli_fibres_bad");
  const auto vtp = (dir / "x.vtp").string();
  // Unknown template: usage error (2).
  FibresCliRun r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --template spiral --out " + vtp);
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("spiral"), std::string::npos) << r.out;
  // Missing mesh: bad input (3) naming the file.
  r = run_fibres_cli("--mesh " + (dir / "none.stl").string() + " --out " + vtp);
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("none.stl"), std::string::npos) << r.out;
  // Landmarks of another muscle (far from this surface): bad input (3).
  const auto far = (dir / "far.csv").string();
  std::ofstream(far) << "x,y,z\n1000,1000,1000\n1001,1000,1000\n";
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --origin " + far + " --insertion " + far +
                     " --out " + vtp);
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("landmark"), std::string::npos) << r.out;
  // A non-manifold muscle is rejected with the mesh report (3).
  r = run_fibres_cli("--mesh " +
                     fascicle::test::data_path("negative/left_biceps_brachii.stl").string() +
                     " --units mm --out " + vtp);
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_FALSE(std::filesystem::exists(vtp));
}

TEST(CliFibres, AponeurosisAttachmentsGivePennateFibres) {
  const auto dir = fascicle::test::scratch_dir("cli_fibres_aponeurosis");
  const auto vtp = (dir / "ta.vtp").string(), json = (dir / "ta.json").string();
  const std::string apo = fascicle::test::data_path("bolsterlee_dti/TA_apo.stl").string();
  FibresCliRun r = run_fibres_cli(
      "--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --architecture bipennate "
      "--pennation-deg 9.6 --aponeurosis " + apo + " --method harmonic --count 40 --resolution 9 "
      "--out " + vtp + " --report " + json);
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(json);
  const nlohmann::json j = nlohmann::json::parse(in);
  EXPECT_EQ(j["attachments"].get<std::string>(), "aponeurosis");
  EXPECT_EQ(j["architecture"].get<std::string>(), "bipennate");
  EXPECT_EQ(j["pennation_plane"].get<std::string>(), "thickness");
  // Pennate fibres between the surface and the aponeurosis: Ward et al. 2009 give 68.3 mm for the
  // TA; end-to-end fibres of this belly are about 27 cm.
  EXPECT_GT(j["mean_fibre_length_m"].get<double>(), 0.0683 * 0.75);
  EXPECT_LT(j["mean_fibre_length_m"].get<double>(), 0.0683 * 1.25);
  // Missing pennation angle, unknown architecture: usage errors.
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --method "
                     "harmonic --out " + vtp);
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--pennation-deg"), std::string::npos) << r.out;
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis "
                     "--architecture multipennate --pennation-deg 10 --out " + vtp);
  EXPECT_EQ(r.code, 2) << r.out;
  // An aponeurosis of another muscle (outside this one): bad input naming the file.
  const std::string mg = fascicle::test::data_path("bolsterlee_dti/MG.stl").string();
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis "
                     "--architecture bipennate --pennation-deg 10 --aponeurosis " + mg +
                     " --method harmonic --out " + vtp);
  EXPECT_EQ(r.code, 3) << r.out;
  EXPECT_NE(r.out.find("MG.stl"), std::string::npos) << r.out;
}

TEST(CliFibres, RiseCrossingRuleIsSelectable) {
  // With a pennation angle, the mapped-crossing rise makes the TA's pennate fibres run at the
  // target angle; the default (mean thickness) gives a steeper angle and so shorter fibres
  // (docs/fibres.md, "Rise from a pennation angle").
  const auto dir = fascicle::test::scratch_dir("cli_fibres_rise");
  double length[2] = {0.0, 0.0};
  const char* rules[2] = {"mean-thickness", "mapped-crossing"};
  for (int i = 0; i < 2; ++i) {
    const auto json = (dir / (std::string(rules[i]) + ".json")).string();
    const FibresCliRun r = run_fibres_cli(
        "--mesh " + ta_mesh() + " --units mm --template pennate --pennation-deg 9.6 "
        "--rise-crossing " + rules[i] + " --count 40 --resolution 9 --out " +
        (dir / "f.vtp").string() + " --report " + json);
    ASSERT_EQ(r.code, 0) << r.out;
    std::ifstream in(json);
    length[i] = nlohmann::json::parse(in)["mean_fibre_length_m"].get<double>();
  }
  EXPECT_GT(length[1], 1.05 * length[0]);
  const FibresCliRun bad = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --template pennate "
                                          "--pennation-deg 9.6 --rise-crossing chord --out " +
                                          (dir / "f.vtp").string());
  EXPECT_EQ(bad.code, 2) << bad.out;
  // The rule applies to the template method only: elsewhere it is a usage error, not ignored.
  const FibresCliRun ignored = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --method harmonic "
                                              "--pennation-deg 9.6 --rise-crossing mapped-crossing --out " +
                                              (dir / "f.vtp").string());
  EXPECT_EQ(ignored.code, 2) << ignored.out;
}

TEST(CliFibres, PennationAgainstTheAponeurosesWithTheInsertionOnTheDeepSide) {
  // Bolsterlee MG, unipennate, insertion face towards the TA (the deep side), 21.8 degrees to the
  // aponeuroses: fibres cross the 18.9 mm belly, t / sin(a) = 51 mm (docs/fibres.md).
  const auto dir = fascicle::test::scratch_dir("cli_fibres_reference");
  const auto json = (dir / "mg.json").string();
  const std::string mg = fascicle::test::data_path("bolsterlee_dti/MG.stl").string();
  FibresCliRun r = run_fibres_cli(
      "--mesh " + mg + " --units mm --attachments aponeurosis --architecture unipennate "
      "--pennation-deg 21.8 --method harmonic --pennation-reference aponeurosis "
      "--insertion-side " + ta_mesh() + " --count 30 --resolution 9 --out " +
      (dir / "mg.vtp").string() + " --report " + json);
  ASSERT_EQ(r.code, 0) << r.out;
  std::ifstream in(json);
  const double length = nlohmann::json::parse(in)["mean_fibre_length_m"].get<double>();
  EXPECT_GT(length, 0.051 * 0.75);
  EXPECT_LT(length, 0.051 * 1.25);
  // Without aponeurosis areas the option is a usage error; an unknown reference too.
  r = run_fibres_cli("--mesh " + mg + " --units mm --insertion-side " + ta_mesh() + " --out " +
                     (dir / "x.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  r = run_fibres_cli("--mesh " + mg + " --units mm --attachments aponeurosis --pennation-deg 20 "
                     "--method harmonic --pennation-reference tendon --out " +
                     (dir / "x.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  // The aponeurosis reference needs aponeurosis areas: without them it is refused, not ignored.
  r = run_fibres_cli("--mesh " + mg + " --units mm --method harmonic --pennation-reference aponeurosis "
                     "--out " + (dir / "x.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
}

TEST(CliFibres, PennationPlaneIsSelectable) {
  // Bolsterlee TA: the pennate field turning in the thickness plane (default), in the plane of
  // the aponeurosis potential's gradient, or towards TA_apo's tendon-side border (session 10); the
  // fibres differ, all within Ward's +-25 %.
  const auto dir = fascicle::test::scratch_dir("cli_fibres_plane");
  const std::string apo = fascicle::test::data_path("bolsterlee_dti/TA_apo.stl").string();
  double length[3] = {0.0, 0.0, 0.0};
  const char* planes[3] = {"thickness", "gradient", "sheet-border"};
  for (int i = 0; i < 3; ++i) {
    const auto json = (dir / (std::string(planes[i]) + ".json")).string();
    const FibresCliRun r = run_fibres_cli(
        "--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --architecture bipennate "
        "--pennation-deg 9.6 --aponeurosis " + apo + " --method harmonic --pennation-plane " +
        planes[i] + " --count 40 --resolution 9 --out " + (dir / "f.vtp").string() +
        " --report " + json);
    ASSERT_EQ(r.code, 0) << r.out;
    std::ifstream in(json);
    const nlohmann::json j = nlohmann::json::parse(in);
    EXPECT_EQ(j["pennation_plane"].get<std::string>(), planes[i]);
    length[i] = j["mean_fibre_length_m"].get<double>();
    EXPECT_GT(length[i], 0.0683 * 0.75) << planes[i];
    EXPECT_LT(length[i], 0.0683 * 1.25) << planes[i];
  }
  EXPECT_GT(std::abs(length[0] - length[1]), 1e-4);
  EXPECT_GT(std::abs(length[0] - length[2]), 1e-4);
  // With the angle measured against the aponeuroses the default plane is their potential's
  // gradient (the thickness plane would replace their level sets by the box's plane).
  {
    const auto json = (dir / "reference.json").string();
    const FibresCliRun r = run_fibres_cli(
        "--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --architecture bipennate "
        "--pennation-deg 9.6 --aponeurosis " + apo + " --method harmonic --pennation-reference "
        "aponeurosis --count 40 --resolution 9 --out " + (dir / "f.vtp").string() + " --report " + json);
    ASSERT_EQ(r.code, 0) << r.out;
    std::ifstream in(json);
    EXPECT_EQ(nlohmann::json::parse(in)["pennation_plane"].get<std::string>(), "gradient");
  }
  // Refused where it does not apply (template method, no aponeurosis areas) and when unknown,
  // with a message naming the option.
  FibresCliRun r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis "
                                  "--pennation-deg 9.6 --pennation-plane thickness --out " +
                                  (dir / "f.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--pennation-plane"), std::string::npos) << r.out;
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --method harmonic --pennation-plane "
                     "thickness --out " + (dir / "f.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--pennation-plane"), std::string::npos) << r.out;
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --pennation-deg "
                     "9.6 --method harmonic --pennation-plane sideways --out " +
                     (dir / "f.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("pennation-plane"), std::string::npos) << r.out;
  // The sheet border needs the interior aponeurosis.
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --architecture "
                     "bipennate --pennation-deg 9.6 --method harmonic --pennation-plane sheet-border "
                     "--out " + (dir / "f.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--aponeurosis"), std::string::npos) << r.out;
  // ... and the line-of-action reference (against the aponeuroses it is documented as worse).
  r = run_fibres_cli("--mesh " + ta_mesh() + " --units mm --attachments aponeurosis --architecture "
                     "bipennate --pennation-deg 9.6 --aponeurosis " + apo + " --method harmonic "
                     "--pennation-reference aponeurosis --pennation-plane sheet-border --out " +
                     (dir / "f.vtp").string());
  EXPECT_EQ(r.code, 2) << r.out;
  EXPECT_NE(r.out.find("--pennation-reference line"), std::string::npos) << r.out;
}
