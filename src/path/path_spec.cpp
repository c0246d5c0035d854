// Parsing and printing of the small enums of path_spec.hpp.
#include "fascicle/path/path_spec.hpp"

#include <cctype>

#include "fascicle/core/error.hpp"

namespace fascicle {
namespace {

// Lower-case copy without blanks.
std::string normalised(std::string_view text) {
  std::string out;
  for (char c : text) {
    if (!std::isspace(static_cast<unsigned char>(c))) {
      out.push_back(static_cast<char>(std::tolower(static_cast<unsigned char>(c))));
    }
  }
  return out;
}

}  // namespace

WrapQuadrant parse_wrap_quadrant(std::string_view text) {
  const std::string t = normalised(text);
  if (t == "all" || t.empty()) return WrapQuadrant::all;
  if (t == "x" || t == "+x") return WrapQuadrant::pos_x;
  if (t == "-x") return WrapQuadrant::neg_x;
  if (t == "y" || t == "+y") return WrapQuadrant::pos_y;
  if (t == "-y") return WrapQuadrant::neg_y;
  if (t == "z" || t == "+z") return WrapQuadrant::pos_z;
  if (t == "-z") return WrapQuadrant::neg_z;
  throw_bad_input("unknown wrap quadrant '" + std::string(text) + "'",
                  {.suggestion = "use all, +x, -x, +y, -y, +z or -z"});
}

std::string to_string(WrapQuadrant quadrant) {
  switch (quadrant) {
    case WrapQuadrant::all: return "all";
    case WrapQuadrant::pos_x: return "+x";
    case WrapQuadrant::neg_x: return "-x";
    case WrapQuadrant::pos_y: return "+y";
    case WrapQuadrant::neg_y: return "-y";
    case WrapQuadrant::pos_z: return "+z";
    case WrapQuadrant::neg_z: return "-z";
  }
  return "all";
}

WrapMethod parse_wrap_method(std::string_view text) {
  const std::string t = normalised(text);
  if (t == "hybrid" || t.empty()) return WrapMethod::hybrid;
  if (t == "midpoint") return WrapMethod::midpoint;
  if (t == "axial") return WrapMethod::axial;
  throw_bad_input("unknown wrap method '" + std::string(text) + "'",
                  {.suggestion = "use hybrid, midpoint or axial"});
}

CoordinateFunction constant_function(double value) {
  return {.coordinate = {},
          .value = [value](double) { return value; },
          .slope = [](double) { return 0.0; }};
}

}  // namespace fascicle
