#include "fascicle/scene/schema.hpp"

#include "fascicle/core/error.hpp"
#include "fascicle/scene/names.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

namespace fascicle {

std::string escape_json_pointer(const std::string& token) {
  std::string out;
  for (char c : token) {
    if (c == '~')
      out += "~0";
    else if (c == '/')
      out += "~1";
    else
      out += c;
  }
  return out;
}

namespace {

const char* type_name(JsonType t) {
  switch (t) {
    case JsonType::object: return "an object";
    case JsonType::array: return "an array";
    case JsonType::string: return "a string";
    case JsonType::number: return "a number";
    case JsonType::integer: return "an integer";
    case JsonType::boolean: return "true or false";
    case JsonType::vec3: return "an array of 3 numbers";
    case JsonType::any: return "any value";
  }
  return "?";
}

std::string describe(const nlohmann::json& v) {
  std::string text = v.dump();
  if (text.size() > 40) text = text.substr(0, 37) + "...";
  return std::string(v.type_name()) + " " + text;
}

struct Validator {
  const NameTable& names;
  const std::string& file;

  [[noreturn]] void fail(const std::string& path, const std::string& message, std::string suggestion = {}) const {
    throw_bad_input(message,
                    {.file = file, .json_path = path.empty() ? "/" : path, .suggestion = std::move(suggestion)});
  }

  bool has_type(const nlohmann::json& v, JsonType t) const {
    switch (t) {
      case JsonType::object: return v.is_object();
      case JsonType::array: return v.is_array();
      case JsonType::string: return v.is_string();
      case JsonType::number: return v.is_number();
      case JsonType::integer: return v.is_number_integer();
      case JsonType::boolean: return v.is_boolean();
      case JsonType::vec3:
        return v.is_array() && v.size() == 3 &&
               std::all_of(v.begin(), v.end(), [](const nlohmann::json& x) { return x.is_number(); });
      case JsonType::any: return true;
    }
    return false;
  }

  void check(const nlohmann::json& v, const SchemaNode& s, const std::string& path) const {
    if (!has_type(v, s.type)) fail(path, std::string("expected ") + type_name(s.type) + ", got " + describe(v));
    if (s.type == JsonType::number || s.type == JsonType::integer) {
      const double x = v.get<double>();
      if (!std::isfinite(x)) fail(path, "number is not finite");
      if (s.min && x < *s.min) fail(path, "value " + v.dump() + " is below the minimum " + std::to_string(*s.min));
      if (s.max && x > *s.max) fail(path, "value " + v.dump() + " is above the maximum " + std::to_string(*s.max));
    }
    if (s.type == JsonType::string) {
      const std::string& text = v.get_ref<const std::string&>();
      if (!s.enum_values.empty() &&
          std::find(s.enum_values.begin(), s.enum_values.end(), text) == s.enum_values.end())
        fail(path, "'" + text + "' is not one of the allowed values", make_name_suggestion(text, s.enum_values));
      if (!s.ref.empty()) {
        const auto it = names.find(s.ref);
        static const std::vector<std::string> none;
        const auto& valid = it == names.end() ? none : it->second;
        if (std::find(valid.begin(), valid.end(), text) == valid.end())
          fail(path, "unknown " + s.ref + " '" + text + "'", make_name_suggestion(text, valid));
      }
    }
    if (s.type == JsonType::array && !s.items.empty()) {
      if (s.min_items && v.size() < *s.min_items)
        fail(path, "expected at least " + std::to_string(*s.min_items) + " elements, got " + std::to_string(v.size()));
      for (size_t i = 0; i < v.size(); ++i) check(v[i], s.items.front(), path + "/" + std::to_string(i));
    }
    if (s.type == JsonType::object && !s.items.empty()) {  // a map: any key, typed values
      for (const auto& [key, value] : v.items()) check(value, s.items.front(), path + "/" + escape_json_pointer(key));
    } else if (s.type == JsonType::object) {
      std::vector<std::string> keys;
      for (const auto& f : s.fields) keys.push_back(f.key);
      for (const auto& [key, value] : v.items()) {
        const auto f = std::find_if(s.fields.begin(), s.fields.end(), [&](const SchemaField& x) { return x.key == key; });
        if (f == s.fields.end())
          fail(path + "/" + escape_json_pointer(key), "unknown key '" + key + "'", make_name_suggestion(key, keys));
      }
      for (const auto& f : s.fields) {
        const std::string sub = path + "/" + escape_json_pointer(f.key);
        if (!v.contains(f.key)) {
          if (f.required) fail(sub, "missing required key '" + f.key + "'", std::string("add \"") + f.key + "\": <" + type_name(f.node.type) + ">");
          continue;
        }
        check(v.at(f.key), f.node, sub);
      }
    }
  }
};

}  // namespace

void validate_json(const nlohmann::json& value, const SchemaNode& schema, const NameTable& names,
                   const std::string& file) {
  Validator{names, file}.check(value, schema, "");
}

namespace schema {
SchemaNode object(std::vector<SchemaField> fields) {
  SchemaNode n;
  n.type = JsonType::object;
  n.fields = std::move(fields);
  return n;
}
SchemaNode array(SchemaNode item, size_t min_items) {
  SchemaNode n;
  n.type = JsonType::array;
  n.items.push_back(std::move(item));
  if (min_items > 0) n.min_items = min_items;
  return n;
}

SchemaNode map(SchemaNode value) {
  SchemaNode n;
  n.type = JsonType::object;
  n.items.push_back(std::move(value));
  return n;
}
SchemaNode string() { return SchemaNode{.type = JsonType::string}; }
SchemaNode one_of(std::vector<std::string> values) {
  SchemaNode n = string();
  n.enum_values = std::move(values);
  return n;
}
SchemaNode reference(std::string kind) {
  SchemaNode n = string();
  n.ref = std::move(kind);
  return n;
}
SchemaNode number(std::optional<double> min, std::optional<double> max) {
  SchemaNode n{.type = JsonType::number};
  n.min = min;
  n.max = max;
  return n;
}
SchemaNode integer(std::optional<double> min, std::optional<double> max) {
  SchemaNode n = number(min, max);
  n.type = JsonType::integer;
  return n;
}
SchemaNode boolean() { return SchemaNode{.type = JsonType::boolean}; }
SchemaNode vec3() { return SchemaNode{.type = JsonType::vec3}; }
SchemaNode any() { return SchemaNode{}; }
SchemaField required(std::string key, SchemaNode node) { return {std::move(key), true, std::move(node)}; }
SchemaField optional(std::string key, SchemaNode node) { return {std::move(key), false, std::move(node)}; }
}  // namespace schema

}  // namespace fascicle
