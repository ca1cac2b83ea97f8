#include "vo/pose_refine.h"

#include <algorithm>
#include <cmath>

#include "util/check.h"

namespace m3c::vo {

namespace {

// Cauchy-robust cost 0.5 * sum s^2 log(1 + |r|^2 / s^2), matching ceres::CauchyLoss (rho/2 per residual block).
double RobustCost(const std::vector<Eigen::Vector2d>& residuals, double scale) {
  const double s2 = scale * scale;
  double cost = 0.0;
  for (const auto& r : residuals) cost += 0.5 * s2 * std::log1p(r.squaredNorm() / s2);
  return cost;
}

void Residuals(const Intrinsics& K, const std::vector<Eigen::Vector4d>& points, const std::vector<Eigen::Vector2d>& uv,
               const Rigid3& pose, std::vector<Eigen::Vector2d>* residuals, std::vector<Eigen::Vector3d>* ys) {
  residuals->resize(points.size());
  if (ys) ys->resize(points.size());
  const Eigen::Matrix3d R = pose.rotation.toRotationMatrix();
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d y = R * points[i].head<3>() + points[i].w() * pose.translation;
    const double z = std::max(y.z(), 1e-6);
    (*residuals)[i] = Eigen::Vector2d(K.fx * y.x() / z + K.cx, K.fy * y.y() / z + K.cy) - uv[i];
    if (ys) (*ys)[i] = y;
  }
}

}  // namespace

PoseRefineResult RefinePose(const Intrinsics& K, const std::vector<Eigen::Vector4d>& points_in_world,
                            const std::vector<Eigen::Vector2d>& observed_uv, const Rigid3& initial_cam_from_world,
                            const PoseRefineOptions& options) {
  M3C_CHECK(points_in_world.size() == observed_uv.size())
      << points_in_world.size() << " points but " << observed_uv.size() << " observations";
  M3C_CHECK(K.Valid()) << "intrinsics must be finite with fx, fy > 0";
  PoseRefineResult result;
  result.cam_from_world = initial_cam_from_world;
  if (points_in_world.empty()) return result;

  const double s2 = options.loss_scale_px * options.loss_scale_px;
  std::vector<Eigen::Vector2d> residuals;
  std::vector<Eigen::Vector3d> ys;
  Residuals(K, points_in_world, observed_uv, result.cam_from_world, &residuals, &ys);
  double cost = RobustCost(residuals, options.loss_scale_px);
  const double initial_cost = cost;
  double lambda = 1e-4;

  for (int it = 0; it < options.max_iterations; ++it) {
    Eigen::Matrix<double, 6, 6> H = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> g = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t i = 0; i < points_in_world.size(); ++i) {
      const Eigen::Vector3d& y = ys[i];
      if (y.z() <= 1e-6) continue;
      const double z = y.z();
      Eigen::Matrix<double, 2, 3> dpi;
      dpi << K.fx / z, 0.0, -K.fx * y.x() / (z * z), 0.0, K.fy / z, -K.fy * y.y() / (z * z);
      Eigen::Matrix<double, 2, 6> J;
      J.leftCols<3>() = points_in_world[i].w() * dpi;
      // Rotation-only updates turn R but keep t: d(R x)/dphi = -[R x]x with R x = y - w t.
      const Eigen::Vector3d rotated =
          options.rotation_only ? Eigen::Vector3d(y - points_in_world[i].w() * result.cam_from_world.translation) : y;
      J.rightCols<3>() = -dpi * Skew(rotated);
      // IRLS weight of the Cauchy loss: rho'(|r|^2) = 1 / (1 + |r|^2 / s^2).
      const double w = 1.0 / (1.0 + residuals[i].squaredNorm() / s2);
      H.noalias() += w * J.transpose() * J;
      g.noalias() += w * J.transpose() * residuals[i];
    }
    bool accepted = false;
    for (int attempt = 0; attempt < 8 && !accepted; ++attempt) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      if (options.rotation_only) {
        Eigen::Matrix3d Hr = H.bottomRightCorner<3, 3>();
        Hr.diagonal() += lambda * Hr.diagonal() + Eigen::Vector3d::Constant(1e-9);
        delta.tail<3>() = -Hr.ldlt().solve(g.tail<3>());
      } else {
        Eigen::Matrix<double, 6, 6> Hd = H;
        Hd.diagonal() += lambda * H.diagonal() + Eigen::Matrix<double, 6, 1>::Constant(1e-9);
        delta = -Hd.ldlt().solve(g);
      }
      if (!delta.allFinite()) break;
      const Rigid3 candidate =
          options.rotation_only
              ? Rigid3(ExpSO3(Eigen::Vector3d(delta.tail<3>())) * result.cam_from_world.rotation,
                       result.cam_from_world.translation)
              : LeftPlus(result.cam_from_world, delta);
      std::vector<Eigen::Vector2d> cand_res;
      std::vector<Eigen::Vector3d> cand_ys;
      Residuals(K, points_in_world, observed_uv, candidate, &cand_res, &cand_ys);
      const double cand_cost = RobustCost(cand_res, options.loss_scale_px);
      if (cand_cost < cost) {
        const bool tiny = cost - cand_cost < 1e-10 * std::max(1.0, cost);
        result.cam_from_world = candidate;
        residuals.swap(cand_res);
        ys.swap(cand_ys);
        cost = cand_cost;
        lambda = std::max(lambda / 10.0, 1e-8);
        accepted = true;
        if (tiny) it = options.max_iterations;  // converged
      } else {
        lambda *= 10.0;
      }
    }
    ++result.iterations;
    if (!accepted) break;
  }
  double sum = 0.0;
  for (const auto& r : residuals) sum += r.squaredNorm();
  result.rms_px = std::sqrt(sum / residuals.size());
  result.improved = cost < initial_cost;
  return result;
}

}  // namespace m3c::vo
