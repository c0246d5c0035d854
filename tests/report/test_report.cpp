// The report module: viewer file encodings (round trips, quantisation bound, damaged input), the
// report writer on the demo leg (frame files match the State, incomplete runs, frame budget), the
// glTF export read back with Assimp, and the view server's path checks over real HTTP.
#include "fascicle/core/error.hpp"
#include "fascicle/report/gltf_export.hpp"
#include "fascicle/report/report.hpp"
#include "fascicle/report/view_server.hpp"
#include "fascicle/report/viewer_data.hpp"
#include "fascicle/scene/demo.hpp"
#include "fascicle/scene/driver.hpp"
#include "fascicle/scene/model.hpp"
#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/state.hpp"

#include "test_support.hpp"

#include <assimp/Importer.hpp>
#include <assimp/scene.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <random>
#include <sstream>
#include <thread>

namespace fs = std::filesystem;
using namespace fascicle;

namespace {

ViewerFrame make_random_frame(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-0.3, 0.5);
  ViewerFrame f;
  f.time_s = 0.125;
  Transform X = Transform::Identity();
  X.rotate(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized()));
  X.translation() = Vec3(0.1, -0.2, 0.3);
  f.X_ground_body = {X, Transform::Identity()};
  for (int m = 0; m < 3; ++m) {
    ViewerMuscleFrame mf;
    mf.surface = Points3::NullaryExpr(m == 1 ? 0 : 50 + m, 3, [&] { return u(rng); });
    mf.action_line = Points3::NullaryExpr(3, 3, [&] { return u(rng); });
    for (int k = 0; k < m; ++k) mf.fibres.push_back(Points3::NullaryExpr(4 + k, 3, [&] { return u(rng); }));
    mf.fibre_strain = VecX::NullaryExpr(m, [&] { return 0.1 * u(rng); });
    f.muscles.push_back(mf);
  }
  return f;
}

double max_position_error(const ViewerFrame& a, const ViewerFrame& b) {
  double e = 0;
  for (size_t m = 0; m < a.muscles.size(); ++m) {
    if (a.muscles[m].surface.rows()) e = std::max(e, (a.muscles[m].surface - b.muscles[m].surface).cwiseAbs().maxCoeff());
    e = std::max(e, (a.muscles[m].action_line - b.muscles[m].action_line).cwiseAbs().maxCoeff());
    for (size_t k = 0; k < a.muscles[m].fibres.size(); ++k)
      e = std::max(e, (a.muscles[m].fibres[k] - b.muscles[m].fibres[k]).cwiseAbs().maxCoeff());
  }
  return e;
}

std::string read_text(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}


// The demo leg, compiled once for the writer tests.
struct DemoRun {
  Model model;
  CoordinateTrajectory trajectory;
};
const DemoRun& get_demo() {
  static const DemoRun run = [] {
    const Registry registry = make_default_registry();
    const DemoScene demo = make_demo_leg(100.0, 1);
    DemoRun r{compile(demo.spec, registry), {}};
    r.trajectory = make_trajectory(r.model, demo.motion, 5.0);
    return r;
  }();
  return run;
}

}  // namespace

