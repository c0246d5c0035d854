// Fibres of B-spline solids: which parametric direction runs along the fibres is a property of
// the solid (BSplineSolid::fibre_direction). Iso-parametric fibre curves follow that direction at
// fixed cross-section coordinates; streamlines integrate a direction field given in material
// coordinates (seed 000 §3.1.2, Fig. 5) and are mapped to space by x(U).
#pragma once

#include "fascicle/bspline/solid.hpp"

#include <functional>
#include <vector>

namespace fascicle {

// Unit spatial fibre direction J e_f / |J e_f| at a material point.
Vec3 calc_fibre_direction(const BSplineSolid& solid, const Vec3& uvw);

// The iso-parametric fibre curve through cross-section coordinates `seed` (the two non-fibre
// coordinates in cyclic order after the fibre direction), `samples` >= 2 points (#samples x 3, m).
Points3 calc_fibre_curve(const BSplineSolid& solid, const Vec2& seed, int samples);

// A grid of na x nb fibre curves spread over the cross-section (cell centres on clamped
// directions, uniform on periodic ones).
std::vector<Points3> calc_fibre_curves(const BSplineSolid& solid, int na, int nb, int samples);

// A direction field in material coordinates (need not be normalised).
using MaterialDirectionField = std::function<Vec3(const Vec3& uvw)>;

// Unipennate template: fibres leave the fibre direction at angle `pennation_rad` towards the
// cross direction `towards` (0,1,2, not the fibre direction), measured in material units.
MaterialDirectionField make_pennate_field(FibreDirection fibre, int towards, double pennation_rad);
// Fanned template: fibres converge from the full width of cross direction `across` at the start
// of the fibre direction towards its centre line; convergence in [0, 1) (0 = parallel).
MaterialDirectionField make_fanned_field(FibreDirection fibre, int across, double convergence);

struct StreamlineOptions {
  double step = 0.01;   // RK4 step in material units (arc length in parameter space)
  int max_steps = 1000;
};

// Streamline of `field` from material point `seed` (RK4 in material coordinates, both directions
// from the seed), stopped at the boundary of non-periodic directions. Returns spatial points
// (#n x 3, m) ordered along the field; `material` (optional) receives the material points.
Points3 trace_streamline(const BSplineSolid& solid, const MaterialDirectionField& field,
                         const Vec3& seed, const StreamlineOptions& options = {},
                         Points3* material = nullptr);

}  // namespace fascicle
