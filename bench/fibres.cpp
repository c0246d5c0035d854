// Fibre decomposition benchmarks on the Visible Human medial gastrocnemius (19k triangles), and
// a one-iteration validation run per muscle and method (fibre length vs Ward 2009, DTI angles).
#include "fascicle/fibres/analysis.hpp"
#include "fascicle/fibres/decompose.hpp"
#include "fascicle/io/mesh_io.hpp"

#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>

using namespace fascicle;

namespace {

const std::filesystem::path data = FASCICLE_DEFAULT_DATA_DIR;
const std::string vh = "visible_human_female/right/VHF_Right_";

const TriMesh& mg() {
  static const TriMesh m =
      read_mesh(data / (vh + "Muscle_GastrocnemiusMedial_smooth.stl"), LengthUnit::millimetre);
  return m;
}

void BM_TemplateSetup(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  for (auto _ : state) {
    TemplateMapper mapper(mg(), areas);
    benchmark::DoNotOptimize(mapper);
  }
  state.counters["triangles"] = static_cast<double>(mg().num_faces());
}
BENCHMARK(BM_TemplateSetup)->Unit(benchmark::kMillisecond);

void BM_TemplateFibres(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  const TemplateMapper mapper(mg(), areas);
  const auto t = static_cast<FibreTemplate>(state.range(0));
  for (auto _ : state) {
    const FibreSet unit = make_template_fibres(t, 100, 16);  // 15 segments
    FibreSet f = mapper.calc_fibres(unit, is_end_to_end(t));
    benchmark::DoNotOptimize(f);
  }
  state.SetLabel(to_string(t));
}
BENCHMARK(BM_TemplateFibres)->DenseRange(0, 4)->Unit(benchmark::kMillisecond);

// What decompose_muscle does for the parallel template since 2026-11-24: start parameters spread
// by mapped cross-section (TemplateMapper::calc_section_samples), then the same mapping.
void BM_TemplateFibresSectionStarts(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  const TemplateMapper mapper(mg(), areas);
  for (auto _ : state) {
    const FibreSet unit = make_template_fibres(FibreTemplate::parallel,
                                               mapper.calc_section_samples(100), 16,
                                               default_pennate_rise);
    FibreSet f = mapper.calc_fibres(unit, true);
    benchmark::DoNotOptimize(f);
  }
  state.SetLabel("parallel, section-proportional starts");
}
BENCHMARK(BM_TemplateFibresSectionStarts)->Unit(benchmark::kMillisecond);

// Muscles with side attachment areas (session 8): the VH soleus (tibial/fibular strip; the
// automatic rule slices it by the Laplace field, so the set-up includes TetGen and the solve)
// and the VH TA (one tibial contact split at mid-length: planes with side re-routing). Bone
// areas as in the quality test; Arg 0 = soleus, 1 = TA.
struct SideCase {
  TriMesh muscle;
  Attachments areas;
};

const SideCase& side_case(int i) {
  static const auto load = [](const std::string& m, const std::vector<std::string>& bones) {
    SideCase c;
    c.muscle = read_mesh(data / (vh + m), LengthUnit::millimetre);
    std::vector<TriMesh> b;
    for (const auto& name : bones) b.push_back(read_mesh(data / (vh + name), LengthUnit::millimetre));
    c.areas = find_bone_attachments(c.muscle, b, 0.002);
    return c;
  };
  static const SideCase soleus = load("Muscle_Soleus_smooth.stl",
                                      {"Bone_Tibia_smooth.stl", "Bone_Fibula_smooth.stl"});
  static const SideCase ta = load("Muscle_TibialisAnterior_smooth.stl", {"Bone_Tibia_smooth.stl"});
  return i == 0 ? soleus : ta;
}

void BM_TemplateSetupSideAreas(benchmark::State& state) {
  const SideCase& c = side_case(static_cast<int>(state.range(0)));
  bool field = false;
  for (auto _ : state) {
    TemplateMapper mapper(c.muscle, c.areas);
    field = mapper.uses_field_slicing();
    benchmark::DoNotOptimize(mapper);
  }
  state.counters["triangles"] = static_cast<double>(c.muscle.num_faces());
  state.SetLabel(field ? "soleus, field slicing" : "VH TA, planes + side re-routing");
}
BENCHMARK(BM_TemplateSetupSideAreas)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_TemplateFibresSideAreas(benchmark::State& state) {
  const SideCase& c = side_case(static_cast<int>(state.range(0)));
  const TemplateMapper mapper(c.muscle, c.areas);
  for (auto _ : state) {
    const FibreSet unit = make_template_fibres(FibreTemplate::parallel,
                                               mapper.calc_section_samples(100), 16,
                                               default_pennate_rise);
    FibreSet f = mapper.calc_fibres(unit, true);
    benchmark::DoNotOptimize(f);
  }
  state.counters["triangles"] = static_cast<double>(c.muscle.num_faces());
  state.SetLabel(mapper.uses_field_slicing() ? "soleus, field slicing"
                                             : "VH TA, planes + side re-routing");
}
BENCHMARK(BM_TemplateFibresSideAreas)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_Tetrahedralise(benchmark::State& state) {
  TetOptions opt;
  opt.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  Eigen::Index tets = 0;
  for (auto _ : state) {
    TetMesh t = calc_tet_mesh(mg(), opt);
    tets = t.num_tets();
    benchmark::DoNotOptimize(t);
  }
  state.counters["tets"] = static_cast<double>(tets);
  state.SetLabel(state.range(0) ? "quality q2" : "boundary only");
}
BENCHMARK(BM_Tetrahedralise)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_LaplaceSolve(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  TetOptions opt;
  opt.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  const TetMesh t = calc_tet_mesh(mg(), opt);
  for (auto _ : state) {
    VecX u = solve_laplace(t, areas.origin.vertices, areas.insertion.vertices);
    benchmark::DoNotOptimize(u);
  }
  state.counters["vertices"] = static_cast<double>(t.num_vertices());
}
BENCHMARK(BM_LaplaceSolve)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_HarmonicTrace(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  HarmonicOptions opt;
  opt.tets.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  const HarmonicField field = calc_harmonic_field(mg(), areas, opt);
  for (auto _ : state) {
    FibreSet f = trace_harmonic_fibres(field, areas.origin, {.count = 100, .resolution = 16});
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_HarmonicTrace)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// The plain field's default since 2026-11-24: seeds spread over the volume, traced both ways.
void BM_HarmonicTraceVolumeSeeds(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  HarmonicOptions opt;
  opt.tets.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  const HarmonicField field = calc_harmonic_field(mg(), areas, opt);
  for (auto _ : state) {
    FibreSet f = trace_harmonic_fibres(
        field, areas.origin,
        {.count = 100, .resolution = 16, .seeding = TraceOptions::Seeding::volume});
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_HarmonicTraceVolumeSeeds)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// Volume candidates only: factor x 100 volume seeds traced, 100 fibres chosen by farthest-point
// order of their shapes (decompose_muscle adds area candidates: BM_HarmonicTraceDefault).
// Arguments: tet quality, factor.
void BM_HarmonicTraceVolumeCandidates(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  HarmonicOptions opt;
  opt.tets.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  const HarmonicField field = calc_harmonic_field(mg(), areas, opt);
  for (auto _ : state) {
    FibreSet f = trace_harmonic_fibres(field, areas.origin,
                                       {.count = 100,
                                        .resolution = 16,
                                        .seeding = TraceOptions::Seeding::volume,
                                        .candidate_factor = static_cast<int>(state.range(1))});
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_HarmonicTraceVolumeCandidates)
    ->ArgsProduct({{0, 1}, {2, 4}})
    ->Unit(benchmark::kMillisecond);

// What decompose_muscle does for plain fields since session 7: 8 x volume candidates plus 100
// candidates seeded on each area, kinked or unfinished traces last. Argument: tet quality, volume
// candidate factor (4 is shown for comparison).
void BM_HarmonicTraceDefault(benchmark::State& state) {
  const Attachments areas = find_end_attachments(mg());
  HarmonicOptions opt;
  opt.tets.max_radius_edge_ratio = state.range(0) ? 2.0 : 0.0;
  const HarmonicField field = calc_harmonic_field(mg(), areas, opt);
  for (auto _ : state) {
    FibreSet f = trace_harmonic_fibres(field, areas.origin,
                                       {.count = 100,
                                        .resolution = 16,
                                        .seeding = TraceOptions::Seeding::volume,
                                        .candidate_factor = static_cast<int>(state.range(1)),
                                        .area_candidate_factor = 1},
                                       &areas.insertion);
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_HarmonicTraceDefault)
    ->ArgsProduct({{0, 1}, {4, 8}})
    ->Unit(benchmark::kMillisecond);

// Validation: one decomposition per muscle, method and template; counters carry the results.
// Counters shared by the validation benchmarks: mean fibre length and its ratio to Ward et al.
// 2009, mean pennation, and (when a tracts file is given) the DTI direction deviation.
void report_validation(benchmark::State& state, const FibreAnalysis& a, double ward_m,
                       const std::filesystem::path& tracts_file, const FibreSet& fibres) {
  state.counters["fibre_len_mm"] = a.mean_fibre_length_m * 1e3;
  state.counters["ward_ratio"] = a.mean_fibre_length_m / ward_m;
  state.counters["pennation_deg"] = a.mean_pennation_rad * 180 / M_PI;
  if (tracts_file.empty()) return;
  const FibreSet tracts = read_tracts(tracts_file, 1e-3);
  const DirectionDeviation dev = compare_directions(fibres, tracts);
  state.counters["dti_mean_deg"] = dev.mean_rad * 180 / M_PI;
  state.counters["dti_sd_deg"] = dev.stddev_rad * 180 / M_PI;
  const DirectionDeviation old = compare_directions(fibres, tracts, 0.0);
  state.counters["dti_old_mean_deg"] = old.mean_rad * 180 / M_PI;
}

struct ValidationCase {
  const char* name;
  std::string mesh;
  std::vector<std::string> bones;
  double ward_m;
  const char* tracts;  // DTI tracts or nullptr
};

const ValidationCase validation_cases[] = {
    {"soleus", vh + "Muscle_Soleus_smooth.stl",
     {vh + "Bone_Tibia_smooth.stl", vh + "Bone_Fibula_smooth.stl"}, 0.0440, nullptr},
    {"tibialis_anterior", vh + "Muscle_TibialisAnterior_smooth.stl", {vh + "Bone_Tibia_smooth.stl"},
     0.0683, nullptr},
    {"medial_gastrocnemius", vh + "Muscle_GastrocnemiusMedial_smooth.stl", {}, 0.0510, nullptr},
    {"vastus_lateralis", vh + "Muscle_VastusLateralis_smooth.stl", {}, 0.0994, nullptr},
    {"gluteus_medius", vh + "Muscle_GluteusMedius_smooth.stl", {}, 0.0733, nullptr},
    {"bolsterlee_MG", "bolsterlee_dti/MG.stl", {}, 0.0510, "bolsterlee_dti/tracts_MG.txt"},
    {"bolsterlee_TA", "bolsterlee_dti/TA.stl", {}, 0.0683, "bolsterlee_dti/tracts_TA.txt"},
};

void BM_Validate(benchmark::State& state) {
  const ValidationCase& c = validation_cases[state.range(0)];
  const auto method = static_cast<FibreMethod>(state.range(1));
  const auto tmpl = static_cast<FibreTemplate>(state.range(2));
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  Attachments areas;
  if (c.bones.empty()) {
    areas = find_end_attachments(muscle);
  } else {
    std::vector<TriMesh> bones;
    for (const auto& b : c.bones) bones.push_back(read_mesh(data / b, LengthUnit::millimetre));
    areas = find_bone_attachments(muscle, bones, 0.002);
  }
  DecomposeOptions opt;
  opt.method = method;
  opt.fibre_template = tmpl;
  opt.count = 100;
  opt.resolution = 16;
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, areas, opt);
  const FibreAnalysis a = analyse_fibres(muscle, areas, d.fibres);
  report_validation(state, a, c.ward_m, c.tracts ? data / c.tracts : std::filesystem::path(), d.fibres);
  state.counters["pcsa_cm2"] = a.pcsa_m2 * 1e4;
  state.counters["volume_cm3"] = a.volume_m3 * 1e6;
  state.SetLabel(std::string(c.name) + " " + to_string(d.method_used) + " " + to_string(tmpl));
}
BENCHMARK(BM_Validate)
    ->ArgsProduct({benchmark::CreateDenseRange(0, 6, 1), {0, 1}, {0, 1, 2}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// Architecture-aware validation: aponeurosis attachment areas (find_aponeurosis_attachments) and
// the pennate templates' rise from the target pennation angle (Ward et al. 2009 pennation; the
// architecture type from anatomy texts); the TA from Bolsterlee also takes its segmented
// aponeurosis (TA_apo.stl) as the interior insertion and as the template's thickness direction.
struct ArchitectureCase {
  const char* name;
  std::string mesh;
  Architecture architecture;
  double pennation_deg;  // Ward et al. 2009
  double ward_m;
  const char* tracts;
  const char* aponeurosis;
  // Unipennate muscles whose insertion aponeurosis is known to be deep (the medial
  // gastrocnemius: the deep, anterior aponeurosis continues into the Achilles tendon): a mesh on
  // the deep side; the insertion face is the one towards its centroid. nullptr: eigenvector sign.
  const char* deep_side = nullptr;
};

// The insertion side for a case: from the muscle's centroid to the deep-side mesh's centroid, or
// zero.
Vec3 find_deep_direction(const ArchitectureCase& c, const TriMesh& muscle) {
  if (!c.deep_side) return Vec3::Zero();
  const TriMesh other = read_mesh(data / c.deep_side, LengthUnit::millimetre);
  return Vec3(other.V.colwise().mean()) - Vec3(muscle.V.colwise().mean());
}

const ArchitectureCase architecture_cases[] = {
    {"soleus", vh + "Muscle_Soleus_smooth.stl", Architecture::bipennate, 28.3, 0.0440, nullptr,
     nullptr},
    {"tibialis_anterior", vh + "Muscle_TibialisAnterior_smooth.stl", Architecture::bipennate, 9.6,
     0.0683, nullptr, nullptr},
    {"medial_gastrocnemius", vh + "Muscle_GastrocnemiusMedial_smooth.stl",
     Architecture::unipennate, 9.9, 0.0510, nullptr, nullptr, "visible_human_female/right/VHF_Right_Bone_Tibia_smooth.stl"},
    {"vastus_lateralis", vh + "Muscle_VastusLateralis_smooth.stl", Architecture::unipennate, 18.4,
     0.0994, nullptr, nullptr},
    {"gluteus_medius", vh + "Muscle_GluteusMedius_smooth.stl", Architecture::unipennate, 20.5,
     0.0733, nullptr, nullptr},
    // Deep side: the anterior compartment (the subject's TA, same MRI frame).
    {"bolsterlee_MG", "bolsterlee_dti/MG.stl", Architecture::unipennate, 9.9, 0.0510,
     "bolsterlee_dti/tracts_MG.txt", nullptr, "bolsterlee_dti/TA.stl"},
    {"bolsterlee_TA", "bolsterlee_dti/TA.stl", Architecture::bipennate, 9.6, 0.0683,
     "bolsterlee_dti/tracts_TA.txt", "bolsterlee_dti/TA_apo.stl"},
    // The posterior soleus, the largest part of the muscle, is unipennate between the anterior
    // and posterior aponeuroses (Agur et al. 2003, Clin Anat 16:285); docs/fibres.md.
    {"soleus_posterior", vh + "Muscle_Soleus_smooth.stl", Architecture::unipennate, 28.3, 0.0440,
     nullptr, nullptr},
};

void BM_ValidateArchitecture(benchmark::State& state) {
  const ArchitectureCase& c = architecture_cases[state.range(0)];
  const auto method = static_cast<FibreMethod>(state.range(1));
  const auto tmpl = static_cast<FibreTemplate>(state.range(2));
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  AponeurosisOptions ao;
  ao.architecture = c.architecture;
  ao.pennation_rad = c.pennation_deg * M_PI / 180;
  ao.insertion_face_towards = find_deep_direction(c, muscle);
  DecomposeOptions opt;
  opt.mapping.insertion_side_towards = ao.insertion_face_towards;
  opt.method = method;
  opt.fibre_template = tmpl;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = ao.pennation_rad;
  // Harmonic: third argument 0 = plain field on the aponeurosis areas, 1 = pennate field (angle to
  // the line of action), 2 = pennate field with the angle to the aponeurosis level sets; 3 and 4
  // = 1 and 2 turning in the thickness plane (HarmonicOptions::transverse_direction).
  const bool pennate_field = method == FibreMethod::harmonic && state.range(2) >= 1;
  const bool to_aponeurosis =
      method == FibreMethod::harmonic && (state.range(2) == 2 || state.range(2) == 4);
  const bool thickness_plane = method == FibreMethod::harmonic && state.range(2) >= 3;
  if (pennate_field) opt.harmonic.pennation_rad = ao.pennation_rad;
  if (to_aponeurosis)
    opt.harmonic.pennation_reference = HarmonicOptions::PennationReference::aponeurosis;
  TriMesh apo;
  if (c.aponeurosis) {
    apo = read_mesh(data / c.aponeurosis, LengthUnit::millimetre);
    ao.thickness_direction = calc_sheet_normal(apo);
    opt.mapping.thickness_direction = ao.thickness_direction;
  }
  Attachments areas = find_aponeurosis_attachments(muscle, ao);
  if (c.aponeurosis) set_interior_aponeurosis(muscle, apo, areas);
  if (thickness_plane) opt.harmonic.transverse_direction = areas.thickness_direction;
  // The template's box stays aligned with the muscle's ends (end regions); the harmonic method
  // takes the aponeurosis areas.
  const Attachments box_areas = find_end_attachments(muscle);
  const Attachments& used = method == FibreMethod::template_map ? box_areas : areas;
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, used, opt);
  const FibreAnalysis a = analyse_fibres(muscle, used, d.fibres);
  report_validation(state, a, c.ward_m, c.tracts ? data / c.tracts : std::filesystem::path(), d.fibres);
  const std::string variant = (method == FibreMethod::template_map ? to_string(tmpl)
                               : to_aponeurosis                     ? "pennate-field-to-aponeurosis"
                               : pennate_field                      ? "pennate-field"
                                                                    : "plain-field") +
                              std::string(thickness_plane ? "-thickness-plane" : "");
  state.SetLabel(std::string(c.name) + " " + to_string(d.method_used) + " " + variant + " " +
                 to_string(c.architecture));
}
BENCHMARK(BM_ValidateArchitecture)
    ->ArgsProduct({benchmark::CreateDenseRange(0, 7, 1), {0}, {0, 1, 2}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ValidateArchitecture)
    ->ArgsProduct({benchmark::CreateDenseRange(0, 7, 1), {1}, {0, 1, 2, 3, 4}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// Mean angle (deg) between each template fibre's chord (first to last point) and the box's z axis
// (the line of action): the pennation the mapped fibres make, to compare with the target.
double calc_chord_angle_deg(const FibreSet& fibres, const Vec3& axis) {
  double sum = 0.0;
  for (const Points3& P : fibres.fibres) {
    const Vec3 chord = P.row(P.rows() - 1) - P.row(0);
    sum += std::acos(std::min(1.0, std::abs(chord.normalized().dot(axis))));
  }
  return sum / static_cast<double>(fibres.size()) * 180 / M_PI;
}

// The pennation-derived rise with either crossing rule (argument 2: 0 mean thickness, the default;
// 1 mapped crossing): fibre length vs Ward and the pennation the fibres actually make.
void BM_ValidateRiseRule(benchmark::State& state) {
  const ArchitectureCase& c = architecture_cases[state.range(0)];
  const auto tmpl = static_cast<FibreTemplate>(state.range(1));
  const bool mapped = state.range(2) == 1;
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  DecomposeOptions opt;
  opt.fibre_template = tmpl;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = c.pennation_deg * M_PI / 180;
  opt.rise_crossing = mapped ? DecomposeOptions::RiseCrossing::mapped_crossing
                             : DecomposeOptions::RiseCrossing::mean_thickness;
  opt.mapping.insertion_side_towards = find_deep_direction(c, muscle);
  if (c.aponeurosis)
    opt.mapping.thickness_direction =
        calc_sheet_normal(read_mesh(data / c.aponeurosis, LengthUnit::millimetre));
  const Attachments areas = find_end_attachments(muscle);
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, areas, opt);
  const TemplateMapper mapper(muscle, areas, opt.mapping);
  const FibreAnalysis a = analyse_fibres(muscle, areas, d.fibres);
  report_validation(state, a, c.ward_m, c.tracts ? data / c.tracts : std::filesystem::path(), d.fibres);
  state.counters["target_deg"] = c.pennation_deg;
  state.counters["chord_angle_deg"] =
      calc_chord_angle_deg(d.fibres, mapper.get_box_frame().linear().col(2));
  state.counters["thickness_mm"] = mapper.get_mean_thickness() * 1e3;
  state.counters["crossing_mm"] = mapper.get_mean_crossing() * 1e3;
  state.SetLabel(std::string(c.name) + " " + to_string(tmpl) +
                 (mapped ? " mapped-crossing" : " mean-thickness"));
}
BENCHMARK(BM_ValidateRiseRule)
    ->ArgsProduct({benchmark::CreateDenseRange(0, 6, 1), {1, 2}, {0, 1}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// Face thickness (calc_face_thickness, the perpendicular distance a pennate fibre crosses) and
// the fibre length it implies with Ward's angle, t / sin(alpha) (t / (2 sin alpha) bipennate):
// the geometric consistency of Ward's (length, angle) pair with each image.
void BM_ThicknessConsistency(benchmark::State& state) {
  const ArchitectureCase& c = architecture_cases[state.range(0)];
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  AponeurosisOptions ao;
  if (c.aponeurosis)
    ao.thickness_direction = calc_sheet_normal(read_mesh(data / c.aponeurosis, LengthUnit::millimetre));
  double t = 0.0;
  for (auto _ : state) t = calc_face_thickness(muscle, ao);
  const double crossing = c.architecture == Architecture::bipennate ? 0.5 * t : t;
  const double alpha = c.pennation_deg * M_PI / 180;
  state.counters["face_thickness_mm"] = t * 1e3;
  state.counters["implied_len_mm"] = crossing / std::sin(alpha) * 1e3;
  state.counters["implied_ratio"] = crossing / std::sin(alpha) / c.ward_m;
  // The crossing Ward's pair implies: L sin(alpha).
  state.counters["ward_crossing_mm"] = c.ward_m * std::sin(alpha) * 1e3;
  state.SetLabel(std::string(c.name) + " " + to_string(c.architecture));
}
BENCHMARK(BM_ThicknessConsistency)
    ->DenseRange(0, 7, 1)
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// DTI with the pennation angle from the MRI muscle's own face thickness and Ward's fibre length,
// alpha = asin(t_f / L_Ward) (t_f = t unipennate, t/2 bipennate): independent of the tracts (not
// fitted to them); not usable for the Ward length check, which it would make circular.
// Also the mean angle per fifth of the tract segments along the principal axis (proximal first).
void BM_DtiThicknessPennation(benchmark::State& state) {
  const ArchitectureCase& c = architecture_cases[state.range(0)];
  // Optional third argument: the angle scaled by range(2) / 100 (BM_DtiHeldOutScale).
  const double scale = state.range(2) > 0 ? static_cast<double>(state.range(2)) / 100.0 : 1.0;
  // Optional fourth argument 1: the angle varies with the local crossing distance for Ward's
  // fibre length (HarmonicOptions::fibre_length_m; harmonic variants only).
  const bool local_angle = state.range(3) == 1;
  // Optional fifth argument 1: the fibres turn in the plane of the thickness direction
  // (HarmonicOptions::transverse_direction = the aponeurosis box's x; harmonic variants only);
  // 2: towards the tendon-side border of the interior aponeurosis (session 10,
  // HarmonicOptions::transverse_targets = find_aponeurosis_border; cases with an aponeurosis mesh).
  const bool thickness_plane = state.range(4) == 1;
  const bool sheet_border = state.range(4) == 2;
  // Variant: 0 template pennate, 1 pennate field (angle to the line of action), 2 pennate field
  // with the angle to the aponeurosis level sets (HarmonicOptions::pennation_reference).
  const bool harmonic = state.range(1) >= 1;
  const bool to_aponeurosis = state.range(1) == 2;
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  AponeurosisOptions ao;
  ao.architecture = c.architecture;
  ao.insertion_face_towards = find_deep_direction(c, muscle);
  TriMesh apo;
  if (c.aponeurosis) {
    apo = read_mesh(data / c.aponeurosis, LengthUnit::millimetre);
    ao.thickness_direction = calc_sheet_normal(apo);
  }
  const double t = calc_face_thickness(muscle, ao);
  const double crossing = c.architecture == Architecture::bipennate ? 0.5 * t : t;
  const double alpha = scale * std::asin(std::min(1.0, crossing / c.ward_m));
  ao.pennation_rad = alpha;
  DecomposeOptions opt;
  opt.method = harmonic ? FibreMethod::harmonic : FibreMethod::template_map;
  opt.fibre_template = FibreTemplate::pennate;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = alpha;
  opt.mapping.thickness_direction = ao.thickness_direction;
  opt.mapping.insertion_side_towards = ao.insertion_face_towards;
  Attachments areas;
  if (harmonic) {
    areas = find_aponeurosis_attachments(muscle, ao);
    if (c.aponeurosis) set_interior_aponeurosis(muscle, apo, areas);
    opt.harmonic.pennation_rad = alpha;
    if (local_angle) opt.harmonic.fibre_length_m = c.ward_m;
    if (thickness_plane) opt.harmonic.transverse_direction = areas.thickness_direction;
    if (sheet_border) {
      if (!c.aponeurosis) {
        state.SkipWithError("the sheet border needs an interior aponeurosis mesh");
        return;
      }
      opt.harmonic.transverse_targets =
          find_aponeurosis_border(muscle, areas.insertion_interior, areas.thickness_direction);
    }
    if (to_aponeurosis)
      opt.harmonic.pennation_reference = HarmonicOptions::PennationReference::aponeurosis;
  } else {
    areas = find_end_attachments(muscle);
  }
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, areas, opt);
  const FibreSet tracts = read_tracts(data / c.tracts, 1e-3);
  const DirectionDeviation dev = compare_directions(d.fibres, tracts);
  state.counters["face_thickness_mm"] = t * 1e3;
  state.counters["alpha_deg"] = alpha * 180 / M_PI;
  state.counters["dti_mean_deg"] = dev.mean_rad * 180 / M_PI;
  state.counters["dti_sd_deg"] = dev.stddev_rad * 180 / M_PI;
  double len = 0.0;
  for (const Points3& P : d.fibres.fibres) len += calc_polyline_length(P);
  state.counters["fibre_len_mm"] = len / static_cast<double>(d.fibres.size()) * 1e3;
  // Per fifth along the principal axis: tract segments as two-point polylines.
  const Vec3 ez = calc_principal_axis(muscle);
  const VecX z = muscle.V * ez;
  const double z_hi = z.maxCoeff(), extent = z_hi - z.minCoeff();
  FibreSet part[5];
  for (const Points3& T : tracts.fibres)
    for (Eigen::Index k = 1; k < T.rows(); ++k) {
      const Vec3 mid = 0.5 * (T.row(k) + T.row(k - 1));
      const int b = std::clamp(static_cast<int>((z_hi - mid.dot(ez)) / extent * 5), 0, 4);
      part[b].fibres.push_back(T.middleRows(k - 1, 2));
    }
  for (int b = 0; b < 5; ++b) {
    const std::string key = "dti_fifth" + std::to_string(b + 1);
    state.counters[key + "_deg"] =
        part[b].size() ? compare_directions(d.fibres, part[b]).mean_rad * 180 / M_PI : -1.0;
    state.counters[key + "_n"] = static_cast<double>(part[b].size());
  }
  state.SetLabel(std::string(c.name) +
                 (!harmonic        ? " template pennate"
                  : to_aponeurosis ? " pennate-field (to aponeurosis)"
                                   : " pennate-field") +
                 (thickness_plane ? ", thickness plane" : sheet_border ? ", sheet border" : ""));
}
BENCHMARK(BM_DtiThicknessPennation)
    ->ArgsProduct({{5, 6}, {0, 1, 2}, {0}, {0}, {0}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
// The fibres turning in the plane of the thickness direction (session 9, DTI error map).
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiThicknessPlane")
    ->ArgsProduct({{5, 6}, {1, 2}, {0}, {0}, {1}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
// The TA's fibres turning towards the tendon-side border of its central aponeurosis (session 10;
// the MG has no interior aponeurosis: docs/fibres.md).
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiSheetBorder")
    ->ArgsProduct({{6}, {1, 2}, {0}, {0}, {2}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
// The held-out scale with the TA's sheet border (the MG keeps the thickness plane,
// BM_DtiHeldOutScalePlane).
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiHeldOutScaleBorder")
    ->ArgsProduct({{6}, {1}, {100, 115, 130, 145, 160}, {0}, {2}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
// Held-out check of a tract-chosen correction: the thickness-derived angle scaled by 0.85 ... 1.45;
// the scale is chosen on the MG (case 5) and tested on the TA (case 6), never the other way.
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiHeldOutScale")
    ->ArgsProduct({{5, 6}, {1, 2}, {85, 100, 115, 130, 145}, {0}, {0}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);
// The same held-out check with the fibres turning in the thickness plane (session 9).
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiHeldOutScalePlane")
    ->ArgsProduct({{5, 6}, {1}, {100, 115, 130, 145, 160}, {0}, {1}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// Pennate fields whose angle follows the local crossing distance for Ward's fibre length
// (planimetric model, sin a = t / L; not fitted to the tracts).
BENCHMARK(BM_DtiThicknessPennation)
    ->Name("BM_DtiLocalPennation")
    ->ArgsProduct({{5, 6}, {1, 2}, {0}, {1}, {0}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// Sensitivity of the DTI deviation to the pennation angle (not a validation: the angle is swept,
// not fitted). Arguments: case (5 MG, 6 TA), variant (0 template pennate, 1 pennate harmonic
// field), pennation angle in degrees.
void BM_DtiPennationSweep(benchmark::State& state) {
  const ArchitectureCase& c = architecture_cases[state.range(0)];
  const bool harmonic = state.range(1) == 1;
  const double alpha = static_cast<double>(state.range(2)) * M_PI / 180;
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  AponeurosisOptions ao;
  ao.architecture = c.architecture;
  ao.pennation_rad = alpha;
  ao.insertion_face_towards = find_deep_direction(c, muscle);
  DecomposeOptions opt;
  opt.mapping.insertion_side_towards = ao.insertion_face_towards;
  opt.method = harmonic ? FibreMethod::harmonic : FibreMethod::template_map;
  opt.fibre_template = FibreTemplate::pennate;
  opt.count = 100;
  opt.resolution = 16;
  opt.pennation_rad = alpha;
  TriMesh apo;
  if (c.aponeurosis) {
    apo = read_mesh(data / c.aponeurosis, LengthUnit::millimetre);
    ao.thickness_direction = calc_sheet_normal(apo);
    opt.mapping.thickness_direction = ao.thickness_direction;
  }
  Attachments areas;
  if (harmonic) {
    areas = find_aponeurosis_attachments(muscle, ao);
    if (c.aponeurosis) set_interior_aponeurosis(muscle, apo, areas);
    opt.harmonic.pennation_rad = alpha;
  } else {
    areas = find_end_attachments(muscle);
  }
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, areas, opt);
  const DirectionDeviation dev = compare_directions(d.fibres, read_tracts(data / c.tracts, 1e-3));
  state.counters["dti_mean_deg"] = dev.mean_rad * 180 / M_PI;
  state.counters["dti_median_deg"] = dev.median_rad * 180 / M_PI;
  state.SetLabel(std::string(c.name) + (harmonic ? " pennate-field" : " template pennate"));
}
BENCHMARK(BM_DtiPennationSweep)
    ->ArgsProduct({{5, 6}, {0, 1}, {5, 10, 15, 20, 25, 30}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

// The tracts' own consistency, a floor for any field compared with them: each half of the
// tracts (even / odd lines) compared with the other half by the same measure as the fibres
// (compare_directions: every tract segment against the nearest point of the other half).
void BM_DtiTractFloor(benchmark::State& state) {
  const char* file = state.range(0) == 0 ? "bolsterlee_dti/tracts_MG.txt" : "bolsterlee_dti/tracts_TA.txt";
  const FibreSet tracts = read_tracts(data / file, 1e-3);
  FibreSet even, odd;
  for (std::size_t i = 0; i < tracts.size(); ++i) (i % 2 ? odd : even).fibres.push_back(tracts.fibres[i]);
  DirectionDeviation a, b;
  for (auto _ : state) {
    a = compare_directions(odd, even);
    b = compare_directions(even, odd);
  }
  state.counters["tracts"] = static_cast<double>(tracts.size());
  state.counters["odd_vs_even_deg"] = a.mean_rad * 180 / M_PI;
  state.counters["even_vs_odd_deg"] = b.mean_rad * 180 / M_PI;
  state.counters["sd_deg"] = a.stddev_rad * 180 / M_PI;
  state.SetLabel(state.range(0) == 0 ? "MG" : "TA");
}
BENCHMARK(BM_DtiTractFloor)->Arg(0)->Arg(1)->Iterations(1)->Unit(benchmark::kMillisecond);

// DTI and fibre length of the plain harmonic field (default end regions) with the volume seeds
// alone (factor 1, the session-6 default) and with fibres chosen among 4 x volume candidates plus
// area candidates (the session-7 default). Arguments: case (5 MG, 6 TA), factor.
void BM_DtiHarmonicCandidates(benchmark::State& state) {
  const ValidationCase& c = validation_cases[state.range(0)];
  const TriMesh muscle = read_mesh(data / c.mesh, LengthUnit::millimetre);
  const Attachments areas = find_end_attachments(muscle);
  DecomposeOptions opt;
  opt.method = FibreMethod::harmonic;
  opt.count = 100;
  opt.resolution = 16;
  opt.harmonic_candidate_factor = static_cast<int>(state.range(1));
  if (state.range(1) == 1) opt.harmonic_area_candidate_factor = 0;
  Decomposition d;
  for (auto _ : state) d = decompose_muscle(muscle, areas, opt);
  const FibreAnalysis a = analyse_fibres(muscle, areas, d.fibres);
  report_validation(state, a, c.ward_m, data / c.tracts, d.fibres);
  state.SetLabel(std::string(c.name) + " factor " + std::to_string(state.range(1)));
}
BENCHMARK(BM_DtiHarmonicCandidates)
    ->ArgsProduct({{5, 6}, {1, 4, 8}})
    ->Iterations(1)
    ->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