TEST(ViewerData, Float32FrameRoundTripIsExactToSinglePrecision) {
  std::mt19937 rng(7);
  const ViewerFrame f = make_random_frame(rng);
  const ViewerFrame g = decode_viewer_frame(encode_viewer_frame(f, PositionEncoding::float32));
  EXPECT_EQ(g.time_s, f.time_s);
  ASSERT_EQ(g.muscles.size(), 3u);
  EXPECT_EQ(g.muscles[1].surface.rows(), 0);
  EXPECT_EQ(g.muscles[2].fibres.size(), 2u);
  EXPECT_EQ(g.muscles[2].fibres[1].rows(), 5);
  EXPECT_LT(max_position_error(f, g), 0.5 * 6e-8);  // float32 rounding of |x| ≤ 0.5
  EXPECT_LT((g.X_ground_body[0].matrix() - f.X_ground_body[0].matrix()).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_LT((g.muscles[2].fibre_strain - f.muscles[2].fibre_strain).cwiseAbs().maxCoeff(), 1e-8);
}

TEST(ViewerData, Uint16QuantisationErrorIsWithinHalfAStep) {
  std::mt19937 rng(11);
  const ViewerFrame f = make_random_frame(rng);
  const ViewerBox box = calc_viewer_box(f);
  const double step = (box.hi - box.lo).maxCoeff() / 65535.0;
  const ViewerFrame g = decode_viewer_frame(encode_viewer_frame(f, PositionEncoding::uint16, box), box);
  const double e = max_position_error(f, g);
  EXPECT_LE(e, 0.5 * step * (1 + 1e-9));
  EXPECT_GT(e, 0.1 * step);  // it really is quantised (random points fall between steps)
  // Bounds of the box map exactly onto 0 and 65535.
  EXPECT_NEAR(g.muscles[0].surface.col(0).minCoeff(), f.muscles[0].surface.col(0).minCoeff(), 0.5 * step);
  // 2 bytes instead of 4 per coordinate.
  EXPECT_LT(encode_viewer_frame(f, PositionEncoding::uint16, box).size(),
            0.6 * encode_viewer_frame(f, PositionEncoding::float32).size());
}

TEST(ViewerData, NonFinitePositionsNeitherStretchTheBoxNorBreakTheEncoding) {
  std::mt19937 rng(5);
  ViewerFrame f = make_random_frame(rng);
  const ViewerBox finite = calc_viewer_box(f);
  ViewerFrame bad = f;
  bad.muscles[0].surface(3, 1) = std::numeric_limits<double>::quiet_NaN();
  bad.muscles[0].surface(4, 2) = std::numeric_limits<double>::infinity();
  const ViewerBox box = calc_viewer_box(bad);
  EXPECT_TRUE(box.lo.allFinite() && box.hi.allFinite());
  EXPECT_TRUE(((box.hi - box.lo).array() <= (finite.hi - finite.lo).array() + 1e-15).all());
  const ViewerFrame g = decode_viewer_frame(encode_viewer_frame(bad, PositionEncoding::uint16, box), box);
  EXPECT_TRUE(g.muscles[0].surface.allFinite());
  EXPECT_LT((g.muscles[1].action_line - f.muscles[1].action_line).cwiseAbs().maxCoeff(),
            (box.hi - box.lo).maxCoeff() / 65535.0);
}

TEST(ViewerData, MeshRoundTripAndDamagedFilesAreBadInput) {
  ViewerMesh mesh;
  mesh.body_vertices = {Points3::Random(6, 3)};
  mesh.body_triangles = {(Triangles(2, 3) << 0, 1, 2, 3, 4, 5).finished()};
  mesh.muscle_triangles = {Triangles(0, 3), (Triangles(1, 3) << 2, 1, 0).finished()};
  const std::string bytes = encode_viewer_mesh(mesh);
  const ViewerMesh back = decode_viewer_mesh(bytes);
  EXPECT_EQ(back.body_triangles[0], mesh.body_triangles[0]);
  EXPECT_EQ(back.muscle_triangles[1], mesh.muscle_triangles[1]);
  EXPECT_LT((back.body_vertices[0] - mesh.body_vertices[0]).cwiseAbs().maxCoeff(), 1e-7);
  EXPECT_THROW(decode_viewer_mesh(bytes.substr(0, bytes.size() - 3)), Error);
  EXPECT_THROW(decode_viewer_mesh("not a mesh at all"), Error);
  std::mt19937 rng(3);
  const std::string frame = encode_viewer_frame(make_random_frame(rng), PositionEncoding::float32);
  EXPECT_THROW(decode_viewer_frame(frame.substr(0, 40)), Error);
  std::string huge = frame;
  huge[20] = '\xff';  // a body count far beyond the bytes present
  huge[21] = '\xff';
  try {
    decode_viewer_frame(huge);
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
  }
}

TEST(ViewerData, Base64MatchesRfc4648Vectors) {
  EXPECT_EQ(encode_base64(""), "");
  EXPECT_EQ(encode_base64("f"), "Zg==");
  EXPECT_EQ(encode_base64("fo"), "Zm8=");
  EXPECT_EQ(encode_base64("foo"), "Zm9v");
  EXPECT_EQ(encode_base64("foob"), "Zm9vYg==");
  EXPECT_EQ(encode_base64("fooba"), "Zm9vYmE=");
  EXPECT_EQ(encode_base64("foobar"), "Zm9vYmFy");
  EXPECT_EQ(encode_base64(std::string("\xff\xfe\x00", 3)), "//4A");
}

TEST(ReportWriter, FrameFilesMatchTheStateAndTheReportEmbedsTheRun) {
  const DemoRun& demo = get_demo();
  const Model& model = demo.model;
  const fs::path out = test::scratch_dir("report_writer");
  auto writer = make_report_writer({.html_frame_budget_bytes = 24u << 20, .viewer_dir = {}});
  const int frames = 3;
  writer->begin(model, {out, "demo", frames, 5.0});
  State state = make_state(model);
  // What the frames held (State itself is not copyable).
  struct Kept {
    double time_s;
    std::vector<Transform> X_ground_body;
    std::vector<Points3> surfaces;
    std::vector<size_t> num_fibres;
    double musculotendon_length_m;
  };
  std::vector<Kept> states;
  for (int k = 0; k < frames; ++k) {
    state.time_s = demo.trajectory.time[k * 4];
    state.q = demo.trajectory.q.row(k * 4).transpose();
    state.stage = Stage::none;
    forward(model, state);
    writer->write_frame(model, state, k);
    Kept kept{state.time_s, state.X_ground_body, {}, {}, state.muscles[0].musculotendon_length_m};
    for (const MuscleFrame& mf : state.muscles) {
      kept.surfaces.push_back(mf.surface);
      kept.num_fibres.push_back(mf.fibres.size());
    }
    states.push_back(std::move(kept));
  }
  writer->finish(model);

  std::ifstream in(out / "viewer" / "manifest.json");
  const auto manifest = nlohmann::json::parse(in);
  EXPECT_EQ(manifest["frames_written"], frames);
  EXPECT_TRUE(manifest["complete"].get<bool>());
  ASSERT_EQ(manifest["muscles"].size(), static_cast<size_t>(model.num_muscles()));
  const auto& mt = manifest["muscles"][0]["metrics"]["musculotendon_length_m"];
  ASSERT_EQ(mt.size(), static_cast<size_t>(frames));
  EXPECT_NEAR(mt[2].get<double>(), states[2].musculotendon_length_m, 1e-12);

  // The last frame file holds the State's geometry (float32).
  const ViewerFrame f = decode_viewer_frame(read_text(out / "viewer" / "frames" / "00002.bin"));
  EXPECT_DOUBLE_EQ(f.time_s, states[2].time_s);
  int drawn = 0;
  for (int b = 1; b < model.num_bodies(); ++b) {
    if (model.bodies[b].mesh.V.rows() == 0) continue;
    EXPECT_LT((f.X_ground_body[drawn].matrix() - states[2].X_ground_body[b].matrix()).cwiseAbs().maxCoeff(), 1e-6);
    ++drawn;
  }
  EXPECT_EQ(static_cast<int>(f.X_ground_body.size()), drawn);
  EXPECT_GE(drawn, 4);
  for (int m = 0; m < model.num_muscles(); ++m) {
    const Points3& surface = states[2].surfaces[m];
    ASSERT_EQ(f.muscles[m].surface.rows(), surface.rows());
    if (surface.rows()) {
      EXPECT_LT((f.muscles[m].surface - surface).cwiseAbs().maxCoeff(), 1e-6);
    }
    EXPECT_EQ(f.muscles[m].fibres.size(), states[2].num_fibres[m]);
  }

  const std::string html = read_text(out / "report.html");
  EXPECT_NE(html.find("id=\"fascicle-manifest\""), std::string::npos);
  size_t embedded = 0;
  for (size_t at = html.find("class=\"fascicle-frame\""); at != std::string::npos;
       at = html.find("class=\"fascicle-frame\"", at + 1))
    ++embedded;
  EXPECT_EQ(embedded, static_cast<size_t>(frames));
}

TEST(ReportWriter, IncompleteRunAndFrameBudgetAreStatedInTheManifest) {
  const DemoRun& demo = get_demo();
  const Model& model = demo.model;
  const fs::path out = test::scratch_dir("report_incomplete");
  // A budget of a single byte keeps only the first and last frame.
  // A summary.json left by an earlier run is not embedded.
  std::ofstream(out / "summary.json") << "{\"stale\": true}";
  fs::last_write_time(out / "summary.json", fs::file_time_type::clock::now() - std::chrono::hours(1));
  auto writer = make_report_writer({.html_frame_budget_bytes = 1, .viewer_dir = {}});
  writer->begin(model, {out, "demo", 10, 5.0});
  State state = make_state(model);
  for (int k = 0; k < 4; ++k) {
    state.time_s = demo.trajectory.time[k];
    state.q = demo.trajectory.q.row(k).transpose();
    state.stage = Stage::none;
    forward(model, state);
    writer->write_frame(model, state, k);
  }
  writer->finish(model);  // as after a failure at frame 4
  std::ifstream in(out / "viewer" / "manifest.json");
  const auto manifest = nlohmann::json::parse(in);
  EXPECT_FALSE(manifest["complete"].get<bool>());
  EXPECT_FALSE(manifest.contains("summary"));
  // Each drawn body carries its default pose (column-major 4×4) for pages with no frame.
  for (const auto& jb : manifest["bodies"]) {
    const BodyIndex b = model.find_body(jb["name"].get<std::string>());
    ASSERT_TRUE(b.v > 0);
    const auto X = jb["X_ground_default"].get<std::vector<double>>();
    ASSERT_EQ(X.size(), 16u);
    EXPECT_LT((Eigen::Map<const Mat4>(X.data()) - model.X_ground_body_default[b.v].matrix()).cwiseAbs().maxCoeff(),
              1e-15);
  }
  EXPECT_EQ(manifest["frames_expected"], 10);
  EXPECT_EQ(manifest["frames_written"], 4);
  const std::string html = read_text(out / "report.html");
  EXPECT_NE(html.find("\"frame_indices\":[0,2,3]"), std::string::npos) << html.substr(0, 300);
  EXPECT_NE(html.find("\"subsampled\":true"), std::string::npos);
  EXPECT_NE(html.find("\"complete\":false"), std::string::npos);
}

TEST(GltfExport, DemoFrameReadsBackWithAssimp) {
  const DemoRun& demo = get_demo();
  const Model& model = demo.model;
  const fs::path out = test::scratch_dir("report_gltf");
  auto writer = make_report_writer();
  writer->begin(model, {out, "demo", 2, 5.0});
  State state = make_state(model);
  for (int k = 0; k < 2; ++k) {
    state.time_s = demo.trajectory.time[k];
    state.q = demo.trajectory.q.row(k).transpose();
    state.stage = Stage::none;
    forward(model, state);
    writer->write_frame(model, state, k);
  }
  writer->finish(model);

  const GltfExportCounts c = export_gltf_frame(out, 1, out / "scene.glb");
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile((out / "scene.glb").string(), 0);
  ASSERT_NE(scene, nullptr) << importer.GetErrorString();
  EXPECT_EQ(static_cast<int>(scene->mNumMeshes), c.bones + c.muscles + c.fibre_sets + c.action_lines);
  EXPECT_GE(c.bones, 4);
  EXPECT_EQ(c.action_lines, model.num_muscles());
  int lines = 0, triangles = 0;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    if (scene->mMeshes[i]->mPrimitiveTypes & aiPrimitiveType_LINE) ++lines;
    if (scene->mMeshes[i]->mPrimitiveTypes & aiPrimitiveType_TRIANGLE) ++triangles;
  }
  EXPECT_EQ(lines, c.fibre_sets + c.action_lines);
  EXPECT_EQ(triangles, c.bones + c.muscles);
  // The first muscle's action line starts at the State's origin point.
  const std::string name = "action_line_" + model.muscles[0].name;
  bool found = false;
  for (unsigned i = 0; i < scene->mNumMeshes; ++i) {
    const aiMesh* mesh = scene->mMeshes[i];
    if (name != mesh->mName.C_Str()) continue;
    found = true;
    const Vec3 p0(mesh->mVertices[0].x, mesh->mVertices[0].y, mesh->mVertices[0].z);
    EXPECT_LT((p0 - state.muscles[0].action_line.row(0).transpose()).norm(), 1e-6);
  }
  EXPECT_TRUE(found) << name;

  try {
    export_gltf_frame(out, 2, out / "bad.glb");
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("out of range"), std::string::npos) << e.what();
  }
  EXPECT_THROW(export_gltf_frame(test::scratch_dir("report_gltf_empty"), 0, out / "x.glb"), Error);
}

