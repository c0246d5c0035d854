// `fascicle view` and `fascicle export --gltf` end to end: the demo's report.html and viewer files,
// the .glb read back with Assimp, traversal requests against the running server, a busy port and
// folders that are not runs.
#include "test_support.hpp"

#include <assimp/Importer.hpp>
#include <assimp/scene.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <regex>
#include <sstream>
#include <thread>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

int run_cli(const std::string& args, std::string* output = nullptr) {
  const auto r = test::run_command(std::string(FASCICLE_CLI_PATH) + " " + args + " 2>&1");
  if (output) *output = r.output;
  return r.exit_code;
}

// The demo at 10 Hz (21 frames), written once for this program.
const fs::path& get_demo_dir() {
  static const fs::path dir = [] {
    const fs::path d = test::scratch_dir("cli_view_demo") / "demo";
    std::string out;
    if (run_cli("--quiet --threads 2 demo --out " + d.string() + " --fps 10", &out) != 0)
      ADD_FAILURE() << "fascicle demo failed: " << out;
    return d;
  }();
  return dir;
}


}  // namespace

TEST(CliView, DemoWritesReportHtmlAndViewerFiles) {
  const fs::path& demo = get_demo_dir();
  ASSERT_TRUE(fs::exists(demo / "report.html"));
  std::ifstream in(demo / "viewer" / "manifest.json");
  const auto manifest = nlohmann::json::parse(in);
  EXPECT_EQ(manifest["frames_written"], 21);
  EXPECT_TRUE(manifest["complete"].get<bool>());
  EXPECT_EQ(manifest["muscles"].size(), 4u);
  EXPECT_EQ(manifest["bodies"].size(), 6u);
  EXPECT_TRUE(fs::exists(demo / "viewer" / "frames" / "00020.bin"));
  EXPECT_EQ(manifest["summary"]["frames"], 21);  // this run's summary.json, embedded
  // Self-contained: no external script or style sheet, and well under 20 MB for the demo.
  std::ifstream html_in(demo / "report.html");
  std::stringstream html;
  html << html_in.rdbuf();
  EXPECT_EQ(html.str().find("<script src="), std::string::npos);
  EXPECT_EQ(html.str().find("<link "), std::string::npos);
  EXPECT_LT(fs::file_size(demo / "report.html"), 20u << 20);
}

TEST(CliView, ExportGltfOfTheDemoReadsBackWithAssimp) {
  const fs::path& demo = get_demo_dir();
  const fs::path glb = test::scratch_dir("cli_view_export") / "scene.glb";
  std::string out;
  ASSERT_EQ(run_cli("export --gltf " + demo.string() + " --frame 20 --out " + glb.string(), &out), 0) << out;
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(glb.string(), 0);
  ASSERT_NE(scene, nullptr) << importer.GetErrorString();
  int bones = 0, muscles = 0, fibres = 0, action_lines = 0;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    const std::string name = scene->mMeshes[i]->mName.C_Str();
    const bool lines = scene->mMeshes[i]->mPrimitiveTypes & aiPrimitiveType_LINE;
    if (name.rfind("bone_", 0) == 0 && !lines) ++bones;
    if (name.rfind("muscle_", 0) == 0 && !lines) ++muscles;
    if (name.rfind("fibres_", 0) == 0 && lines) ++fibres;
    if (name.rfind("action_line_", 0) == 0 && lines) ++action_lines;
  }
  EXPECT_EQ(bones, 6);
  EXPECT_EQ(muscles, 4);
  EXPECT_EQ(fibres, 4);
  EXPECT_EQ(action_lines, 4);
  EXPECT_EQ(run_cli("export --gltf " + demo.string() + " --frame 21 --out " + glb.string(), &out), 3);
  EXPECT_NE(out.find("out of range"), std::string::npos) << out;
  EXPECT_EQ(run_cli("export --gltf " + test::scratch_dir("cli_view_empty").string() + " --out " + glb.string(), &out), 3);
  EXPECT_NE(out.find("not a fascicle run"), std::string::npos) << out;
}

TEST(CliView, ServesOnLoopbackAndRefusesTraversal) {
  const fs::path& demo = get_demo_dir();
  std::ofstream(demo.parent_path() / "secret.txt") << "do not serve";
  const std::string cmd = std::string(FASCICLE_CLI_PATH) + " view " + demo.string() + " --port 0 --max-seconds 6";
  FILE* pipe = ::popen(cmd.c_str(), "r");
  ASSERT_NE(pipe, nullptr);
  char line[512] = {0};
  ASSERT_NE(std::fgets(line, sizeof line, pipe), nullptr);
  std::smatch m;
  const std::string first(line);
  ASSERT_TRUE(std::regex_search(first, m, std::regex(R"(http://127\.0\.0\.1:(\d+)/)"))) << first;
  const int port = std::stoi(m[1]);
  std::string body;
  EXPECT_EQ(test::http_get(port, "/run/viewer/manifest.json", &body), 200);
  EXPECT_NE(body.find("fascicle-viewer"), std::string::npos);
  EXPECT_EQ(test::http_get(port, "/", &body), 200);
  for (const char* p : {"/run/../secret.txt", "/run/viewer/../../secret.txt", "/../secret.txt",
                        "/run/%2e%2e/secret.txt", "/run/..%2fsecret.txt", "/run/../../../../etc/passwd"}) {
    const int status = test::http_get(port, p, &body);
    EXPECT_TRUE(status == 403 || status == 404) << p << " → " << status;
    EXPECT_EQ(body.find("do not serve"), std::string::npos) << p;
    EXPECT_EQ(body.find("root:"), std::string::npos) << p;
  }
  // Listening on 127.0.0.1 only: the kernel's socket table shows the port on 0100007F and nowhere else.
  {
    std::ifstream tcp("/proc/net/tcp");
    char hex_port[8];
    std::snprintf(hex_port, sizeof hex_port, "%04X", port);
    int listening = 0;
    for (std::string row; std::getline(tcp, row);) {
      std::istringstream fields(row);
      std::string slot, local, remote, state;
      fields >> slot >> local >> remote >> state;
      if (state != "0A" || local.size() < 13 || local.substr(9) != hex_port) continue;  // 0A = LISTEN
      ++listening;
      EXPECT_EQ(local.substr(0, 8), "0100007F") << row;
    }
    EXPECT_EQ(listening, 1);
  }
  std::string busy;
  EXPECT_EQ(run_cli("view " + demo.string() + " --port " + std::to_string(port) + " --max-seconds 1", &busy), 3);
  EXPECT_NE(busy.find("in use"), std::string::npos) << busy;
  ::pclose(pipe);  // waits for --max-seconds
}

TEST(CliView, NotAFolderIsBadInput) {
  std::string out;
  EXPECT_EQ(run_cli("view " + (test::scratch_dir("cli_view_missing") / "nope").string() + " --port 0 --max-seconds 1", &out), 3);
  EXPECT_NE(out.find("is not a folder"), std::string::npos) << out;
  EXPECT_EQ(run_cli("view", &out), 2);
}
