#include "vo/patch_ba.h"

#include <algorithm>
#include <chrono>
#include <memory>

#include "util/blas_threads.h"
#include "util/check.h"

namespace m3c::vo {

bool LeftSE3Manifold::Plus(const double* x, const double* delta, double* x_plus_delta) const {
  const Eigen::Map<const Eigen::Matrix<double, 6, 1>> d(delta);
  LeftPlus(Rigid3::FromParams(x), d).ToParams(x_plus_delta);
  return true;
}

bool LeftSE3Manifold::PlusJacobian(const double* /*x*/, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, 7, 6, Eigen::RowMajor>> j(jacobian);
  j.setZero();
  j.topRows<6>().setIdentity();
  return true;
}

bool LeftSE3Manifold::Minus(const double* y, const double* x, double* y_minus_x) const {
  Eigen::Map<Eigen::Matrix<double, 6, 1>> out(y_minus_x);
  out = LeftMinus(Rigid3::FromParams(y), Rigid3::FromParams(x));
  return true;
}

bool LeftSE3Manifold::MinusJacobian(const double* /*x*/, double* jacobian) const {
  Eigen::Map<Eigen::Matrix<double, 6, 7, Eigen::RowMajor>> j(jacobian);
  j.setZero();
  j.leftCols<6>().setIdentity();
  return true;
}

void PatchReprojectionCost::TangentJacobians(const PatchReprojectionResidual& r, const double* host,
                                             const double* target, double inverse_depth, Eigen::Vector2d* residual,
                                             Eigen::Matrix<double, 2, 6>* d_host,
                                             Eigen::Matrix<double, 2, 6>* d_target, Eigen::Vector2d* d_depth) {
  const Rigid3 host_from_world = Rigid3::FromParams(host);
  const Rigid3 target_from_world = Rigid3::FromParams(target);
  const Rigid3 target_from_host = target_from_world * host_from_world.Inverse();
  const Eigen::Matrix3d R_jh = target_from_host.rotation.toRotationMatrix();
  const Eigen::Vector3d& t_jh = target_from_host.translation;
  const double d = inverse_depth;
  const Eigen::Vector3d y = R_jh * r.bearing + d * t_jh;

  const bool clamped = y.z() < kMinDepthRatio;
  const double z = clamped ? kMinDepthRatio : y.z();
  const double s = r.sqrt_weight;
  *residual = {s * (r.K.fx * y.x() / z + r.K.cx - r.observed.x()), s * (r.K.fy * y.y() / z + r.K.cy - r.observed.y())};
  if (!d_host && !d_target && !d_depth) return;

  // d(residual)/dY, zero along Y2 where the depth ratio is clamped.
  Eigen::Matrix<double, 2, 3> dpi;
  dpi << s * r.K.fx / z, 0.0, clamped ? 0.0 : -s * r.K.fx * y.x() / (z * z),  //
      0.0, s * r.K.fy / z, clamped ? 0.0 : -s * r.K.fy * y.y() / (z * z);
  if (d_target) {
    // Y' = Exp(phi) Y + d rho
    d_target->leftCols<3>() = d * dpi;
    d_target->rightCols<3>() = -dpi * Skew(y);
  }
  if (d_host) {
    // Y' = R_jh (b + [b]x phi - d rho) + d t_jh
    const Eigen::Matrix<double, 2, 3> dpi_R = dpi * R_jh;
    d_host->leftCols<3>() = -d * dpi_R;
    d_host->rightCols<3>() = dpi_R * Skew(r.bearing);
  }
  if (d_depth) *d_depth = dpi * t_jh;
}

bool PatchReprojectionCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  Eigen::Vector2d res;
  Eigen::Matrix<double, 2, 6> jh, jt;
  Eigen::Vector2d jd;
  const bool want = jacobians != nullptr;
  TangentJacobians(r_, parameters[0], parameters[1], parameters[2][0], &res, want && jacobians[0] ? &jh : nullptr,
                   want && jacobians[1] ? &jt : nullptr, want && jacobians[2] ? &jd : nullptr);
  residuals[0] = res.x();
  residuals[1] = res.y();
  if (!want) return true;
  using Ambient = Eigen::Matrix<double, 2, 7, Eigen::RowMajor>;
  if (jacobians[0]) {
    Eigen::Map<Ambient> j(jacobians[0]);
    j.leftCols<6>() = jh;
    j.col(6).setZero();
  }
  if (jacobians[1]) {
    Eigen::Map<Ambient> j(jacobians[1]);
    j.leftCols<6>() = jt;
    j.col(6).setZero();
  }
  if (jacobians[2]) {
    jacobians[2][0] = jd.x();
    jacobians[2][1] = jd.y();
  }
  return true;
}

