// One frame of a run as glTF 2.0 binary through Assimp's "glb2" exporter.
#include "fascicle/report/gltf_export.hpp"

#include "fascicle/core/atomic_file.hpp"
#include "fascicle/core/error.hpp"
#include "fascicle/report/viewer_data.hpp"

#include <assimp/Exporter.hpp>
#include <assimp/material.h>
#include <assimp/scene.h>
#include <nlohmann/json.hpp>

#include <fstream>
#include <memory>
#include <sstream>

namespace fascicle {
namespace {

namespace fs = std::filesystem;

std::string read_bytes(const fs::path& path, const std::string& what) {
  std::ifstream in(path, std::ios::binary);
  if (!in)
    throw_bad_input(what + " '" + path.string() + "' is missing",
                    {.file = path.string(), .suggestion = "write the run again with the report writer"});
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

aiMaterial* make_material(const std::string& name, const aiColor4D& colour) {
  auto* mat = new aiMaterial();
  const aiString ai_name(name);
  mat->AddProperty(&ai_name, AI_MATKEY_NAME);
  mat->AddProperty(&colour, 1, AI_MATKEY_BASE_COLOR);
  const aiColor3D diffuse(colour.r, colour.g, colour.b);
  mat->AddProperty(&diffuse, 1, AI_MATKEY_COLOR_DIFFUSE);
  const float opacity = colour.a;
  mat->AddProperty(&opacity, 1, AI_MATKEY_OPACITY);
  const int two_sided = colour.a < 1.0f ? 1 : 0;
  mat->AddProperty(&two_sided, 1, AI_MATKEY_TWOSIDED);
  return mat;
}

// Builds aiScene contents; the scene owns everything it points to once added.
class SceneBuilder {
 public:
  unsigned add_material(aiMaterial* m) {
    materials_.push_back(m);
    return static_cast<unsigned>(materials_.size() - 1);
  }

  void add_triangles(const std::string& name, const Points3& V, const Triangles& F, unsigned material) {
    auto* mesh = new aiMesh();
    mesh->mName = aiString(name);
    mesh->mPrimitiveTypes = aiPrimitiveType_TRIANGLE;
    mesh->mMaterialIndex = material;
    set_vertices(mesh, V);
    mesh->mNumFaces = static_cast<unsigned>(F.rows());
    mesh->mFaces = new aiFace[F.rows()];
    for (Eigen::Index i = 0; i < F.rows(); ++i) {
      for (int k = 0; k < 3; ++k)
        if (F(i, k) < 0 || F(i, k) >= V.rows())
          throw_bad_input("mesh '" + name + "' has a triangle index out of range",
                          {.suggestion = "write the run again"});
      set_face(mesh->mFaces[i], {static_cast<unsigned>(F(i, 0)), static_cast<unsigned>(F(i, 1)),
                                  static_cast<unsigned>(F(i, 2))});
    }
    add_mesh(mesh);
  }

  // Polylines as line segments.
  void add_lines(const std::string& name, const std::vector<Points3>& polylines, unsigned material) {
    long n = 0, segments = 0;
    for (const Points3& p : polylines) {
      n += p.rows();
      segments += std::max<long>(0, p.rows() - 1);
    }
    if (segments == 0) return;
    Points3 V(n, 3);
    auto* mesh = new aiMesh();
    mesh->mName = aiString(name);
    mesh->mPrimitiveTypes = aiPrimitiveType_LINE;
    mesh->mMaterialIndex = material;
    mesh->mNumFaces = static_cast<unsigned>(segments);
    mesh->mFaces = new aiFace[segments];
    long at = 0, s = 0;
    for (const Points3& p : polylines) {
      V.middleRows(at, p.rows()) = p;
      for (long i = 0; i + 1 < p.rows(); ++i)
        set_face(mesh->mFaces[s++], {static_cast<unsigned>(at + i), static_cast<unsigned>(at + i + 1)});
      at += p.rows();
    }
    set_vertices(mesh, V);
    add_mesh(mesh);
  }

  std::unique_ptr<aiScene> take(const std::string& root_name) {
    auto scene = std::make_unique<aiScene>();
    scene->mRootNode = new aiNode(root_name);
    scene->mNumMaterials = static_cast<unsigned>(materials_.size());
    scene->mMaterials = new aiMaterial*[materials_.size()];
    for (size_t i = 0; i < materials_.size(); ++i) scene->mMaterials[i] = materials_[i];
    materials_.clear();
    scene->mNumMeshes = static_cast<unsigned>(meshes_.size());
    scene->mMeshes = new aiMesh*[meshes_.size()];
    scene->mRootNode->mNumChildren = static_cast<unsigned>(meshes_.size());
    scene->mRootNode->mChildren = new aiNode*[meshes_.size()];
    for (size_t i = 0; i < meshes_.size(); ++i) {
      scene->mMeshes[i] = meshes_[i];
      auto* node = new aiNode(meshes_[i]->mName.C_Str());
      node->mParent = scene->mRootNode;
      node->mNumMeshes = 1;
      node->mMeshes = new unsigned[1]{static_cast<unsigned>(i)};
      scene->mRootNode->mChildren[i] = node;
    }
    meshes_.clear();
    return scene;
  }

  ~SceneBuilder() {
    for (aiMaterial* m : materials_) delete m;
    for (aiMesh* m : meshes_) delete m;
  }

 private:
  static void set_vertices(aiMesh* mesh, const Points3& V) {
    mesh->mNumVertices = static_cast<unsigned>(V.rows());
    mesh->mVertices = new aiVector3D[V.rows()];
    for (Eigen::Index i = 0; i < V.rows(); ++i)
      mesh->mVertices[i] = aiVector3D(static_cast<float>(V(i, 0)), static_cast<float>(V(i, 1)),
                                      static_cast<float>(V(i, 2)));
  }
  static void set_face(aiFace& face, std::initializer_list<unsigned> indices) {
    face.mNumIndices = static_cast<unsigned>(indices.size());
    face.mIndices = new unsigned[indices.size()];
    std::copy(indices.begin(), indices.end(), face.mIndices);
  }
  void add_mesh(aiMesh* mesh) { meshes_.push_back(mesh); }

  std::vector<aiMaterial*> materials_;
  std::vector<aiMesh*> meshes_;
};

}  // namespace

GltfExportCounts export_gltf_frame(const fs::path& run_dir, int frame, const fs::path& out) {
  const fs::path manifest_path = run_dir / "viewer" / "manifest.json";
  nlohmann::json manifest;
  {
    std::ifstream in(manifest_path);
    if (!in)
      throw_bad_input("'" + run_dir.string() + "' is not a fascicle run: viewer/manifest.json is missing",
                      {.file = manifest_path.string(),
                       .suggestion = "give the output folder of `fascicle run` or `fascicle demo` (report "
                                     "writer)"});
    try {
      manifest = nlohmann::json::parse(in);
    } catch (const nlohmann::json::exception& e) {
      throw_bad_input(std::string("manifest is not valid JSON: ") + e.what(), {.file = manifest_path.string()});
    }
  }
  try {
    const auto& files = manifest.at("frame_files");
    const int frames = static_cast<int>(files.size());
    if (frame < 0 || frame >= frames)
      throw_bad_input("frame " + std::to_string(frame) + " is out of range: the run has " +
                          std::to_string(frames) + " frames",
                      {.file = manifest_path.string(),
                       .suggestion = frames > 0 ? "use --frame 0…" + std::to_string(frames - 1)
                                                : std::string("the run wrote no frame")});
    const ViewerMesh mesh = decode_viewer_mesh(read_bytes(run_dir / "viewer" / "mesh.bin", "mesh file"),
                                               (run_dir / "viewer" / "mesh.bin").string());
    const fs::path frame_path = run_dir / "viewer" / files[frame].get<std::string>();
    const ViewerFrame vf = decode_viewer_frame(read_bytes(frame_path, "frame file"), {}, frame_path.string());
    const auto& bodies = manifest.at("bodies");
    const auto& muscles = manifest.at("muscles");
    if (vf.X_ground_body.size() != bodies.size() || mesh.body_vertices.size() != bodies.size() ||
        vf.muscles.size() != muscles.size() || mesh.muscle_triangles.size() != muscles.size())
      throw_bad_input("the viewer files of '" + run_dir.string() + "' disagree with its manifest",
                      {.file = manifest_path.string(), .suggestion = "write the run again"});

    SceneBuilder builder;
    GltfExportCounts counts;
    const unsigned bone_mat = builder.add_material(make_material("bone", aiColor4D(0.89f, 0.86f, 0.79f, 1.0f)));
    for (size_t b = 0; b < bodies.size(); ++b) {
      const Transform& X = vf.X_ground_body[b];
      const Points3 V = ((mesh.body_vertices[b] * X.linear().transpose()).rowwise() +
                         X.translation().transpose()).eval();
      builder.add_triangles("bone_" + bodies[b].at("name").get<std::string>(), V, mesh.body_triangles[b],
                            bone_mat);
      ++counts.bones;
    }
    for (size_t m = 0; m < muscles.size(); ++m) {
      const std::string name = muscles[m].at("name").get<std::string>();
      const auto c = muscles[m].at("color");
      const aiColor4D colour(c[0].get<float>(), c[1].get<float>(), c[2].get<float>(), 0.55f);
      const ViewerMuscleFrame& mf = vf.muscles[m];
      if (mf.surface.rows() > 0 && mesh.muscle_triangles[m].rows() > 0) {
        builder.add_triangles("muscle_" + name, mf.surface, mesh.muscle_triangles[m],
                              builder.add_material(make_material("muscle_" + name, colour)));
        ++counts.muscles;
      }
      if (!mf.fibres.empty()) {
        const aiColor4D fibre(0.5f + 0.5f * colour.r, 0.5f + 0.5f * colour.g, 0.5f + 0.5f * colour.b, 1.0f);
        builder.add_lines("fibres_" + name, mf.fibres, builder.add_material(make_material("fibres_" + name, fibre)));
        ++counts.fibre_sets;
      }
      if (mf.action_line.rows() >= 2) {
        builder.add_lines("action_line_" + name, {mf.action_line},
                          builder.add_material(make_material("action_line_" + name, aiColor4D(0.1f, 0.1f, 0.1f, 1.0f))));
        ++counts.action_lines;
      }
    }
    const std::unique_ptr<aiScene> scene = builder.take(manifest.value("scene", std::string("fascicle")));
    write_via_temporary(out, [&](const fs::path& tmp) {
      Assimp::Exporter exporter;
      if (exporter.Export(scene.get(), "glb2", tmp.string()) != AI_SUCCESS)
        throw_internal(std::string("glTF export failed: ") + exporter.GetErrorString());
    });
    return counts;
  } catch (const nlohmann::json::exception& e) {
    throw_bad_input(std::string("manifest is incomplete: ") + e.what(),
                    {.file = manifest_path.string(), .suggestion = "write the run again"});
  }
}

}  // namespace fascicle
