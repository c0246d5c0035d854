// glTF 2.0 binary (.glb) of one frame of a run, from the viewer data the "report" writer wrote
// (OUT/viewer/manifest.json, mesh.bin, frames/*.bin), through Assimp's "glb2" exporter.
// Bones and muscle surfaces are triangle meshes (bones opaque, muscles translucent with their
// viewer colour), fibres and action lines are line meshes. Ground frame, m (glTF's unit).
#pragma once

#include <filesystem>

namespace fascicle {

struct GltfExportCounts {
  int bones = 0;
  int muscles = 0;        // surfaces
  int fibre_sets = 0;     // one line mesh per muscle with fibres
  int action_lines = 0;
};

// Writes frame `frame` (0-based, of the frames written) of the run in `run_dir` to `out`
// atomically. Throws fascicle::Error: bad input when the folder is not a run written with the
// report writer, or the frame is out of range or missing (the message says which).
GltfExportCounts export_gltf_frame(const std::filesystem::path& run_dir, int frame,
                                   const std::filesystem::path& out);

}  // namespace fascicle