TEST(ViewServer, ResolvesOnlyFilesBelowTheRunFolder) {
  const fs::path root = test::scratch_dir("view_resolve");
  fs::create_directories(root / "run" / "viewer");
  std::ofstream(root / "run" / "viewer" / "manifest.json") << "{}";
  std::ofstream(root / "secret.txt") << "secret";
  fs::create_symlink(root / "secret.txt", root / "run" / "link.txt");
  const fs::path run = root / "run";
  EXPECT_EQ(resolve_run_path(run, "/run/viewer/manifest.json").status, 200);
  EXPECT_EQ(resolve_run_path(run, "/run/../secret.txt").status, 403);
  EXPECT_EQ(resolve_run_path(run, "/run/viewer/../../secret.txt").status, 403);
  EXPECT_EQ(resolve_run_path(run, "/run/./viewer/manifest.json").status, 403);
  EXPECT_EQ(resolve_run_path(run, "/run//etc/passwd").status, 403);
  EXPECT_EQ(resolve_run_path(run, "/run/..\\secret.txt").status, 403);
  EXPECT_EQ(resolve_run_path(run, "/run/link.txt").status, 403);  // symbolic link out of the folder
  EXPECT_EQ(resolve_run_path(run, "/run/viewer").status, 404);    // a folder
  EXPECT_EQ(resolve_run_path(run, "/run/missing.bin").status, 404);
  EXPECT_EQ(resolve_run_path(run, "/secret.txt").status, 404);
}

