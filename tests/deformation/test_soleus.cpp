// The Visible Human female right soleus under an ankle-like rotation: volume held and no deeper
// penetration of the tibia and fibula than at rest.
#include "fascicle/deformation/surface_first.hpp"
#include "fascicle/io/mesh_io.hpp"

#include "test_support.hpp"

#include <gtest/gtest.h>

namespace fascicle {
namespace {

const std::string kDir = "visible_human_female/right/";

// Vertices with z in the lowest or highest `fraction` of the muscle's height.
std::vector<int> z_band(const TriMesh& m, double fraction, bool top) {
  const double z0 = m.V.col(2).minCoeff(), z1 = m.V.col(2).maxCoeff();
  std::vector<int> out;
  for (int i = 0; i < m.V.rows(); ++i) {
    const double t = (m.V(i, 2) - z0) / (z1 - z0);
    if (top ? t > 1.0 - fraction : t < fraction) out.push_back(i);
  }
  return out;
}

Vec3 centroid(const TriMesh& m, const std::vector<int>& idx) {
  Vec3 c = Vec3::Zero();
  for (int i : idx) c += m.V.row(i).transpose();
  return c / idx.size();
}

TEST(SurfaceFirstSoleus, AnkleRotationKeepsVolumeAndStaysOutOfShankBones) {
  const TriMesh soleus = read_mesh(test::data_path(kDir + "VHF_Right_Muscle_Soleus_smooth.stl"),
                                   LengthUnit::millimetre);
  const MeshQuery tibia(read_mesh(test::data_path(kDir + "VHF_Right_Bone_Tibia_smooth.stl"),
                                  LengthUnit::millimetre));
  const MeshQuery fibula(read_mesh(test::data_path(kDir + "VHF_Right_Bone_Fibula_smooth.stl"),
                                   LengthUnit::millimetre));
  ASSERT_GT(soleus.V.rows(), 10000);

  // origin: top 4% (rides on the shank); insertion: bottom 4% (rides on the foot)
  std::vector<SurfaceAttachment> areas{{"origin", z_band(soleus, 0.04, true)},
                                    {"insertion", z_band(soleus, 0.04, false)}};
  const Vec3 p_origin = centroid(soleus, areas[0].vertices);
  const Vec3 p_insertion = centroid(soleus, areas[1].vertices);
  Points3 rest_line(2, 3);
  rest_line << p_origin.transpose(), p_insertion.transpose();
  const BoneQueries bones{&tibia, &fibula};
  const SurfaceBinding b = bind_surface(soleus, rest_line, areas, bones, {}, "soleus_r");
  SurfaceFirstSolver solver(b, bones);

  // ankle axis: medio-lateral (x in the VH frame), through the talar dome (about z = 135 mm)
  const Vec3 ankle(0.588, 0.412, 0.135);
  for (double deg : {-15.0, -5.0, 10.0}) {
    Transform foot = Transform::Identity();
    foot.translate(ankle).rotate(Eigen::AngleAxisd(deg * M_PI / 180.0, Vec3::UnitX())).translate(-ankle);
    SurfaceFrameInput in;
    in.action_line = rest_line;
    in.action_line.row(1) = (foot * p_insertion).transpose();
    in.attachment_motions = {Transform::Identity(), foot};
    in.bone_motions = {Transform::Identity(), Transform::Identity()};
    const Points3& X = solver.calc_frame(in);
    const SurfaceFrameInfo& info = solver.get_info();
    EXPECT_LT(info.relative_volume_error, 1e-4) << deg << " deg";
    EXPECT_NEAR(calc_enclosed_volume(X, soleus.F, Vec3(0.6, 0.4, 0.3)) / b.rest_volume_m3, 1.0, 1e-4);
    for (int k = 0; k < 2; ++k) {
      const PenetrationInfo p = calc_bone_penetration(X, *bones[k], Transform::Identity(),
                                                      b.rest_bone_depth[k], b.fixed_vertices);
      EXPECT_LE(p.max_depth_beyond_rest_m, 0.5e-3) << deg << " deg, bone " << k;
    }
    // the insertion followed the foot
    const Vec3 moved = centroid(TriMesh{X, soleus.F}, areas[1].vertices);
    EXPECT_LT((moved - foot * p_insertion).norm(), 1e-12);
    std::printf("soleus %+5.1f deg: rel. volume error %.2e, %d solves, %d contact rounds, "
                "%d contacts, max depth beyond rest %.3f mm\n",
                deg, info.relative_volume_error, info.volume_iterations, info.contact_rounds,
                info.active_contacts, info.max_penetration_beyond_rest_m * 1e3);
  }
}

}  // namespace
}  // namespace fascicle
