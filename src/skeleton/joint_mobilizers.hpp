// Private to the skeleton module (included from its .cpp files only; it includes Simbody).
// Joints whose motion is not a CustomJoint spatial transform, built as Simbody
// MobilizedBody::Custom mobilizers with u = q̇ (see joint_mobilizers.cpp and docs/skeleton.md).
#pragma once

#include <Simbody.h>

#include "fascicle/skeleton/skeleton.hpp"

namespace fascicle::detail {

// X_F_M(q) of an ellipsoid or scapulothoracic joint (q has 3 or 4 entries), in Eigen types.
Transform calc_ellipsoid_joint_transform(const JointSpec& joint, const double* q);

// Adds a MobilizedBody::Custom for an ellipsoid or scapulothoracic joint and returns its index.
SimTK::MobilizedBodyIndex add_ellipsoid_mobilizer(SimTK::SimbodyMatterSubsystem& matter,
                                                  SimTK::MobilizedBody& parent,
                                                  const SimTK::Transform& X_PF,
                                                  const SimTK::Body& body,
                                                  const SimTK::Transform& X_BM,
                                                  const JointSpec& joint);

}  // namespace fascicle::detail