TEST(ViewServer, ServesOverHttpRejectsTraversalAndReportsABusyPort) {
  const fs::path root = test::scratch_dir("view_http");
  fs::create_directories(root / "run" / "viewer");
  std::ofstream(root / "run" / "viewer" / "manifest.json") << "{\"format\":\"fascicle-viewer\"}";
  std::ofstream(root / "secret.txt") << "secret";
  ViewServer server({.run_dir = root / "run", .viewer_dir = {}, .port = 0});
  const int port = server.get_port();
  ASSERT_GT(port, 0);
  EXPECT_EQ(server.get_url(), "http://127.0.0.1:" + std::to_string(port) + "/");
  std::thread serving([&] { server.serve(30.0); });
  std::string body;
  int status = -1;
  for (int attempt = 0; attempt < 100 && status != 200; ++attempt) {
    status = test::http_get(port, "/run/viewer/manifest.json", &body);
    if (status != 200) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  EXPECT_EQ(status, 200);
  EXPECT_EQ(body, "{\"format\":\"fascicle-viewer\"}");
  EXPECT_EQ(test::http_get(port, "/", &body), 200);
  EXPECT_NE(body.find("<html"), std::string::npos);
  EXPECT_EQ(test::http_get(port, "/run/../secret.txt", &body), 403);
  EXPECT_EQ(body.find("secret"), std::string::npos);
  EXPECT_EQ(test::http_get(port, "/run/%2e%2e/secret.txt"), 403);
  EXPECT_EQ(test::http_get(port, "/../secret.txt"), 404);
  EXPECT_EQ(test::http_get(port, "/run/nothing"), 404);
  // The port is taken now: a second server on it is a clear bad-input error.
  try {
    ViewServer second({.run_dir = root / "run", .viewer_dir = {}, .port = port});
    FAIL() << "no error";
  } catch (const Error& e) {
    EXPECT_EQ(e.kind(), ErrorKind::bad_input);
    EXPECT_NE(std::string(e.what()).find("in use"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ViewServer({.run_dir = root / "missing", .viewer_dir = {}, .port = 0}), Error);
  server.stop();
  serving.join();
}
