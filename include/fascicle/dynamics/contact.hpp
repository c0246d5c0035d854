// Contact between solid muscles (seed 000 §4.7): boundary sample points of one solid found inside
// the other by the point-membership test (bspline/membership.hpp) are pushed out towards the
// other's current boundary by a penalty force; the opposite force acts on the other solid at the
// material point where the sample was found. Forces exist only while the solids overlap, so they
// push and never pull. Bone contact is the point-on-plane constraint of SolidDynamicsSpec.
#pragma once

#include "fascicle/dynamics/solid_dynamics.hpp"

#include <utility>
#include <vector>

namespace fascicle {

struct MuscleContactResult {
  Points3 forces_a;            // #P_a x 3 generalised forces on a's control points (N)
  Points3 forces_b;            // #P_b x 3
  int num_contacts = 0;        // sample points found inside the other solid
  double max_depth_m = 0.0;    // deepest penetration
  Vec3 force_on_a_N = Vec3::Zero();  // total contact force on a (= −total on b)
};

// samples_per_span: boundary sample density (per knot span) on both solids. stiffness_N_m: per
// sample point. Builds membership locators for the current shapes (cost: a few ms per pair).
MuscleContactResult calc_muscle_contact(const SolidDynamicsModel& a, const Points3& P_a,
                                        const SolidDynamicsModel& b, const Points3& P_b,
                                        double stiffness_N_m, int samples_per_span = 2);

// Broad phase: the pairs of `adjacency` (which muscles can touch, e.g. from anatomy) whose control
// point bounding boxes, grown by `margin_m`, overlap (a solid lies in its control points' convex
// hull, so this never misses a contact).
std::vector<std::pair<int, int>> find_contact_pairs(
    const std::vector<Points3>& control_points, const std::vector<std::pair<int, int>>& adjacency,
    double margin_m = 0.0);

}  // namespace fascicle
