// Attachment areas: the parts of a muscle's surface where its fibres start (origin) and end
// (insertion). Areas are vertex sets of the muscle's TriMesh; their triangles are the faces whose
// three vertices all belong to the set. See docs/fibres.md.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"

#include <cmath>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace fascicle {

struct AttachmentArea {
  std::string name;              // "origin", "insertion" (used in messages)
  std::vector<int> vertices;     // sorted vertex indices of the muscle mesh
  std::vector<int> triangles;    // faces with all three vertices in `vertices`
  double area_m2 = 0.0;          // total area of `triangles`
  Vec3 centroid = Vec3::Zero();  // area-weighted centroid of `triangles` (vertex mean if none)
  Vec3 normal = Vec3::Zero();    // unit area-weighted mean outward normal (zero if none)
};

// The pair of areas used for a decomposition.
struct Attachments {
  AttachmentArea origin;
  AttachmentArea insertion;
  // Points (metres, #N x 3) sampling an insertion aponeurosis inside the muscle (a central sheet,
  // or a segmented aponeurosis such as the tibialis anterior's); empty when the insertion is on
  // the surface only. The harmonic method holds u = 1 there; the template method ignores it.
  Points3 insertion_interior = Points3(0, 3);
  // Unipennate aponeurosis areas only (find_aponeurosis_attachments): every vertex of the -x and
  // of the +x face, over the whole length. Their potential (0 on -x, 1 on +x) has level sets
  // parallel to both faces, the reference of HarmonicOptions::PennationReference::aponeurosis.
  // Empty otherwise.
  std::vector<int> face_minus, face_plus;
  // Aponeurosis areas only (find_aponeurosis_attachments): the box's thickness direction x (unit,
  // towards the insertion face for unipennate areas), e.g. for HarmonicOptions::
  // transverse_direction. Zero otherwise.
  Vec3 thickness_direction = Vec3::Zero();
};

// Builds an area from vertex indices (duplicates removed). Throws bad_input when the set is empty
// or an index is out of range (naming the area).
AttachmentArea make_attachment_area(const TriMesh& muscle, std::vector<int> vertices,
                                    const std::string& name);

// Checks a pair of areas: both non-empty with at least one triangle each, and disjoint (throws
// bad_input naming the shared vertex count otherwise).
void check_attachments(const TriMesh& muscle, const Attachments& areas);

// The muscle's principal axis (unit, largest variance of the vertices, area-weighted), oriented so
// the origin end is towards +z of the mesh frame (proximal in the z-up Visible Human and MRI
// frames) unless `origin_towards` is given.
Vec3 calc_principal_axis(const TriMesh& muscle, const Vec3& origin_towards = Vec3::UnitZ());

// The two end regions along the principal axis: vertices whose position along the axis is within
// `fraction` (0 < fraction < 0.5) of the muscle's extent from each end. For bellies without
// tendons (Visible Human). Origin is the end towards `origin_towards`.
Attachments find_end_attachments(const TriMesh& muscle, double fraction = 0.08,
                                 const Vec3& origin_towards = Vec3::UnitZ());

// Areas from landmark point clouds (metres): each landmark is projected onto the muscle surface;
// the area is the vertices within `radius` of a projected landmark (radius <= 0: 1.5 times the
// median nearest-neighbour spacing of the landmarks, at least the mean edge length).
// Throws bad_input when a landmark lies farther than `max_offset` from the surface (landmarks of
// another muscle) or the areas overlap.
Attachments find_landmark_attachments(const TriMesh& muscle, const Points3& origin_landmarks,
                                      const Points3& insertion_landmarks, double radius = 0.0,
                                      double max_offset = 0.01);

// Areas from bones: the muscle vertices within `distance` of any bone surface.
// With `split_by_bone` the origin is the contact with bones[0] and the insertion the contact with
// the other bones; otherwise the contact region is split at the middle of the principal axis, and
// a side without contact falls back to its end region (find_end_attachments with `end_fraction`).
// Throws bad_input when no muscle vertex lies within `distance` of any bone.
Attachments find_bone_attachments(const TriMesh& muscle, const std::vector<TriMesh>& bones,
                                  double distance, bool split_by_bone = false,
                                  double end_fraction = 0.08,
                                  const Vec3& origin_towards = Vec3::UnitZ());

// Bone areas with anatomical roles (find_bone_role_attachments).
struct BoneRoleOptions {
  double distance = 0.002;     // a muscle vertex within this distance of a bone touches it (m)
  double end_fraction = 0.08;  // end region of a side whose bones the belly does not touch
  // A bone contact counts only within this fraction of the principal axis from its own end
  // (1: anywhere). Anatomy texts give the extent of an origin along the bone, e.g. the tibialis
  // anterior arises from the upper two-thirds of the tibia's lateral surface; a belly lying on
  // the bone beyond that slides over it.
  double origin_reach = 1.0;
  double insertion_reach = 1.0;
  Vec3 origin_towards = Vec3::UnitZ();
};

// Areas from bones given with their roles: origin = the muscle vertices within `distance` of an
// origin bone (and within origin_reach of the origin end), insertion likewise. A side whose bones
// the belly does not touch -- its tendon is not part of the mesh (Visible Human bellies), or no
// bone is given -- takes its end region (the musculotendinous junction), and the other side's
// contact then gives up the vertices in that end region. Contact specks are dropped as in
// find_bone_attachments. Throws bad_input when neither side touches its bones.
Attachments find_bone_role_attachments(const TriMesh& muscle,
                                       const std::vector<TriMesh>& origin_bones,
                                       const std::vector<TriMesh>& insertion_bones,
                                       const BoneRoleOptions& options = {});

