#include "fascicle/scene/names.hpp"

#include <algorithm>
#include <cctype>

namespace fascicle {

int calc_edit_distance(std::string_view a, std::string_view b) {
  std::vector<int> prev(b.size() + 1), cur(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) prev[j] = static_cast<int>(j);
  for (size_t i = 1; i <= a.size(); ++i) {
    cur[0] = static_cast<int>(i);
    for (size_t j = 1; j <= b.size(); ++j) {
      const bool same = std::tolower(static_cast<unsigned char>(a[i - 1])) ==
                        std::tolower(static_cast<unsigned char>(b[j - 1]));
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + (same ? 0 : 1)});
    }
    std::swap(prev, cur);
  }
  return prev[b.size()];
}

std::string find_nearest_name(std::string_view name, const std::vector<std::string>& candidates) {
  std::string best;
  int best_d = std::max<int>(2, static_cast<int>(name.size()) / 2) + 1;
  for (const auto& c : candidates) {
    const int d = calc_edit_distance(name, c);
    if (d < best_d) {
      best_d = d;
      best = c;
    }
  }
  return best;
}

std::string make_name_suggestion(std::string_view name, const std::vector<std::string>& candidates) {
  std::string text;
  const std::string nearest = find_nearest_name(name, candidates);
  if (!nearest.empty()) text = "did you mean '" + nearest + "'? ";
  if (candidates.empty()) return text + "nothing is valid here";
  text += "valid: ";
  for (size_t i = 0; i < candidates.size() && i < 12; ++i) text += (i ? ", " : "") + candidates[i];
  if (candidates.size() > 12) text += ", ...";
  return text;
}

}  // namespace fascicle
