#include "fascicle/core/units.hpp"

#include "fascicle/core/error.hpp"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>

namespace fascicle {

double metres_per(LengthUnit unit) {
  switch (unit) {
    case LengthUnit::metre: return 1.0;
    case LengthUnit::centimetre: return 1e-2;
    case LengthUnit::millimetre: return 1e-3;
  }
  return 1.0;
}

LengthUnit parse_length_unit(std::string_view text) {
  std::string t(text);
  std::transform(t.begin(), t.end(), t.begin(), [](unsigned char c) { return std::tolower(c); });
  if (t == "m" || t == "metre" || t == "meter") return LengthUnit::metre;
  if (t == "cm") return LengthUnit::centimetre;
  if (t == "mm") return LengthUnit::millimetre;
  throw_usage("unknown length unit '" + std::string(text) + "'",
              {.suggestion = "use m, cm or mm"});
}

double parse_length(std::string_view text) {
  std::size_t i = 0;
  while (i < text.size() && std::isspace(static_cast<unsigned char>(text[i]))) ++i;
  double value = 0.0;
  const char* first = text.data() + i;
  const char* last = text.data() + text.size();
  auto [ptr, ec] = std::from_chars(first, last, value);
  if (ec != std::errc() || !std::isfinite(value)) {
    throw_usage("'" + std::string(text) + "' is not a length", {.suggestion = "write e.g. 2mm or 0.002"});
  }
  std::string_view rest(ptr, static_cast<std::size_t>(last - ptr));
  while (!rest.empty() && std::isspace(static_cast<unsigned char>(rest.front()))) rest.remove_prefix(1);
  if (rest.empty()) return value;
  return value * metres_per(parse_length_unit(rest));
}

std::string to_string(LengthUnit unit) {
  switch (unit) {
    case LengthUnit::metre: return "m";
    case LengthUnit::centimetre: return "cm";
    case LengthUnit::millimetre: return "mm";
  }
  return "m";
}

}  // namespace fascicle
