// Template method of fibre decomposition (Kohout et al.; seed 002 section 3): a unit-cube fibre
// template is placed in an oriented box aligned with the attachment areas, cube and muscle are cut
// by the same planes, and each template slice (the unit square) is mapped onto the muscle's
// contour in that plane with mean value coordinates (Floater 2003, CAGD 20(1):19-27). Fibres of
// end-to-end templates are then re-routed so their ends spread over the whole attachment areas,
// smoothed, and pulled inside the surface where the map left them outside.
#pragma once

#include "fascicle/fibres/attachment.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/fibres/tet_mesh.hpp"

#include <memory>
#include <vector>

namespace fascicle {

class MeshQuery;

struct TemplateMapOptions {
  int num_slices = 48;       // planes cutting the muscle between the attachment levels
  int contour_samples = 64;  // points per slice contour (and per unit-square boundary)
  double end_margin = 0.02;  // fraction of the axial extent kept clear of the muscle's tips
  double reroute_fraction = 0.15;  // part of each fibre end replaced by a segment to the area
  int smoothing_iterations = 4;    // Laplacian smoothing passes (ends fixed)
  // Re-routing targets on each area: > 1 chooses them by farthest-point order among this many
  // times as many stratified area samples (evenly spaced out to the rim); 1: the stratified
  // samples themselves (the default: docs/fibres.md gives the measured trade-off).
  int target_factor = 1;
  // Box x axis (the template's thickness direction, across which pennate fibres run), projected
  // normal to the line of action; zero: x is normal to the direction of largest variance.
  // E.g. the normal of a known aponeurosis sheet.
  Vec3 thickness_direction = Vec3::Zero();
  // Nonzero: the sign of x is chosen so the box's +x side (where pennate fibres end) is the one
  // towards this direction (e.g. the deep side of the medial gastrocnemius). Zero: the sign given
  // by the eigenvector or by thickness_direction.
  Vec3 insertion_side_towards = Vec3::Zero();
  // How the muscle is sliced (docs/fibres.md, "Field slicing"). planes: K planes normal to the
  // box axis between the attachment centroids' levels. field: K iso-contours (on the surface) of
  // the Laplace potential u (0 on the origin area, 1 on the insertion area; tets `field_tets`) at
  // the levels that split the volume into equal parts, from `field_end_fraction` of it to 1 minus
  // that, so the first and last slices wrap the attachment areas wherever they lie on the belly;
  // mapped ends are only snapped to their area targets (no re-routed segment) and the fibres get
  // `field_smoothing_iterations` passes. automatic: field when an attachment area lies along the
  // side of the belly (its extent along the box axis exceeds `side_area_extent` of the muscle's)
  // and the two areas are apart along the axis (gap > `min_area_gap` of the extent: the level
  // sets of areas that abut all meet at their common border, so the slices would be hinged
  // there), else planes.
  enum class Slicing { automatic, planes, field };
  Slicing slicing = Slicing::automatic;
  double side_area_extent = 0.15;
  double min_area_gap = 0.1;
  double field_end_fraction = 0.0;
  // Planes with a side area (and the areas abutting, so no field slicing): the slices run from
  // the origin area's far end to the insertion area's far end, and fibre ends are re-routed
  // onto the areas from the point of the fibre where that turns least for the length of the
  // new segment (docs/fibres.md), with
  // targets chosen as with target_factor = max(target_factor, side_target_factor).
  bool side_reroute = true;
  int side_target_factor = 8;
  double side_max_turn_rad = 1.0471975511965976;  // 60 degrees
  // Fibre budget along an origin side area (docs/fibres.md, "Side re-routing"): a fibre starting
  // on the strip crosses only the sections beyond its start, so the targets are allotted along
  // the axis (per slice interval) so that the number of fibres started by each level is
  // count x (side_section_share x the running maximum of the section area, from the area's far
  // end, over its maximum on the area + (1 - side_section_share) x the area's fraction), the
  // targets within that quota chosen by farthest-point order as before; and fibres are matched to
  // the targets in `side_order_bands` bands: the first count / bands fibres (the start order is a
  // farthest-point order, so every prefix is spread over the section) to the targets nearest the
  // far end, greedily by least cost within a band, then the next. Off: the session-8 rule
  // (evenly spaced targets, global least-cost matching).
  bool side_budget = true;
  double side_section_share = 0.5;
  int side_order_bands = 10;
  int field_smoothing_iterations = 2;
  TetOptions field_tets{.max_volume = 0.0, .volume_scale = 2.0, .max_radius_edge_ratio = 0.0};
};

// A slice whose plane cuts the muscle into more than one closed contour: the template cannot be
// mapped there (the largest contour is used).
struct SliceIssue {
  double axial_position_m = 0.0;  // along the box's z axis from the origin level
  Vec3 point = Vec3::Zero();      // the slice centre in the mesh frame
  int num_contours = 0;
};

// The reusable per-muscle set-up: box frame, slices and their resampled contours.
class TemplateMapper {
 public:
  // Throws bad_input when the attachment centroids coincide or a slice misses the muscle.
  TemplateMapper(const TriMesh& muscle, const Attachments& areas,
                 const TemplateMapOptions& options = {});
  ~TemplateMapper();
  TemplateMapper(TemplateMapper&&) noexcept;
  TemplateMapper& operator=(TemplateMapper&&) noexcept;

