// The data files of the browser viewer (docs/viewer.md): a static mesh file (bones in their body
// frames, muscle triangles) and one binary file per frame (body poses, muscle surfaces, action
// lines, fibres and fibre strains in ground), described by a JSON manifest. The same encoding is
// embedded in report.html (base64), there with positions quantised to 16 bits in a bounding box.
// All lengths in m; little-endian; the JavaScript decoder is viewer/src/data.ts.
#pragma once

#include "fascicle/core/types.hpp"

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace fascicle {

// Axis-aligned box of the positions quantised in a frame (ground frame, m).
struct ViewerBox {
  Vec3 lo = Vec3::Zero();
  Vec3 hi = Vec3::Zero();
};

enum class PositionEncoding : uint32_t { float32 = 0, uint16 = 1 };

struct ViewerMuscleFrame {
  Points3 surface;               // #V×3, rows match the muscle's triangles' vertices (0 rows: none)
  Points3 action_line;           // origin, via points, insertion
  std::vector<Points3> fibres;   // polylines
  VecX fibre_strain;             // per fibre: length / rest length − 1 (may be empty)
};

// One frame as the viewer draws it.
struct ViewerFrame {
  double time_s = 0.0;
  std::vector<Transform> X_ground_body;  // per drawn body (those with a mesh), in manifest order
  std::vector<ViewerMuscleFrame> muscles;
};

// Static geometry: bones in their body frames, muscle triangles (indices into the surface rows).
struct ViewerMesh {
  std::vector<Points3> body_vertices;    // per drawn body, body frame
  std::vector<Triangles> body_triangles;
  std::vector<Triangles> muscle_triangles;  // per muscle (0 rows for line-only muscles)
};

// Bytes of one frame ("FVF1" layout, docs/viewer.md). uint16 positions map [lo, hi] of `box`
// linearly onto 0…65535 per axis (error ≤ (hi − lo)/131070 per axis); `box` must contain them.
std::string encode_viewer_frame(const ViewerFrame& frame, PositionEncoding encoding,
                                const ViewerBox& box = {});
// Inverse of encode_viewer_frame; throws fascicle::Error (bad input, naming `what`) on bytes that
// are not a valid frame.
ViewerFrame decode_viewer_frame(std::string_view bytes, const ViewerBox& box = {},
                                const std::string& what = "frame");

std::string encode_viewer_mesh(const ViewerMesh& mesh);
ViewerMesh decode_viewer_mesh(std::string_view bytes, const std::string& what = "mesh");

// The box of every position of a frame (empty frame: zero box).
ViewerBox calc_viewer_box(const ViewerFrame& frame);
// The union of two boxes, and a box grown so that each side is at least `min_extent_m`.
ViewerBox merge_boxes(const ViewerBox& a, const ViewerBox& b);
ViewerBox pad_box(const ViewerBox& box, double min_extent_m);

// Standard base64 (RFC 4648, with padding).
std::string encode_base64(std::string_view bytes);

}  // namespace fascicle