// Muscle architecture for aponeurosis attachment areas (Blemker & Delp 2005's unipennate and
// bipennate templates).
enum class Architecture { unipennate, bipennate };
Architecture parse_architecture(std::string_view name);  // "unipennate" | "pennate" | "bipennate"
std::string to_string(Architecture a);

struct AponeurosisOptions {
  Architecture architecture = Architecture::unipennate;
  double pennation_rad = 0.35;  // target angle between fibres and the line of action, (0, pi/2)
  // A vertex is on a face of the box when its outward normal is within this angle of the face's
  // outward direction (+x or -x).
  double face_angle_rad = M_PI / 3.0;
  double end_fraction = 0.08;     // bipennate: the insertion's surface part (distal end region)
  double sheet_spacing_m = 1e-3;  // bipennate: spacing of the central sheet's sample points
  Vec3 origin_towards = Vec3::UnitZ();
  Vec3 thickness_direction = Vec3::Zero();  // zero: least variance across the principal axis
  // Nonzero: the sign of x is chosen so the insertion (+x) face is the one towards this direction
  // (unipennate: e.g. the deep side, towards the bone, for the medial gastrocnemius, whose
  // insertion aponeurosis is deep). Zero: the sign of the eigenvector or of thickness_direction.
  Vec3 insertion_face_towards = Vec3::Zero();
};

// Aponeurosis attachment areas derived from the muscle's shape and architecture (docs/fibres.md,
// "Aponeurosis areas"). Box: z the principal axis (origin end towards `origin_towards`), x the
// thickness direction, s the axial position from the origin end (0) to the insertion end (L),
// T the mean thickness along x, d = T_f / tan(pennation) the axial offset a fibre makes while
// crossing its thickness T_f (T for unipennate, T/2 for bipennate).
//   unipennate: origin = the -x face over s in [0, L - d], insertion = the +x face over [d, L];
//   bipennate:  origin = both x faces over [0, L - d]; insertion = the distal end region, and
//               interior points on the mid-thickness sheet over [d, L] (insertion_interior).
// d is kept within [0.2 L, 0.8 L]. Throws bad_input when an area ends up empty.
Attachments find_aponeurosis_attachments(const TriMesh& muscle,
                                         const AponeurosisOptions& options = {});

// The muscle's thickness between its two faces across the thickness direction, as ultrasound
// measures it (the perpendicular distance between the aponeuroses a pennate fibre crosses): from
// every vertex whose normal is within options.face_angle_rad of +x or -x (box of
// find_aponeurosis_attachments) in the middle 80 % of the principal axis, the distance along the
// inward vertex normal to the opposite surface; the median (m). Only the box options
// (thickness_direction, origin_towards, face_angle_rad) are used. Throws bad_input when no such
// vertex exists.
double calc_face_thickness(const TriMesh& muscle, const AponeurosisOptions& options = {});

// Adds an internal aponeurosis given as a mesh (e.g. a segmented sheet): its vertices and
// triangle centroids that lie inside the muscle become `insertion_interior`. Throws bad_input when
// none lies inside.
void set_interior_aponeurosis(const TriMesh& muscle, const TriMesh& aponeurosis,
                              Attachments& areas);

// The mean normal of a sheet-like mesh (unit; the direction of least variance of its vertices),
// e.g. an aponeurosis' thickness direction.
Vec3 calc_sheet_normal(const TriMesh& sheet);

// The border of an interior aponeurosis on the side where it becomes its tendon (docs/fibres.md,
// "Session 10"), e.g. for HarmonicOptions::transverse_targets. Box as find_aponeurosis_attachments:
// z the muscle's principal axis (origin end towards `origin_towards`), x = `thickness_direction`
// (the sheet's normal), y = z x x. The tendon side is the sign of y towards which the sheet's
// distal third lies from its mean (a sheet narrows into its tendon there, as the tibialis
// anterior's central aponeurosis, whose tendon appears on the anterior surface distally); the
// sheet points (metres, #N x 3) are binned along z over the sheet's own extent, and the border is,
// per non-empty bin, the point farthest to that side. Throws bad_input for fewer than 3 points or
// a sheet whose distal third leans to neither side (shift below 2 % of its mean width: no tendon
// side to turn to); usage for `bins` < 2 and for a zero thickness direction or one along the axis.
Points3 find_aponeurosis_border(const TriMesh& muscle, const Points3& sheet,
                                const Vec3& thickness_direction,
                                const Vec3& origin_towards = Vec3::UnitZ(), int bins = 50);

// `count` points spread over the area's triangles: an area-weighted R2 low-discrepancy sequence
// (point i picks a triangle by its first coordinate, then a point in it by uniform mapping).
Points3 calc_area_samples(const TriMesh& muscle, const AttachmentArea& area, int count);

// Reads landmarks from CSV: one point per row, three numeric columns x,y,z (an optional header
// row and extra columns are ignored; '#' starts a comment), scaled by `metres_per_unit`.
// Throws bad_input naming the file and line on malformed rows or when there is no point.
Points3 read_landmarks_csv(const std::filesystem::path& path, double metres_per_unit = 1.0);

}  // namespace fascicle
