// Scene files (JSON, docs/scene-format.md): loading into a SceneSpec, validated against the
// schema of get_scene_schema() first. Every error is a fascicle::Error (bad_input) naming the file
// and the JSON pointer of the offending value, with a suggestion.
#pragma once

#include "fascicle/scene/registry.hpp"
#include "fascicle/scene/scene_spec.hpp"
#include "fascicle/scene/schema.hpp"

#include <filesystem>
#include <string>

namespace fascicle {

// The schema of a scene file; joint types, muscle representations, actuators and writers are
// enumerations of the names registered in `registry`.
SchemaNode get_scene_schema(const Registry& registry);

// Reads and validates a scene file; meshes and motion files are relative to the file's folder.
// Mesh files are read (read_mesh) and scaled from the file's "units" to metres.
SceneSpec load_scene(const std::filesystem::path& path, const Registry& registry);

// The same from JSON text; `path` names the file in messages and gives the folder for relative
// paths.
SceneSpec parse_scene(const std::string& text, const std::filesystem::path& path, const Registry& registry);

}  // namespace fascicle
