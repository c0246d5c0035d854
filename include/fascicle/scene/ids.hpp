// Strong index types of the scene model. Names are resolved to these once, in compile().
#pragma once

#include <cstdint>

namespace fascicle {

template <class Tag>
struct StrongIndex {
  int32_t v = -1;
  constexpr bool valid() const { return v >= 0; }
  constexpr friend bool operator==(StrongIndex a, StrongIndex b) { return a.v == b.v; }
  constexpr friend bool operator<(StrongIndex a, StrongIndex b) { return a.v < b.v; }
};

using BodyIndex = StrongIndex<struct BodyTag>;
using JointIndex = StrongIndex<struct JointTag>;
using CoordinateIndex = StrongIndex<struct CoordinateTag>;
using MuscleIndex = StrongIndex<struct MuscleTag>;

}  // namespace fascicle