  // The box frame: columns x (thickness), y (width), z (origin -> insertion), unit, right-handed;
  // origin at the origin level on the muscle's axis.
  const Transform& get_box_frame() const { return X_mesh_box_; }
  double get_axial_length() const { return axial_length_; }
  // Mean thickness of the muscle along the box's x axis: the mean over slices of contour area /
  // contour extent along y (m).
  double get_mean_thickness() const { return mean_thickness_; }
  // Mean in-slice distance a pennate template fibre covers while crossing the unit square from
  // x = 0 to x = 1: the distance between the mapped boundary points (0, y) and (1, y), averaged over
  // the slices and y = 0.1, 0.2, ..., 0.9 (m). The pennation-derived rise uses it (docs/fibres.md).
  double get_mean_crossing() const { return mean_crossing_; }
  const std::vector<SliceIssue>& get_issues() const { return issues_; }
  bool is_mappable() const { return issues_.empty(); }
  // True when the slices are iso-contours of the Laplace potential (TemplateMapOptions::slicing).
  bool uses_field_slicing() const { return field_slicing_; }

  // `count` start parameters r in [0, 1]^2 for the parallel template (make_template_fibres with
  // starts; the fibre sits at 0.02 + 0.96 r in the unit square), spread in proportion to the
  // muscle cross-section they map to, and evenly spaced there: the square is split into 16 x 16
  // cells (two triangles each), each weighted by the mean over the slices of the area its mean
  // value coordinate image covers; 1024 candidates are sampled from the cells with the stratified
  // R2 rule of the attachment areas (set-up), and `count` of them are chosen by farthest-point
  // selection, the distance being that of their images in four slices (at 1/8, 3/8, 5/8, 7/8 of
  // the axis), starting from the candidate nearest the mean image. For count > 256 the stratified
  // sample itself, in farthest-point order in the unit square (every prefix spread). The R2
  // sequence is uniform in the square, which the map stretches unevenly (crescent-shaped sections
  // leave sparse horns), and is not evenly spaced at the periphery.
  std::vector<Vec2> calc_section_samples(int count) const;

  // Maps unit-cube fibres into the muscle (metres, mesh frame), re-routing end-to-end templates'
  // ends over the attachment areas when `reroute_ends`, then smoothing and resampling each fibre to
  // its template resolution.
  FibreSet calc_fibres(const FibreSet& unit_fibres, bool reroute_ends) const;

 private:
  struct Slices;
  TemplateMapOptions options_;
  Transform X_mesh_box_ = Transform::Identity();
  double axial_length_ = 0.0;
  double mean_thickness_ = 0.0;
  double mean_crossing_ = 0.0;
  double mean_section_area_ = 0.0;  // mean slice contour area (m^2)
  bool field_slicing_ = false;
  bool side_areas_ = false;  // an attachment area lies along the side of the belly
  bool origin_side_ = false;  // the origin area itself lies along the side of the belly
  std::vector<SliceIssue> issues_;
  std::unique_ptr<Slices> slices_;
  std::unique_ptr<MeshQuery> query_;
  Attachments areas_;
  TriMesh muscle_;
};

// Mean value coordinates of a point strictly inside a simple polygon (#N x 2, either
// orientation): N weights summing to 1 that reproduce the point (Floater 2003, eq. 2.1).
VecX calc_mean_value_coordinates(const Eigen::Matrix<double, Eigen::Dynamic, 2>& polygon,
                                 const Vec2& p);

}  // namespace fascicle
