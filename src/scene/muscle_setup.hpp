// Set-up helpers shared by the built-in muscle representations (internal to the scene module).
#pragma once

#include "fascicle/scene/model.hpp"
#include "fascicle/fibres/fibre_set.hpp"
#include "fascicle/scene/state.hpp"

#include <string>
#include <vector>

namespace fascicle::scene_detail {

// A representation option of the muscle (scene "options"), or `fallback`.
double get_option(const Muscle& m, const std::string& key, double fallback);
// Throws bad input naming the muscle when it has no surface mesh (volumetric representations).
void require_muscle_mesh(const Muscle& m, const std::string& representation);
// Rigid motion of body b from the default pose: X_ground_b(now) · X_ground_b(default)⁻¹.
Transform calc_body_motion(const Model& model, const State& state, BodyIndex b);
// Rest surface vertices within the attachment's radius of its landmarks (ground, default pose).
std::vector<int> find_area_vertices(const Model& model, const Muscle& m, const Attachment& a);
// Origin centroid → via points → insertion centroid at the default pose (ground).
Points3 calc_rest_action_line(const Model& model, const Muscle& m);
// The fibres module's template decomposition of the rest surface between the attachment areas (or,
// when an area has no triangle, the surface's end regions along the insertion → origin
// direction `towards_origin`). Options: fibre_count (60), fibre_resolution (15).
std::vector<Points3> decompose_rest_fibres(const Muscle& m, const std::vector<int>& origin,
                                           const std::vector<int>& insertion, const Vec3& towards_origin);
// The muscle's rest fibres: given ones, or decompose_rest_fibres() (none with option "fibres": 0).
std::vector<Points3> get_or_decompose_rest_fibres(const Model& model, const Muscle& m);
// Per-fibre length, strain against `rest_length` and pennation against the action line, and
// their means, into `out`.
void set_fibre_metrics(const VecX& rest_length, MuscleFrame& out);
// calc_muscle_geometry() without the overlap measure: every muscle's (and group's) surface and
// fibres for this frame. Leaves the stage at Stage::forces (the overlaps are still missing).
void calc_muscle_shapes(const Model& model, State& state);

}  // namespace fascicle::scene_detail