namespace {

void ValidateIndices(const PatchBAData& data) {
  const int num_poses = static_cast<int>(data.cam_from_world.size());
  const int num_patches = static_cast<int>(data.patches.size());
  M3C_CHECK(data.intrinsics.Valid()) << "intrinsics must be finite with fx, fy > 0";
  M3C_CHECK(data.pose_fixed.empty() || static_cast<int>(data.pose_fixed.size()) == num_poses)
      << "pose_fixed has " << data.pose_fixed.size() << " entries for " << num_poses << " poses";
  for (const PatchBAPatch& p : data.patches) {
    M3C_CHECK(p.host >= 0 && p.host < num_poses) << "patch host " << p.host << " outside [0, " << num_poses << ")";
  }
  for (const PatchBAObservation& o : data.observations) {
    M3C_CHECK(o.patch >= 0 && o.patch < num_patches) << "observation patch " << o.patch << " outside [0, "
                                                    << num_patches << ")";
    M3C_CHECK(o.target >= 0 && o.target < num_poses) << "observation target " << o.target << " outside [0, "
                                                    << num_poses << ")";
    M3C_CHECK(o.target != data.patches[o.patch].host) << "observation of patch " << o.patch << " in its own host";
    M3C_CHECK(o.weight >= 0.0 && std::isfinite(o.weight)) << "observation weight must be finite and >= 0";
  }
}

}  // namespace

