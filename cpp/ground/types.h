// Point clouds and planes shared by the ground stage.
#pragma once

#include <Eigen/Core>

namespace m3c::ground {

// N x 3 points, one per row, metres (any fixed frame: camera or world).
using Points3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using PointsRef = Eigen::Ref<const Points3>;

// The plane {x : normal . x + offset = 0} with a unit normal oriented "up" (normal . up > 0).
// normal . x + offset is the signed height of x above the plane, so offset is the height of the frame's origin
// (for camera-frame points: the camera's height above the ground).
struct Plane {
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  double offset = 0.0;

  double SignedDistance(const Eigen::Vector3d& x) const { return normal.dot(x) + offset; }
};

}  // namespace m3c::ground
