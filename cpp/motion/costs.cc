#include "motion/costs.h"

#include <cmath>

#include "util/check.h"

namespace m3c::motion {

namespace {
// Writes d(residual rows)/d(block) = M (rows x 3) * d points / d block for one point into a row-major block
// Jacobian with `stride` columns, adding to what is there when accumulate.
void ChainPointJacobian(const Eigen::Ref<const RowMatrixXd>& M, const body::BlockPoints& points, int point, int block,
                        double* jacobian, int first_row, double sign) {
  const int size = points.block_size(block), offset = points.block_offset(block);
  for (int r = 0; r < M.rows(); ++r) {
    double* out = jacobian + static_cast<size_t>(first_row + r) * size;
    for (int c = 0; c < 3; ++c) {
      const double m = sign * M(r, c);
      if (m == 0.0) continue;
      const double* row = points.jacobian_row(3 * point + c) + offset;
      for (int i = 0; i < size; ++i) out[i] += m * row[i];
    }
  }
}

}  // namespace

body::KeypointRegressor JointDifference(const body::BodyModel& model, int lower, int upper) {
  M3C_CHECK(lower >= 0 && upper >= 0 && lower < model.num_joints() && upper < model.num_joints() && lower != upper)
      << "joints " << lower << " and " << upper << " must be two different joints of the " << model.num_joints();
  Eigen::SparseMatrix<double, Eigen::RowMajor> joints(1, model.num_joints());
  joints.insert(0, lower) = -1.0;
  joints.insert(0, upper) = 1.0;
  return body::KeypointRegressor(Eigen::SparseMatrix<double, Eigen::RowMajor>(1, model.num_vertices()), joints);
}

ReprojectionCost::ReprojectionCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                                   FrameCamera camera,
                                   Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> observations,
                                   double weight, double sigma, double min_depth)
    : model_(model),
      regressor_(regressor),
      camera_(std::move(camera)),
      observations_(std::move(observations)),
      sqrt_weight_(std::sqrt(weight)),
      sigma_(sigma),
      min_depth_(min_depth) {
  M3C_CHECK(observations_.rows() == regressor->num_keypoints())
      << "need one observation per keypoint: " << observations_.rows() << " vs " << regressor->num_keypoints();
  M3C_CHECK(weight >= 0 && sigma > 0) << "reprojection weight must be >= 0 and sigma > 0";
  set_num_residuals(2 * regressor->num_keypoints());
  mutable_parameter_block_sizes()->assign({3, 3, 3 * (model->num_joints() - 1), model->num_betas(), 1, 3});
}

bool ReprojectionCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int K = regressor_->num_keypoints();
  thread_local body::BlockPoints points;
  points.Evaluate(*model_, *regressor_, {parameters[0], parameters[1], parameters[2], parameters[3]},
                  jacobians != nullptr, jacobians && jacobians[2], jacobians && jacobians[3]);
  const double scale = parameters[4][0];
  const Eigen::Map<const Eigen::Vector3d> offset(parameters[5]);
  const Eigen::Matrix3d& R = camera_.cam_from_world_rotation;
  const Eigen::Vector3d centre = scale * camera_.centre_in_world + offset;
  if (jacobians) {
    for (int b = 0; b < 6; ++b) {
      if (jacobians[b]) std::fill(jacobians[b], jacobians[b] + num_residuals() * parameter_block_sizes()[b], 0.0);
    }
  }
  for (int k = 0; k < K; ++k) {
    const double conf = observations_(k, 2);
    if (conf <= 0.0) {
      residuals[2 * k] = residuals[2 * k + 1] = 0.0;
      continue;
    }
    const Eigen::Vector3d xc = R * (points.point(k) - centre);
    if (!(xc.z() > min_depth_)) return false;  // behind or too close to the camera: reject the step
    const Eigen::Matrix<double, 2, 3> dres_dxc = RobustReprojection(
        camera_.intrinsics, xc, observations_(k, 0), observations_(k, 1), conf * sqrt_weight_, sigma_, residuals + 2 * k);
    if (!jacobians) continue;
    const RowMatrixXd dres_dxw = dres_dxc * R;  // d xc / d x_world = R
    for (int b = 0; b < 4; ++b) {
      if (jacobians[b]) ChainPointJacobian(dres_dxw, points, k, b, jacobians[b], 2 * k, 1.0);
    }
    if (jacobians[4]) {
      const Eigen::Vector2d d = -dres_dxw * camera_.centre_in_world;
      jacobians[4][2 * k] = d.x();
      jacobians[4][2 * k + 1] = d.y();
    }
    if (jacobians[5]) {
      for (int r2 = 0; r2 < 2; ++r2)
        for (int c = 0; c < 3; ++c) jacobians[5][(2 * k + r2) * 3 + c] = -dres_dxw(r2, c);
    }
  }
  return true;
}

