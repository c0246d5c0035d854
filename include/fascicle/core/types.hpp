// Eigen type aliases used across fascicle. All quantities are SI (m, kg, s, N, rad) and double.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace fascicle {

using Vec2 = Eigen::Vector2d;
using Vec3 = Eigen::Vector3d;
using Vec4 = Eigen::Vector4d;
using Mat3 = Eigen::Matrix3d;
using Mat4 = Eigen::Matrix4d;
using VecX = Eigen::VectorXd;
using MatX = Eigen::MatrixXd;
using Quat = Eigen::Quaterniond;
// A rigid transform X_AB maps points given in frame B to frame A (Simbody's convention).
using Transform = Eigen::Isometry3d;

// Per-vertex / per-face arrays in libigl's layout: one row per element.
using Points3 = Eigen::Matrix<double, Eigen::Dynamic, 3>;
using Triangles = Eigen::Matrix<int, Eigen::Dynamic, 3>;

}  // namespace fascicle
