// Residual blocks of the staged world-frame optimization. Parameter blocks per person and frame:
// transl (3), root orientation (3, axis-angle), body pose (3(J-1)); per person: betas (B); shared:
// camera scale (1) and camera offset (3). All Jacobians are analytic and checked against numeric ones.
#pragma once

#include <vector>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Core>

#include "body/body_model.h"
#include "body/block_points.h"
#include "util/pinhole.h"

namespace m3c::motion {

using body::RowMatrixXd;

// One frame's camera. The VO trajectory is up to scale: the camera centre in the world is
// scale * centre + offset, with scale and offset optimised. x_cam = rotation * (x_world - that centre).
struct FrameCamera {
  Eigen::Matrix3d cam_from_world_rotation;
  Eigen::Vector3d centre_in_world;  // unscaled, from world_from_cam
  Intrinsics intrinsics;
};

// A regressor of one point: joint `upper` minus joint `lower` (the upright term's spine).
body::KeypointRegressor JointDifference(const body::BodyModel& model, int lower, int upper);

// 2D keypoint reprojection, SLAHMR's robust form: cost = weight * sum_k conf_k^2 GM(|r_k|^2), with the
// Geman-McClure GM(s) = sigma^2 s / (sigma^2 + s) and r_k = pi(x_k) - u_k in pixels. The residual of keypoint k
// is conf_k sqrt(weight) sigma r_k / sqrt(sigma^2 + |r_k|^2): its squared norm is exactly the cost, smooth at 0.
// Blocks: transl, root, body, betas, scale, offset. Residuals: 2K.
class ReprojectionCost : public ceres::CostFunction {
 public:
  ReprojectionCost(const body::BodyModel* model, const body::KeypointRegressor* regressor, FrameCamera camera,
                   Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> observations, double weight,
                   double sigma, double min_depth);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  FrameCamera camera_;
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> observations_;  // u, v, confidence
  double sqrt_weight_, sigma_, min_depth_;
};

// Makes rows 3k..3k+2 of a point term r = sqrt(w) d (d a 3-vector, its Jacobian rows already written) robust in
// the form of ReprojectionCost: sqrt(w) sigma d / sqrt(sigma^2 + |d|^2), so its cost is w GM(|d|^2) with
// GM(s) = sigma^2 s / (sigma^2 + s), and its Jacobian rows with it. sigma <= 0 leaves them as they are.
void RobustPointRows(double sqrt_weight, double sigma, int k, double* residuals, double** jacobians,
                     const std::vector<int32_t>& block_sizes, int num_residuals);

// sqrt(w_k) sum_f c_f p_k(frame f) for every regressor point k: a finite-difference stencil over consecutive
// frames. Velocity (c = -1, 1): 3D joint smoothness and contact velocity; acceleration (c = 1, -2, 1). With
// sigma > 0 each point's residual is robust (RobustPointRows). Blocks: transl_f, root_f, body_f for each frame f
// of the stencil, then betas. Residuals: 3K.
class PointStencilCost : public ceres::CostFunction {
 public:
  PointStencilCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                   std::vector<double> stencil, std::vector<double> point_weights, double sigma = 0.0);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  std::vector<double> stencil_, sqrt_weights_;
  double sigma_;
};

// Upright: the body's lower-to-upper joint vector v (SMPL pelvis to neck: the spine) leaning off the world's
// up direction u (unit; the person's ground normal), in the robust form of ReprojectionCost: with h = P v the
// component of v across u (P: 2 x 3, an orthonormal basis of the plane normal to u), cost = weight GM(|h|^2),
// GM(s) = sigma^2 s / (sigma^2 + s), so a person who bends over (|h| >> sigma metres) pulls with a bounded force.
// Residual sqrt(weight) sigma h / sqrt(sigma^2 + |h|^2). Blocks: transl, root, body, betas. Residuals: 2.
class UprightCost : public ceres::CostFunction {
 public:
  UprightCost(const body::BodyModel* model, int lower_joint, int upper_joint, const Eigen::Vector3d& up_in_world,
              double weight, double sigma);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  body::KeypointRegressor spine_;  // one point: upper joint minus lower joint
  Eigen::Matrix<double, 2, 3, Eigen::RowMajor> across_;
  double sqrt_weight_, sigma_;
};

// Heading anchor: the body's facing direction about the world's up direction u (unit; the person's ground
// normal) held to a reference heading, r = sqrt(weight) atan2(u . (f0 x f), f0 . f), f = R(root) z and f0 the
// reference facing direction (the body model's forward axis z), both projected onto the plane normal to u.
// The camera-local fit sees which way a person faces where the keypoints alone hold it weakly (a person half
// hidden, only one side visible), and a heading leaves the lean to the keypoints and "upright". Block: root.
class HeadingAnchorCost {
 public:
  // Nullptr where the reference faces within 15 degrees of u (lying down: no heading to hold).
  static ceres::CostFunction* Create(const Eigen::Vector3d& up_in_world, const Eigen::Vector3d& reference_root,
                                     double weight);

