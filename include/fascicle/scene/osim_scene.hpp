// An OpenSim model as a scene: its skeleton and muscle paths as they are, its bone meshes (closed
// ones as obstacles, the others drawn only), and for every muscle a generated closed belly around
// the fibre part of its path, so `fascicle run --model M.osim` gives volumetric, fibre-resolved
// muscles for models that have no muscle meshes. Shape rule and picture: docs/opensim-volumes.md.
#pragma once

#include "fascicle/geometry/tri_mesh.hpp"
#include "fascicle/osim/osim_model.hpp"
#include "fascicle/scene/belly_packing.hpp"
#include "fascicle/scene/scene_spec.hpp"

#include <map>
#include <string>
#include <vector>

namespace fascicle {

struct GeneratedBellyOptions {
  // σ in PCSA = F0 / σ (Pa). Seed 001 §2.5.2 (Zajac): 25 N/cm²; Rajagopal et al. 2016 use 60.
  double specific_tension_Pa = 25.0e4;
  int segments = 16;  // vertices around a cross-section
  int rings = 24;     // cross-sections between the two tips
  int fibres = 30;    // fibres of the generated belly
  // Belly slenderness: largest section radius / belly length (fusiform muscles: about 1/6).
  double slenderness = 1.0 / 6.0;
  // Packing at the default pose (on by default): the bellies of the scene are made to touch
  // without overlapping each other or the obstacle bones (pack_bellies, docs/opensim-volumes.md).
  BellyPackingOptions packing;
};

// The fusiform solid around a centreline (polyline, >= 2 points, metres): circular sections
// perpendicular to the line (rotation-minimising frames) of radius R·sin(πu)^(1/2) at normalised
// arc length u, closed by a vertex at each tip, with R chosen so the enclosed volume is
// `volume_m3` (to 1e-9 relative). Closed and outward oriented for any centreline whose curvature
// radius exceeds R. With `pennation_rad` ≈ 0 its fibres run from tip to tip at a constant fraction
// ρ of the local radius and a fixed angle φ in the section frame ((ρ², φ) on a sunflower
// pattern, ρ ≤ 0.9): a parallel-fibred muscle. With pennation α > 5°, each fibre starts on the axis
// (a central aponeurosis) and runs towards the origin tip and outwards at angle α to the axis, at
// a fixed angle φ, until it reaches 95 % of the local radius: a multipennate muscle whose fibre length follows
// from the shape. Throws fascicle::Error (bad input) for a degenerate line or volume.
struct GeneratedBelly {
  TriMesh mesh;
  std::vector<Points3> fibres;  // tip to tip, one point per section
};
GeneratedBelly make_fusiform_belly(const Points3& centreline, double volume_m3,
                                   const GeneratedBellyOptions& options = {}, double pennation_rad = 0.0);

// Where the belly of a musculotendon unit of volume V lies on its path of length lMT at the rest
// pose: the length l_b at which the fusiform solid of slenderness k = R/l_b holds V
// (V = 2 k² l_b³ for the sin^(1/2) profile on a straight line, so l_b = (V / 2k²)^(1/3)), kept
// within [l0 cos α0, 0.9 lMT] (never shorter than its fibres, always leaving some tendon), centred
// on the path (the remaining tendon split equally between origin and insertion). Returns arc
// lengths [start, end], m.
struct BellySpan {
  double start_m = 0.0;
  double end_m = 0.0;
};
BellySpan calc_belly_span(double path_length_m, double volume_m3, const MuscleParameters& p,
                          double slenderness = 1.0 / 6.0);

// The sub-polyline of `polyline` between arc lengths a < b.
Points3 calc_sub_polyline(const Points3& polyline, double a, double b);

struct OsimSceneOptions {
  std::vector<std::string> muscles;  // names or shell patterns ("*_r") to keep (empty: every Hill muscle)
  std::string representation = "surface_first";
  double activation = -1.0;                // constant activation; < 0: each muscle's default
  std::map<std::string, double> muscle_options;  // representation options of every muscle
  GeneratedBellyOptions belly;
};

// The scene. Muscles are the model's Thelen/Millard/DeGroote muscles (others are skipped with a
// warning); an unknown name in options.muscles is a bad-input error suggesting the nearest one.
// With packing on, the bellies are packed against each other and against the obstacle bones at
// the default pose before they become the muscles' meshes and fibres; `packing_report` (optional)
// receives the packing's overlaps before/after and radial changes.
SceneSpec make_scene_from_osim(const OsimModel& osim, const OsimSceneOptions& options = {},
                               PackingReport* packing_report = nullptr);

}  // namespace fascicle
