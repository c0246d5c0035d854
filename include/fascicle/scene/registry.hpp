// The plug-in registry (DANCE-style, seed 000 §6): each object kind — joint types, muscle
// representations, actuators, wrap surfaces, writers — maps a name to a factory. A Registry is a
// plain object owned by the application and passed to compile() and the driver; there is no
// global registry. register_builtins() adds the kinds fascicle ships; a program (or a test) adds
// its own kinds with `registry.muscle_representations.add("mine", factory)` and uses them from a
// scene file without changing fascicle.
#pragma once

#include "fascicle/core/error.hpp"
#include "fascicle/core/types.hpp"
#include "fascicle/geometry/tri_mesh.hpp"
#include "fascicle/musculotendon/muscle.hpp"
#include "fascicle/scene/ids.hpp"
#include "fascicle/scene/scene_spec.hpp"
#include "fascicle/skeleton/skeleton.hpp"

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

namespace fascicle {

struct Model;
struct State;
struct MuscleFrame;

// A joint type turns the scene's description of a joint into a joint of the skeleton module
// (fascicle/skeleton/skeleton.hpp), which poses the bodies (Simbody). A plug-in kind can build any
// skeleton joint, e.g. an OpenSim-style custom joint with coordinate functions.
using JointFactory = std::function<JointSpec(const SceneJointSpec&)>;

// Mutable per-muscle data a representation carries from frame to frame (a prefactorised solver,
// the previous frame's solution as a warm start). Created by MuscleRepresentation::make_state()
// when a State is made; owned by that State (State::representation_states).
class RepresentationState {
 public:
  virtual ~RepresentationState() = default;
};

// What a muscle looks like at a frame: given the posed bodies and the muscle's action line
// (State stage >= action lines), fill `out.surface` (and optionally `out.fibres`, `out.volume_m3`
// and the other geometric metrics of MuscleFrame). Constructed in compile() once the bodies,
// joints, attachments and default pose are known; immutable afterwards, so one Model can drive
// several States. Frame-to-frame data lives in `rs`, what make_state() returned (may be null).
class MuscleRepresentation {
 public:
  virtual ~MuscleRepresentation() = default;
  // The per-run state of this muscle (null: the representation keeps none).
  virtual std::unique_ptr<RepresentationState> make_state() const { return nullptr; }
  virtual void calc_geometry(const Model& model, MuscleIndex muscle, const State& state,
                             RepresentationState* rs, MuscleFrame& out) const = 0;
};
using MuscleRepresentationFactory = std::function<std::unique_ptr<const MuscleRepresentation>(
    const Model& model, MuscleIndex muscle)>;

// A representation that solves several muscles together (e.g. fibres-first, whose muscles push
// each other apart): compile() gives it every muscle of the scene that names it, once. Per frame
// calc_geometry() fills those muscles' MuscleFrames (after the per-muscle representations).
class MuscleGroupRepresentation {
 public:
  virtual ~MuscleGroupRepresentation() = default;
  virtual std::unique_ptr<RepresentationState> make_state() const { return nullptr; }
  // The surface the group draws for member k at rest, when it is not the muscle's own mesh (the
  // Model then holds this one as the muscle's rest mesh, so frames' surfaces match its rows).
  virtual const TriMesh* get_rest_surface(int /*member*/) const { return nullptr; }
  // out[k] is the frame of member k (muscles[k]).
  virtual void calc_geometry(const Model& model, const std::vector<MuscleIndex>& muscles, const State& state,
                             RepresentationState* rs, const std::vector<MuscleFrame*>& out) const = 0;
};
using MuscleGroupFactory = std::function<std::unique_ptr<const MuscleGroupRepresentation>(
    const Model& model, const std::vector<MuscleIndex>& muscles)>;

// Force generation of a musculotendon unit from its path length (static equilibrium at zero
// lengthening speed for the built-in "hill").
class Actuator {
 public:
  virtual ~Actuator() = default;
  virtual MuscleOutputs calc_outputs(double activation, double musculotendon_length_m) const = 0;
};
using ActuatorFactory = std::function<std::unique_ptr<const Actuator>(const MuscleSpec&)>;

// A rigid obstacle a path wraps over: the shortest path from a to b around the surface (both in
// the surface's frame), as a polyline including a and b.
class WrapSurface {
 public:
  virtual ~WrapSurface() = default;
  virtual Points3 calc_wrapped_path(const Vec3& a, const Vec3& b) const = 0;
};
using WrapSurfaceFactory =
    std::function<std::unique_ptr<const WrapSurface>(const std::map<std::string, double>& options)>;

// Receives the State of every frame (after forward()) and writes it somewhere. begin() is called
// once before the first frame, finish() after the last frame or after a failure (so whatever was
// written stays valid).
struct RunInfo {
  std::filesystem::path out_dir;
  std::string basename = "scene";  // file stem for series and tables
  int num_frames = 0;
  double frame_rate_hz = 0.0;
};
// write_frame runs on a worker thread beside the solves of the next frame (run_frames pipelines
// frames), one frame at a time and in frame order. Its State holds that frame's time, coordinates,
// activations, body poses, muscles and overlaps (stage geometry); it has no skeleton state and no
// representation states, which belong to the solver and have already moved on.
class FrameWriter {
 public:
  virtual ~FrameWriter() = default;
  virtual void begin(const Model& model, const RunInfo& info) = 0;
  virtual void write_frame(const Model& model, const State& state, int frame) = 0;
  virtual void finish(const Model& model) = 0;
  // Files written, for the user (relative or absolute paths).
  virtual std::vector<std::filesystem::path> get_outputs() const = 0;
};
using WriterFactory = std::function<std::unique_ptr<FrameWriter>()>;

// Name → factory for one kind of object.
template <class Factory>
class FactoryTable {
 public:
  explicit FactoryTable(std::string kind) : kind_(std::move(kind)) {}