PatchBASummary SolvePatchBA(const PatchBAOptions& options, PatchBAData* data) {
  ValidateIndices(*data);
  PatchBASummary summary;
  const auto start = std::chrono::steady_clock::now();
  const int num_poses = static_cast<int>(data->cam_from_world.size());
  const int num_patches = static_cast<int>(data->patches.size());
  if (data->observations.empty()) {
    summary.usable = true;
    summary.converged = true;
    summary.message = "no observations";
    return summary;
  }

  std::vector<double> pose_params(7 * num_poses);
  for (int i = 0; i < num_poses; ++i) data->cam_from_world[i].ToParams(&pose_params[7 * i]);
  std::vector<double> depths(num_patches);
  for (int p = 0; p < num_patches; ++p) depths[p] = data->patches[p].inverse_depth;

  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  std::unique_ptr<ceres::LossFunction> loss;
  switch (options.loss) {
    case PatchBAOptions::Loss::kHuber:
      loss = std::make_unique<ceres::HuberLoss>(options.loss_scale_px);
      break;
    case PatchBAOptions::Loss::kCauchy:
      loss = std::make_unique<ceres::CauchyLoss>(options.loss_scale_px);
      break;
    case PatchBAOptions::Loss::kTrivial:
      break;
  }
  LeftSE3Manifold manifold;

  std::vector<uint8_t> pose_used(num_poses, 0), patch_used(num_patches, 0);
  for (const PatchBAObservation& o : data->observations) {
    const PatchBAPatch& patch = data->patches[o.patch];
    PatchReprojectionResidual r;
    r.bearing = data->intrinsics.Unproject(patch.uv);
    r.observed = o.uv;
    r.K = data->intrinsics;
    r.sqrt_weight = std::sqrt(o.weight);
    problem.AddResidualBlock(new PatchReprojectionCost(r), loss.get(), &pose_params[7 * patch.host],
                             &pose_params[7 * o.target], &depths[o.patch]);
    pose_used[patch.host] = pose_used[o.target] = 1;
    patch_used[o.patch] = 1;
  }

  auto* ordering = new ceres::ParameterBlockOrdering;
  for (int i = 0; i < num_poses; ++i) {
    if (!pose_used[i]) continue;
    double* block = &pose_params[7 * i];
    problem.SetManifold(block, &manifold);
    if (!data->pose_fixed.empty() && data->pose_fixed[i]) {
      problem.SetParameterBlockConstant(block);
    } else {
      ++summary.num_free_poses;
    }
    ordering->AddElementToGroup(block, 1);
  }
  for (int p = 0; p < num_patches; ++p) {
    if (!patch_used[p]) continue;
    if (data->patches[p].fixed) {
      problem.SetParameterBlockConstant(&depths[p]);
    } else {
      depths[p] = std::clamp(depths[p], options.min_inverse_depth, options.max_inverse_depth);
      ++summary.num_free_patches;
    }
    ordering->AddElementToGroup(&depths[p], 0);
  }

  ceres::Solver::Options solver_options;
  solver_options.minimizer_type = ceres::TRUST_REGION;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  const bool dense = options.solver == PatchBAOptions::Solver::kDenseSchur ||
                     (options.solver == PatchBAOptions::Solver::kAuto &&
                      summary.num_free_poses <= options.dense_max_poses);
  solver_options.linear_solver_type = dense ? ceres::DENSE_SCHUR : ceres::SPARSE_SCHUR;
  solver_options.linear_solver_ordering.reset(ordering);
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = options.function_tolerance;
  solver_options.num_threads = std::max(1, options.num_threads);
  solver_options.logging_type = ceres::SILENT;
  solver_options.minimizer_progress_to_stdout = false;

  ceres::Solver::Summary ceres_summary;
  {
    const util::ScopedBlasThreads blas_threads(solver_options.num_threads);  // SPARSE_SCHUR's CHOLMOD
    ceres::Solve(solver_options, &problem, &ceres_summary);
  }

  summary.iterations = ceres_summary.num_successful_steps + ceres_summary.num_unsuccessful_steps;
  summary.initial_cost = ceres_summary.initial_cost;
  summary.final_cost = ceres_summary.final_cost;
  summary.num_residuals = ceres_summary.num_residual_blocks;
  summary.converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  summary.usable = ceres_summary.IsSolutionUsable();
  summary.message = ceres_summary.message;
  if (summary.usable) {
    for (int i = 0; i < num_poses; ++i) {
      if (pose_used[i]) data->cam_from_world[i] = Rigid3::FromParams(&pose_params[7 * i]);
    }
    for (int p = 0; p < num_patches; ++p) {
      // Clamped after the solve, as DPVO clamps after each update (Ceres bounds would double the Jacobian
      // evaluations per iteration).
      if (patch_used[p] && !data->patches[p].fixed) {
        data->patches[p].inverse_depth = std::clamp(depths[p], options.min_inverse_depth, options.max_inverse_depth);
      }
    }
  }
  summary.solve_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary;
}

std::vector<double> ReprojectionErrors(const PatchBAData& data) {
  ValidateIndices(data);
  std::vector<double> errors;
  errors.reserve(data.observations.size());
  for (const PatchBAObservation& o : data.observations) {
    const PatchBAPatch& patch = data.patches[o.patch];
    const Rigid3 target_from_host = data.cam_from_world[o.target] * data.cam_from_world[patch.host].Inverse();
    const Eigen::Vector3d y = target_from_host.rotation * data.intrinsics.Unproject(patch.uv) +
                              patch.inverse_depth * target_from_host.translation;
    const double z = std::max(y.z(), kMinDepthRatio);
    const Eigen::Vector2d uv(data.intrinsics.fx * y.x() / z + data.intrinsics.cx,
                             data.intrinsics.fy * y.y() / z + data.intrinsics.cy);
    errors.push_back((uv - o.uv).norm());
  }
  return errors;
}

}  // namespace m3c::vo