PointStencilCost::PointStencilCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                                   std::vector<double> stencil, std::vector<double> point_weights, double sigma)
    : model_(model), regressor_(regressor), stencil_(std::move(stencil)), sigma_(sigma) {
  M3C_CHECK(stencil_.size() >= 2) << "a stencil needs at least two frames";
  M3C_CHECK(static_cast<int>(point_weights.size()) == regressor->num_keypoints()) << "one weight per point";
  for (double w : point_weights) {
    M3C_CHECK(w >= 0) << "point weights must be >= 0";
    sqrt_weights_.push_back(std::sqrt(w));
  }
  set_num_residuals(3 * regressor->num_keypoints());
  const int body = 3 * (model->num_joints() - 1);
  auto* sizes = mutable_parameter_block_sizes();
  for (size_t f = 0; f < stencil_.size(); ++f) sizes->insert(sizes->end(), {3, 3, body});
  sizes->push_back(model->num_betas());
}

bool PointStencilCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int K = regressor_->num_keypoints(), F = static_cast<int>(stencil_.size());
  const int betas_block = 3 * F;
  thread_local std::vector<body::BlockPoints> frames;
  frames.resize(F);
  for (int f = 0; f < F; ++f) {
    frames[f].Evaluate(*model_, *regressor_,
                       {parameters[3 * f], parameters[3 * f + 1], parameters[3 * f + 2], parameters[betas_block]},
                       jacobians != nullptr, jacobians && jacobians[3 * f + 2], jacobians && jacobians[betas_block]);
  }
  for (int k = 0; k < K; ++k) {
    for (int c = 0; c < 3; ++c) {
      double value = 0.0;
      for (int f = 0; f < F; ++f) value += stencil_[f] * frames[f].point(k)[c];
      residuals[3 * k + c] = sqrt_weights_[k] * value;
    }
  }
  for (int blk = 0; jacobians && blk <= betas_block; ++blk) {
    if (jacobians[blk]) std::fill(jacobians[blk], jacobians[blk] + num_residuals() * parameter_block_sizes()[blk], 0.0);
  }
  for (int k = 0; jacobians && k < K; ++k) {
    const RowMatrixXd M = sqrt_weights_[k] * RowMatrixXd::Identity(3, 3);
    for (int f = 0; f < F; ++f) {
      for (int blk = 0; blk < 3; ++blk) {
        if (jacobians[3 * f + blk]) ChainPointJacobian(M, frames[f], k, blk, jacobians[3 * f + blk], 3 * k, stencil_[f]);
      }
      if (jacobians[betas_block]) ChainPointJacobian(M, frames[f], k, 3, jacobians[betas_block], 3 * k, stencil_[f]);
    }
  }
  for (int k = 0; sigma_ > 0 && k < K; ++k) {
    RobustPointRows(sqrt_weights_[k], sigma_, k, residuals, jacobians, parameter_block_sizes(), num_residuals());
  }
  return true;
}

void RobustPointRows(double sqrt_weight, double sigma, int k, double* residuals, double** jacobians,
                     const std::vector<int32_t>& block_sizes, int num_residuals) {
  if (!(sigma > 0) || sqrt_weight == 0.0) return;  // zero rows stay zero
  const Eigen::Vector3d d = Eigen::Map<const Eigen::Vector3d>(residuals + 3 * k) / sqrt_weight;
  // Shaped in place; d out / d r = (d out / d d) / sqrt_weight, as r = sqrt_weight d.
  const Eigen::Matrix3d M = ShapeGemanMcClure<3>(d, sqrt_weight, sigma, residuals + 3 * k) / sqrt_weight;
  if (!jacobians) return;
  for (size_t b = 0; b < block_sizes.size(); ++b) {
    if (!jacobians[b]) continue;
    Eigen::Map<RowMatrixXd> J(jacobians[b], num_residuals, block_sizes[b]);
    J.middleRows(3 * k, 3) = (M * J.middleRows(3 * k, 3)).eval();
  }
}

