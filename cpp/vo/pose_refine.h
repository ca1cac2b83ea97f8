// Motion-only refinement of one camera against fixed homogeneous world points (the non-keyframe poses after the
// final bundle adjustment, and the rotation-only fit of a near-static camera). Small dense Levenberg-Marquardt
// with iteratively reweighted Cauchy weights; the same left retraction as the bundle adjustment.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "util/pinhole.h"
#include "vo/rigid3.h"

namespace m3c::vo {

struct PoseRefineOptions {
  bool rotation_only = false;  // solve the rotation only, the translation stays as given
  double loss_scale_px = 1.5;  // Cauchy scale
  int max_iterations = 10;
};

struct PoseRefineResult {
  Rigid3 cam_from_world;
  int iterations = 0;
  double rms_px = 0.0;  // unweighted reprojection RMS over all points at the result
  bool improved = false;  // the cost went down from the initial pose
};

// points_in_world: homogeneous (x, y, z, w); w = 0 is a point at infinity. observed_uv: pixels, one per point.
PoseRefineResult RefinePose(const Intrinsics& K, const std::vector<Eigen::Vector4d>& points_in_world,
                            const std::vector<Eigen::Vector2d>& observed_uv, const Rigid3& initial_cam_from_world,
                            const PoseRefineOptions& options);

}  // namespace m3c::vo
