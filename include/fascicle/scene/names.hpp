// Name suggestions for error messages ("did you mean 'soleus'?").
#pragma once

#include <string>
#include <string_view>
#include <vector>

namespace fascicle {

// Levenshtein edit distance (case-insensitive).
int calc_edit_distance(std::string_view a, std::string_view b);

// The candidate closest to `name`, or "" when none is reasonably close (distance > max(2, |name|/2)).
std::string find_nearest_name(std::string_view name, const std::vector<std::string>& candidates);

// A suggestion sentence: "did you mean 'x'? valid names: a, b, c" (list truncated after 12).
std::string make_name_suggestion(std::string_view name, const std::vector<std::string>& candidates);

}  // namespace fascicle
