// Residual blocks of the per-frame camera-local body fit. Parameter blocks: transl (3, camera frame, metres),
// root orientation (3, axis-angle, camera frame), body pose (3(J-1)), betas (B). Jacobians are analytic,
// chained from body::KeypointsWithJacobian, and checked against numeric ones in tests/cpp/fit.
#pragma once

#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "body/body_model.h"
#include "body/block_points.h"
#include "util/pinhole.h"

namespace m3c::fit {

using body::RowMatrixXd;

using Observations3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
using Observations4 = Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>;

// Robust 2D reprojection in the camera frame (SLAHMR's Geman-McClure form):
//   E = weight * sum_k conf_k^2 GM(|pi(p_k) - u_k|^2),   GM(s) = sigma^2 s / (sigma^2 + s),
// with the residual of keypoint k r_k = conf_k sqrt(weight) sigma e_k / sqrt(sigma^2 + |e_k|^2), so |r|^2 = E
// exactly. Keypoints with conf <= 0 contribute nothing. Blocks: transl, root, body, betas. Residuals: 2K.
class KeypointReprojectionCost : public ceres::CostFunction {
 public:
  KeypointReprojectionCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                           Intrinsics intrinsics, Observations3 observations, double weight, double sigma,
                           double min_depth);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  Intrinsics intrinsics_;
  Observations3 observations_;  // u, v (pixels), confidence
  double sqrt_weight_, sigma_, min_depth_;
};

// Root-relative 3D keypoints (a monocular 3D pose such as MediaPipe's metric landmarks, axes of the camera):
//   e_k = (p_k - mean_{r in ref} p_r) - (q_k - mean_{r in ref} q_r),
// with the same Geman-McClure shaping as above (sigma in metres). Translation cancels, so the blocks are root,
// body, betas. Residuals: 3K.
class RelativePointsCost : public ceres::CostFunction {
 public:
  RelativePointsCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                     Observations4 observations, std::vector<int> reference, double weight, double sigma);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  Observations4 observations_;  // x, y, z (metres), confidence
  std::vector<int> reference_;
  Eigen::Vector3d observed_reference_;
  double sqrt_weight_, sigma_;
};

// r_i = sqrt(w_i) (x_i - mean_i) on one block: Gaussian priors (pose and shape towards 0, or towards the
// previous frame's values).
class WeightedPriorCost : public ceres::CostFunction {
 public:
  WeightedPriorCost(Eigen::VectorXd mean, Eigen::VectorXd weights);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  Eigen::VectorXd mean_, sqrt_weights_;
};

}  // namespace m3c::fit