UprightCost::UprightCost(const body::BodyModel* model, int lower_joint, int upper_joint,
                         const Eigen::Vector3d& up_in_world, double weight, double sigma)
    : model_(model), spine_(JointDifference(*model, lower_joint, upper_joint)), sqrt_weight_(std::sqrt(weight)),
      sigma_(sigma) {
  M3C_CHECK(weight >= 0 && sigma > 0) << "upright weight must be >= 0 and sigma > 0";
  M3C_CHECK(up_in_world.allFinite() && up_in_world.norm() > 1e-9) << "the up direction must be a finite nonzero vector";
  const Eigen::Vector3d u = up_in_world.normalized();
  // Any unit vector not along u, made orthogonal to it, then the cross product: the plane normal to u.
  const Eigen::Vector3d seed = std::abs(u.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d a = (seed - seed.dot(u) * u).normalized();
  across_.row(0) = a.transpose();
  across_.row(1) = u.cross(a).transpose();
  set_num_residuals(2);
  mutable_parameter_block_sizes()->assign({3, 3, 3 * (model->num_joints() - 1), model->num_betas()});
}

bool UprightCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  thread_local body::BlockPoints points;
  points.Evaluate(*model_, spine_, {parameters[0], parameters[1], parameters[2], parameters[3]}, jacobians != nullptr,
                  jacobians && jacobians[2], jacobians && jacobians[3]);
  const Eigen::Vector2d h = across_ * points.point(0);
  const Eigen::Matrix2d dr_dh = ShapeGemanMcClure<2>(h, sqrt_weight_, sigma_, residuals);
  if (!jacobians) return true;
  const RowMatrixXd dr_dv = dr_dh * across_;
  for (int b = 0; b < 4; ++b) {
    if (!jacobians[b]) continue;
    std::fill(jacobians[b], jacobians[b] + 2 * parameter_block_sizes()[b], 0.0);
    ChainPointJacobian(dr_dv, points, 0, b, jacobians[b], 0, 1.0);
  }
  return true;
}

ContactHeightCost::ContactHeightCost(const body::BodyModel* model, const body::KeypointRegressor* regressor,
                                     std::vector<double> point_weights, const FrameCamera& camera,
                                     Eigen::Vector3d normal_in_cam, double offset_in_cam, double tolerance,
                                     const Eigen::VectorXd& point_heights, bool below_only)
    : model_(model),
      regressor_(regressor),
      heights_(point_heights.size() > 0 ? point_heights : Eigen::VectorXd::Zero(regressor->num_keypoints())),
      normal_in_world_(camera.cam_from_world_rotation.transpose() * normal_in_cam.normalized()),
      centre_in_world_(camera.centre_in_world),
      offset_in_cam_(offset_in_cam / normal_in_cam.norm()),
      tolerance_(tolerance),
      below_only_(below_only) {
  M3C_CHECK(static_cast<int>(point_weights.size()) == regressor->num_keypoints()) << "one weight per point";
  M3C_CHECK(heights_.size() == regressor->num_keypoints() && heights_.allFinite())
      << "one finite height per point, or none";
  M3C_CHECK(normal_in_cam.norm() > 1e-6 && std::isfinite(offset_in_cam))
      << "ground plane must have a nonzero normal and a finite offset";
  for (double w : point_weights) sqrt_weights_.push_back(std::sqrt(std::max(w, 0.0)));
  set_num_residuals(regressor->num_keypoints());
  mutable_parameter_block_sizes()->assign({3, 3, 3 * (model->num_joints() - 1), model->num_betas(), 1, 3});
}

bool ContactHeightCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int K = regressor_->num_keypoints();
  thread_local body::BlockPoints p;
  p.Evaluate(*model_, *regressor_, {parameters[0], parameters[1], parameters[2], parameters[3]}, jacobians != nullptr,
             jacobians && jacobians[2], jacobians && jacobians[3]);
  const double scale = parameters[4][0];
  const Eigen::Map<const Eigen::Vector3d> offset(parameters[5]);
  const Eigen::Vector3d& n = normal_in_world_;
  const double d = offset_in_cam_ - n.dot(scale * centre_in_world_ + offset);
  if (jacobians) {
    for (int blk = 0; blk < 6; ++blk) {
      if (jacobians[blk]) std::fill(jacobians[blk], jacobians[blk] + K * parameter_block_sizes()[blk], 0.0);
    }
  }
  for (int k = 0; k < K; ++k) {
    const double height = n.dot(p.point(k)) + d - heights_[k];
    const double excess = (below_only_ ? -height : std::abs(height)) - tolerance_;
    residuals[k] = excess > 0 ? sqrt_weights_[k] * excess : 0.0;
    if (!jacobians || excess <= 0) continue;
    const double a = sqrt_weights_[k] * (height >= 0 && !below_only_ ? 1.0 : -1.0);
    const RowMatrixXd M = a * n.transpose();
    for (int blk = 0; blk < 4; ++blk) {
      if (jacobians[blk]) ChainPointJacobian(M, p, k, blk, jacobians[blk], k, 1.0);
    }
    if (jacobians[4]) jacobians[4][k] = -a * n.dot(centre_in_world_);
    if (jacobians[5]) {
      for (int c = 0; c < 3; ++c) jacobians[5][3 * k + c] = -a * n[c];
    }
  }
  return true;
}

