// A small declarative JSON schema, expressed in code: object keys with their types, required or
// optional, enumerations, arrays, numeric bounds and references by name to other items of the
// document. validate_json() reports the first violation as a fascicle::Error (bad_input) naming
// the file and the JSON pointer of the offending value (e.g. "/muscles/2/origin/body") with a
// suggestion (the nearest valid key or name).
#pragma once

#include <nlohmann/json_fwd.hpp>

#include <map>
#include <optional>
#include <string>
#include <vector>

namespace fascicle {

enum class JsonType { object, array, string, number, integer, boolean, vec3, any };

struct SchemaField;

struct SchemaNode {
  JsonType type = JsonType::any;
  std::vector<SchemaField> fields;       // object: the allowed keys (others are errors)
  std::vector<SchemaNode> items;         // array: one node, the type of every element; object:
                                         // when set, any key, each value of this type (a map)
  std::vector<std::string> enum_values;  // string: the allowed values (empty: any)
  std::string ref;                       // string: must name an item of this kind (NameTable)
  std::optional<double> min, max;        // number/integer: closed bounds
  std::optional<size_t> min_items;       // array: minimum length
};

struct SchemaField {
  std::string key;
  bool required = false;
  SchemaNode node;
};

// Names that references may point to, by kind (e.g. "body" → {"ground", "femur", ...}).
using NameTable = std::map<std::string, std::vector<std::string>>;

// Throws fascicle::Error (bad_input) with .file = file and .json_path = the JSON pointer.
void validate_json(const nlohmann::json& value, const SchemaNode& schema, const NameTable& names,
                   const std::string& file);

// Builders that keep schemas readable.
namespace schema {
SchemaNode object(std::vector<SchemaField> fields);
SchemaNode array(SchemaNode item, size_t min_items = 0);
SchemaNode map(SchemaNode value);  // an object with any keys whose values all match `value`
SchemaNode string();
SchemaNode one_of(std::vector<std::string> values);
SchemaNode reference(std::string kind);
SchemaNode number(std::optional<double> min = std::nullopt, std::optional<double> max = std::nullopt);
SchemaNode integer(std::optional<double> min = std::nullopt, std::optional<double> max = std::nullopt);
SchemaNode boolean();
SchemaNode vec3();
SchemaNode any();
SchemaField required(std::string key, SchemaNode node);
SchemaField optional(std::string key, SchemaNode node);
}  // namespace schema

// A JSON pointer token escaped per RFC 6901 ("~" → "~0", "/" → "~1").
std::string escape_json_pointer(const std::string& token);

}  // namespace fascicle