  template <typename T>
  bool operator()(const T* root, T* residual) const {
    const T forward[3] = {T(0), T(0), T(1)};
    T f[3];
    ceres::AngleAxisRotatePoint(root, forward, f);
    const T along = T(up_[0]) * f[0] + T(up_[1]) * f[1] + T(up_[2]) * f[2];
    T p[3];  // f across u: the heading's plane
    for (int k = 0; k < 3; ++k) p[k] = f[k] - along * T(up_[k]);
    const T cross_up = T(side_[0]) * p[0] + T(side_[1]) * p[1] + T(side_[2]) * p[2];  // (f0 x p) . u = (u x f0) . p
    const T dot = T(reference_[0]) * p[0] + T(reference_[1]) * p[1] + T(reference_[2]) * p[2];
    residual[0] = T(sqrt_weight_) * atan2(cross_up, dot);
    return true;
  }

 private:
  HeadingAnchorCost(const Eigen::Vector3d& up, const Eigen::Vector3d& reference, double weight);
  Eigen::Vector3d up_, reference_, side_;  // u, f0 across u (both unit), u x f0
  double sqrt_weight_;
};

// Contact height against the person's ground plane, given in the frame's camera coordinates (metric, as a
// camera-local estimate measures it): n_c.x_cam + d_c = 0. In the world it is n.x + d = 0 with n = R_wc n_c and
// d = d_c - n.(scale * centre + offset), so the plane moves with the camera scale and the camera height above
// the ground becomes a metric cue. r_k = sqrt(w_k) max(0, |n.p_k + d - h_k| - tolerance), h_k the point's height
// above the ground when it stands on it (a joint's height above the sole: the ankle's is about 7 cm). below_only:
// r_k = sqrt(w_k) max(0, h_k - (n.p_k + d) - tolerance), the point's depth under its standing height (a foot
// through the floor), nothing above it.
// Blocks: transl, root, body, betas, scale, offset. Residuals: K.
class ContactHeightCost : public ceres::CostFunction {
 public:
  ContactHeightCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                    std::vector<double> point_weights, const FrameCamera& camera, Eigen::Vector3d normal_in_cam,
                    double offset_in_cam, double tolerance, const Eigen::VectorXd& point_heights = {},
                    bool below_only = false);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  std::vector<double> sqrt_weights_;
  Eigen::VectorXd heights_;
  Eigen::Vector3d normal_in_world_, centre_in_world_;
  double offset_in_cam_, tolerance_;
  bool below_only_;
};

// sqrt(weight) (x - mean): Gaussian priors on one block (shape prior with mean 0, L2 pose prior).
class GaussianPriorCost : public ceres::CostFunction {
 public:
  GaussianPriorCost(Eigen::VectorXd mean, double weight);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  Eigen::VectorXd mean_;
  double sqrt_weight_;
};

// sqrt(weight) (log(x) - log_mean) / sigma for a positive scalar x: a log-normal prior (the camera scale around
// its estimate, whose uncertainty is relative).
class LogPriorCost : public ceres::SizedCostFunction<1, 1> {
 public:
  LogPriorCost(double log_mean, double sigma, double weight);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  double log_mean_, factor_;
};

// sqrt(weight) ray . (s_0 t_0 + s_1 t_1 + s_2 t_2): a three-frame stencil (the pelvis's acceleration: the root
// translations' stencil, since the pelvis is the translation plus a rest offset that a stencil summing to zero
// cancels) along one fixed unit direction, the camera's line of sight to the person. A monocular fit's depth
// swings along that line; across it the images hold the body. Blocks: the three root translations.
class RayAccelerationCost : public ceres::SizedCostFunction<1, 3, 3, 3> {
 public:
  RayAccelerationCost(const std::vector<double>& stencil, const Eigen::Vector3d& ray, double weight);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  double stencil_[3];
  Eigen::Vector3d ray_;
};

// sqrt(weight) (x_b - x_a - target) for two blocks of equal size: temporal smoothness of a parameter block
// (target zero) or a step held to a given one (target of that size).
class BlockDifferenceCost : public ceres::CostFunction {
 public:
  BlockDifferenceCost(int size, double weight, Eigen::VectorXd target = Eigen::VectorXd());
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  double sqrt_weight_;
  Eigen::VectorXd target_;
};

}  // namespace m3c::motion
