#include "fit/costs.h"

#include <cmath>
#include <utility>

#include "util/check.h"

namespace m3c::fit {

namespace {

void ZeroJacobians(const ceres::CostFunction& cost, double** jacobians) {
  if (!jacobians) return;
  const auto& sizes = cost.parameter_block_sizes();
  for (size_t b = 0; b < sizes.size(); ++b) {
    if (jacobians[b]) std::fill(jacobians[b], jacobians[b] + cost.num_residuals() * sizes[b], 0.0);
  }
}

}  // namespace

KeypointReprojectionCost::KeypointReprojectionCost(const body::BodyModel* model,
                                                   const body::KeypointRegressor* regressor, Intrinsics intrinsics,
                                                   Observations3 observations, double weight, double sigma,
                                                   double min_depth)
    : model_(model),
      regressor_(regressor),
      intrinsics_(intrinsics),
      observations_(std::move(observations)),
      sqrt_weight_(std::sqrt(weight)),
      sigma_(sigma),
      min_depth_(min_depth) {
  M3C_CHECK(observations_.rows() == regressor->num_keypoints())
      << "need one observation per keypoint: " << observations_.rows() << " vs " << regressor->num_keypoints();
  M3C_CHECK(weight >= 0 && sigma > 0) << "reprojection weight must be >= 0 and sigma > 0";
  M3C_CHECK(intrinsics.fx > 0 && intrinsics.fy > 0) << "focal lengths must be > 0";
  set_num_residuals(2 * regressor->num_keypoints());
  mutable_parameter_block_sizes()->assign({3, 3, 3 * (model->num_joints() - 1), model->num_betas()});
}

bool KeypointReprojectionCost::Evaluate(double const* const* parameters, double* residuals,
                                        double** jacobians) const {
  const int K = regressor_->num_keypoints();
  thread_local body::BlockPoints points;
  points.Evaluate(*model_, *regressor_, {parameters[0], parameters[1], parameters[2], parameters[3]},
                  jacobians != nullptr);
  ZeroJacobians(*this, jacobians);
  for (int k = 0; k < K; ++k) {
    const double conf = observations_(k, 2);
    if (conf <= 0.0) {
      residuals[2 * k] = residuals[2 * k + 1] = 0.0;
      continue;
    }
    const Eigen::Vector3d x = points.point(k);
    if (!(x.z() > min_depth_)) return false;  // behind or too close to the camera: reject the step
    const Eigen::Matrix<double, 2, 3> dres_dx = RobustReprojection(intrinsics_, x, observations_(k, 0),
                                                                   observations_(k, 1), conf * sqrt_weight_, sigma_,
                                                                   residuals + 2 * k);
    if (!jacobians) continue;
    for (int b = 0; b < 4; ++b) {
      if (!jacobians[b]) continue;
      Eigen::Map<RowMatrixXd> out(jacobians[b], num_residuals(), points.block_size(b));
      out.middleRows<2>(2 * k) = dres_dx * points.jacobian(k, b);
    }
  }
  return true;
}

RelativePointsCost::RelativePointsCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                                       Observations4 observations, std::vector<int> reference, double weight,
                                       double sigma)
    : model_(model),
      regressor_(regressor),
      observations_(std::move(observations)),
      reference_(std::move(reference)),
      sqrt_weight_(std::sqrt(weight)),
      sigma_(sigma) {
  const int K = regressor->num_keypoints();
  M3C_CHECK(observations_.rows() == K) << "need one 3D observation per keypoint: " << observations_.rows()
                                       << " vs " << K;
  M3C_CHECK(weight >= 0 && sigma > 0) << "3D keypoint weight must be >= 0 and sigma > 0";
  M3C_CHECK(!reference_.empty()) << "the 3D reference needs at least one keypoint";
  observed_reference_.setZero();
  for (int r : reference_) {
    M3C_CHECK(r >= 0 && r < K) << "reference keypoint " << r << " outside [0, " << K << ")";
    observed_reference_ += observations_.block<1, 3>(r, 0).transpose();
  }
  observed_reference_ /= static_cast<double>(reference_.size());
  set_num_residuals(3 * K);
  mutable_parameter_block_sizes()->assign({3, 3 * (model->num_joints() - 1), model->num_betas()});
}

bool RelativePointsCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int K = regressor_->num_keypoints();
  thread_local body::BlockPoints points;
  points.Evaluate(*model_, *regressor_, {nullptr, parameters[0], parameters[1], parameters[2]}, jacobians != nullptr);
  ZeroJacobians(*this, jacobians);
  const double inv_ref = 1.0 / static_cast<double>(reference_.size());
  Eigen::Vector3d model_reference = Eigen::Vector3d::Zero();
  for (int r : reference_) model_reference += inv_ref * points.point(r);
  for (int k = 0; k < K; ++k) {
    const double conf = observations_(k, 3);
    if (conf <= 0.0) {
      residuals[3 * k] = residuals[3 * k + 1] = residuals[3 * k + 2] = 0.0;
      continue;
    }
    const Eigen::Vector3d e = (points.point(k) - model_reference) -
                              (observations_.block<1, 3>(k, 0).transpose() - observed_reference_);
    const Eigen::Matrix3d dres_de = ShapeGemanMcClure<3>(e, conf * sqrt_weight_, sigma_, residuals + 3 * k);
    if (!jacobians) continue;
    for (int b = 0; b < 3; ++b) {
      if (!jacobians[b]) continue;
      const int block = b + 1;  // body::BlockPoints' blocks start with the translation
      RowMatrixXd de = points.jacobian(k, block);
      for (int r : reference_) de -= inv_ref * points.jacobian(r, block);
      Eigen::Map<RowMatrixXd> out(jacobians[b], num_residuals(), points.block_size(block));
      out.middleRows<3>(3 * k) = dres_de * de;
    }
  }
  return true;
}

WeightedPriorCost::WeightedPriorCost(Eigen::VectorXd mean, Eigen::VectorXd weights) : mean_(std::move(mean)) {
  M3C_CHECK(weights.size() == mean_.size()) << "prior: one weight per value (" << mean_.size() << "), got "
                                            << weights.size();
  M3C_CHECK((weights.array() >= 0).all() && weights.allFinite()) << "prior weights must be finite and >= 0";
  sqrt_weights_ = weights.array().sqrt();
  set_num_residuals(static_cast<int>(mean_.size()));
  mutable_parameter_block_sizes()->assign({static_cast<int>(mean_.size())});
}

bool WeightedPriorCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int n = static_cast<int>(mean_.size());
  for (int i = 0; i < n; ++i) residuals[i] = sqrt_weights_[i] * (parameters[0][i] - mean_[i]);
  if (jacobians && jacobians[0]) {
    Eigen::Map<RowMatrixXd>(jacobians[0], n, n) = sqrt_weights_.asDiagonal();
  }
  return true;
}

}  // namespace m3c::fit