  // Adds a kind; throws a usage error if the name is taken (remove it first to replace it).
  void add(const std::string& name, Factory factory) {
    if (table_.count(name)) throw_usage(kind_ + " '" + name + "' is already registered");
    table_.emplace(name, std::move(factory));
  }
  void remove(const std::string& name) { table_.erase(name); }
  const Factory* find(const std::string& name) const {
    const auto it = table_.find(name);
    return it == table_.end() ? nullptr : &it->second;
  }
  // The factory, or a bad-input error naming the kind and suggesting the nearest registered name.
  const Factory& get(const std::string& name, ErrorContext where = {}) const;
  std::vector<std::string> get_names() const {
    std::vector<std::string> names;
    for (const auto& [name, f] : table_) names.push_back(name);
    return names;
  }
  const std::string& get_kind() const { return kind_; }

 private:
  std::string kind_;
  std::map<std::string, Factory> table_;
};

struct Registry {
  FactoryTable<JointFactory> joint_types{"joint type"};
  FactoryTable<MuscleRepresentationFactory> muscle_representations{"muscle representation"};
  FactoryTable<MuscleGroupFactory> muscle_groups{"muscle group representation"};
  FactoryTable<ActuatorFactory> actuators{"actuator"};
  FactoryTable<WrapSurfaceFactory> wrap_surfaces{"wrap surface"};
  FactoryTable<WriterFactory> writers{"writer"};

  // Names a muscle's "representation" may take: per-muscle and group representations.
  std::vector<std::string> get_representation_names() const;
  // Throws bad input naming the unknown representation and suggesting the nearest name.
  void check_representation(const std::string& name, ErrorContext where = {}) const;
};

// Joint types "weld", "pin" (alias "hinge"), "slider", "free"; muscle representations
// "surface_first" (alias "surface-first"), "blended_surface", "action_line"; the group
// representation "fibres_first" (alias "fibres-first"); actuators "hill", "none"; writers "paraview", "sto", "csv".
void register_builtins(Registry& registry);

// A registry with the built-ins.
Registry make_default_registry();

[[noreturn]] void throw_unknown_name(const std::string& kind, const std::string& name,
                                     const std::vector<std::string>& valid, ErrorContext where);

template <class Factory>
const Factory& FactoryTable<Factory>::get(const std::string& name, ErrorContext where) const {
  if (const Factory* f = find(name)) return *f;
  throw_unknown_name(kind_, name, get_names(), std::move(where));
}

}  // namespace fascicle