GaussianPriorCost::GaussianPriorCost(Eigen::VectorXd mean, double weight)
    : mean_(std::move(mean)), sqrt_weight_(std::sqrt(weight)) {
  set_num_residuals(static_cast<int>(mean_.size()));
  mutable_parameter_block_sizes()->assign({static_cast<int>(mean_.size())});
}

bool GaussianPriorCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int n = static_cast<int>(mean_.size());
  for (int i = 0; i < n; ++i) residuals[i] = sqrt_weight_ * (parameters[0][i] - mean_[i]);
  if (jacobians && jacobians[0]) {
    Eigen::Map<RowMatrixXd>(jacobians[0], n, n) = sqrt_weight_ * RowMatrixXd::Identity(n, n);
  }
  return true;
}

LogPriorCost::LogPriorCost(double log_mean, double sigma, double weight)
    : log_mean_(log_mean), factor_(std::sqrt(weight) / sigma) {}

bool LogPriorCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const double x = parameters[0][0];
  if (!(x > 0)) return false;  // outside the prior's domain: Ceres rejects the step
  residuals[0] = factor_ * (std::log(x) - log_mean_);
  if (jacobians && jacobians[0]) jacobians[0][0] = factor_ / x;
  return true;
}

BlockDifferenceCost::BlockDifferenceCost(int size, double weight, Eigen::VectorXd target)
    : sqrt_weight_(std::sqrt(weight)), target_(target.size() > 0 ? std::move(target) : Eigen::VectorXd::Zero(size)) {
  M3C_CHECK(weight >= 0) << "weight must be >= 0";
  M3C_CHECK(target_.size() == size) << "target of size " << target_.size() << " for blocks of size " << size;
  set_num_residuals(size);
  mutable_parameter_block_sizes()->assign({size, size});
}

bool BlockDifferenceCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int n = num_residuals();
  for (int i = 0; i < n; ++i) residuals[i] = sqrt_weight_ * (parameters[1][i] - parameters[0][i] - target_[i]);
  if (jacobians) {
    if (jacobians[0]) Eigen::Map<RowMatrixXd>(jacobians[0], n, n) = -sqrt_weight_ * RowMatrixXd::Identity(n, n);
    if (jacobians[1]) Eigen::Map<RowMatrixXd>(jacobians[1], n, n) = sqrt_weight_ * RowMatrixXd::Identity(n, n);
  }
  return true;
}

RayAccelerationCost::RayAccelerationCost(const std::vector<double>& stencil, const Eigen::Vector3d& ray, double weight) {
  M3C_CHECK(stencil.size() == 3) << "a three-frame stencil, got " << stencil.size() << " coefficients";
  M3C_CHECK(weight >= 0) << "weight must be >= 0";
  M3C_CHECK(std::abs(ray.norm() - 1.0) < 1e-9) << "the ray must be a unit vector";
  const double sqrt_weight = std::sqrt(weight);
  for (int k = 0; k < 3; ++k) stencil_[k] = sqrt_weight * stencil[k];
  ray_ = ray;
}

bool RayAccelerationCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  residuals[0] = 0.0;
  for (int k = 0; k < 3; ++k) {
    residuals[0] += stencil_[k] * ray_.dot(Eigen::Map<const Eigen::Vector3d>(parameters[k]));
    if (jacobians && jacobians[k]) {
      Eigen::Map<Eigen::RowVector3d> row(jacobians[k]);
      row = stencil_[k] * ray_.transpose();
    }
  }
  return true;
}

HeadingAnchorCost::HeadingAnchorCost(const Eigen::Vector3d& up, const Eigen::Vector3d& reference, double weight)
    : up_(up), reference_(reference), side_(up.cross(reference)), sqrt_weight_(std::sqrt(weight)) {}

ceres::CostFunction* HeadingAnchorCost::Create(const Eigen::Vector3d& up_in_world, const Eigen::Vector3d& reference_root,
                                               double weight) {
  const Eigen::Vector3d up = up_in_world.normalized();
  const double forward[3] = {0.0, 0.0, 1.0};
  Eigen::Vector3d facing;  // the rotation operator() applies
  ceres::AngleAxisRotatePoint(reference_root.data(), forward, facing.data());
  const Eigen::Vector3d level = facing - up.dot(facing) * up;
  if (!(level.norm() >= 0.25)) return nullptr;  // within 15 degrees of the up direction (or not finite)
  return new ceres::AutoDiffCostFunction<HeadingAnchorCost, 1, 3>(
      new HeadingAnchorCost(up, level.normalized(), weight));
}

}  // namespace m3c::motion
