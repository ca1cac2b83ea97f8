// Patch bundle adjustment: camera poses (SE3, cam_from_world) and one inverse depth per patch, as in DPVO.
//
// A patch p is anchored in its host frame h at pixel u_p with inverse depth d_p. Its homogeneous point in the
// host camera is X_h = [b_p, d_p] with bearing b_p = [(u-cx)/fx, (v-cy)/fy, 1]. In a target frame j
//   Y = R_jh b_p + d_p t_jh        (T_jh = T_j T_h^-1 = [R_jh, t_jh];  Y = d_p * point_in_cam_j)
// and the residual of an observation z_pj (pixels) is
//   r_pj = sqrt(w_pj) (pi(Y) - z_pj),   pi(Y) = [fx Y0/Y2 + cx, fy Y1/Y2 + cy].
// Y2 is the target/host depth ratio; below `kMinDepthRatio` the point is treated as sitting at that ratio
// (DPVO drops such edges; clamping keeps the cost continuous for the trust region).
//
// E(T, d) = sum_pj rho(|r_pj|^2) is minimised by Ceres (Levenberg-Marquardt, Schur complement on the inverse
// depths). Poses use the left retraction of rigid3.h. The analytic cost evaluates its Jacobian with respect to
// the 6-d tangent perturbation and stores it in the first six columns of the 7-wide ambient block; the manifold's
// PlusJacobian is the matching [I6; 0] selection, so Ceres sees exactly dr/d(delta).
#pragma once

#include <ceres/ceres.h>

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "util/pinhole.h"
#include "vo/rigid3.h"

namespace m3c::vo {

constexpr double kMinDepthRatio = 0.1;

// Left-multiplied SE3 retraction on (qx, qy, qz, qw, tx, ty, tz) parameter blocks (see rigid3.h).
class LeftSE3Manifold final : public ceres::Manifold {
 public:
  int AmbientSize() const override { return 7; }
  int TangentSize() const override { return 6; }
  bool Plus(const double* x, const double* delta, double* x_plus_delta) const override;
  // [I6; 0]: the costs that use this manifold return tangent-space Jacobians in their first six columns.
  bool PlusJacobian(const double* x, double* jacobian) const override;
  bool Minus(const double* y, const double* x, double* y_minus_x) const override;
  bool MinusJacobian(const double* x, double* jacobian) const override;
};

// Templated residual (double or ceres::Jet) over packed poses; the reference the analytic cost is tested against.
struct PatchReprojectionResidual {
  Eigen::Vector3d bearing;   // host bearing b_p
  Eigen::Vector2d observed;  // z_pj, pixels
  Intrinsics K;
  double sqrt_weight = 1.0;

  template <typename T>
  bool operator()(const T* host_from_world, const T* target_from_world, const T* inverse_depth, T* residual) const {
    using Quat = Eigen::Quaternion<T>;
    using Vec3 = Eigen::Matrix<T, 3, 1>;
    const Quat q_h(host_from_world[3], host_from_world[0], host_from_world[1], host_from_world[2]);
    const Quat q_j(target_from_world[3], target_from_world[0], target_from_world[1], target_from_world[2]);
    const Vec3 t_h(host_from_world[4], host_from_world[5], host_from_world[6]);
    const Vec3 t_j(target_from_world[4], target_from_world[5], target_from_world[6]);
    const Quat q_jh = q_j * q_h.conjugate();
    const Vec3 t_jh = t_j - q_jh * t_h;
    const Vec3 y = q_jh * bearing.cast<T>() + inverse_depth[0] * t_jh;
    T z = y[2];
    if (z < T(kMinDepthRatio)) z = T(kMinDepthRatio);
    residual[0] = T(sqrt_weight) * (T(K.fx) * y[0] / z + T(K.cx) - T(observed.x()));
    residual[1] = T(sqrt_weight) * (T(K.fy) * y[1] / z + T(K.cy) - T(observed.y()));
    return true;
  }
};

// Analytic version of PatchReprojectionResidual: parameter blocks (host pose 7, target pose 7, inverse depth 1).
class PatchReprojectionCost final : public ceres::SizedCostFunction<2, 7, 7, 1> {
 public:
  explicit PatchReprojectionCost(const PatchReprojectionResidual& residual) : r_(residual) {}
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // Tangent-space Jacobians (2x6 host, 2x6 target, 2x1 depth) at the given parameters.
  static void TangentJacobians(const PatchReprojectionResidual& r, const double* host, const double* target,
                               double inverse_depth, Eigen::Vector2d* residual, Eigen::Matrix<double, 2, 6>* d_host,
                               Eigen::Matrix<double, 2, 6>* d_target, Eigen::Vector2d* d_depth);

 private:
  PatchReprojectionResidual r_;
};

// ---- The reusable solver --------------------------------------------------------------------------------------

struct PatchBAPatch {
  int host = 0;                         // index into PatchBAData::poses
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();  // pixel in the host frame
  double inverse_depth = 1.0;
  bool fixed = false;
};

struct PatchBAObservation {
  int patch = 0;   // index into PatchBAData::patches
  int target = 0;  // index into PatchBAData::poses; must differ from the patch's host
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();
  double weight = 1.0;  // multiplies the squared residual
};

struct PatchBAData {
  Intrinsics intrinsics;
  std::vector<Rigid3> cam_from_world;
  std::vector<uint8_t> pose_fixed;  // one per pose; empty means none fixed
  std::vector<PatchBAPatch> patches;
  std::vector<PatchBAObservation> observations;
};

struct PatchBAOptions {
  enum class Loss { kTrivial, kHuber, kCauchy };
  Loss loss = Loss::kCauchy;
  double loss_scale_px = 1.5;  // residual (pixels) where the robust loss starts to flatten
  enum class Solver { kDenseSchur, kSparseSchur, kAuto };
  Solver solver = Solver::kAuto;  // kAuto: dense Schur up to `dense_max_poses` free poses, sparse above
  int dense_max_poses = 40;
  int max_iterations = 10;
  double function_tolerance = 1e-6;
  double min_inverse_depth = 1e-3;  // free inverse depths are clamped to this range after the solve (DPVO)
  double max_inverse_depth = 10.0;
  int num_threads = 1;
};

struct PatchBASummary {
  int iterations = 0;          // accepted + rejected LM steps
  double initial_cost = 0.0;   // Ceres cost 0.5 sum rho(|r|^2) before / after
  double final_cost = 0.0;
  double solve_seconds = 0.0;
  int num_residuals = 0;
  int num_free_poses = 0;
  int num_free_patches = 0;
  bool converged = false;
  bool usable = false;  // Ceres reported a usable solution (converged or hit the iteration limit)
  std::string message;
};

// Solves in place (poses and inverse depths of `data`). Patches without observations are left untouched;
// poses that no observation touches are left untouched. Throws std::invalid_argument on inconsistent indices.
PatchBASummary SolvePatchBA(const PatchBAOptions& options, PatchBAData* data);

// Per-observation reprojection error (pixels, unweighted) at the current estimate.
std::vector<double> ReprojectionErrors(const PatchBAData& data);

}  // namespace m3c::vo
