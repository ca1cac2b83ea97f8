#include "fit/frame_fit.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include "body/kinematics.h"
#include "motion/vposer_term.h"
#include "util/check.h"

namespace m3c::fit {

namespace {

Eigen::Vector3d RotationToAxisAngle(const Eigen::Matrix3d& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

Eigen::Matrix3d AxisAngleToRotationMatrix(const Eigen::Vector3d& v) {
  const double angle = v.norm();
  if (angle < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(angle, v / angle).toRotationMatrix();
}

// Rotation R minimising sum_k |R p_k - q_k|^2 over centred point sets (Kabsch, with the reflection fix).
Eigen::Matrix3d Kabsch(const std::vector<Eigen::Vector3d>& p, const std::vector<Eigen::Vector3d>& q) {
  Eigen::Vector3d pm = Eigen::Vector3d::Zero(), qm = Eigen::Vector3d::Zero();
  for (size_t i = 0; i < p.size(); ++i) pm += p[i], qm += q[i];
  pm /= static_cast<double>(p.size());
  qm /= static_cast<double>(q.size());
  Eigen::Matrix3d H = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < p.size(); ++i) H += (p[i] - pm) * (q[i] - qm).transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(H, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixV() * D * svd.matrixU().transpose();
}

}  // namespace

BodyFitter::BodyFitter(const body::BodyModel* model, const body::KeypointRegressor* regressor, FitOptions options,
                       const nn::VPoser* vposer)
    : model_(model), regressor_(regressor), options_(std::move(options)), vposer_(vposer) {
  M3C_CHECK(model && regressor) << "the fitter needs a body model and a keypoint regressor";
  M3C_CHECK(regressor->num_vertices() == model->num_vertices() && regressor->num_joints() == model->num_joints())
      << "keypoint regressor does not match the body model";
  const FitOptions& o = options_;
  M3C_CHECK(o.robust_sigma_px > 0 && o.keypoints3d_sigma > 0) << "robust scales must be > 0";
  M3C_CHECK(o.keypoints3d_weight >= 0 && o.pose_prior_weight >= 0 && o.shape_prior_weight >= 0 &&
            o.temporal_pose_weight >= 0 && o.temporal_betas_weight >= 0 && o.temporal_transl_weight >= 0 &&
            o.vposer_weight >= 0)
      << "term weights must be >= 0";
  M3C_CHECK(!vposer || 3 * vposer->num_joints() <= 3 * (model->num_joints() - 1))
      << "the pose prior has " << vposer->num_joints() << " body joints, more than the body model's "
      << model->num_joints() - 1;
  M3C_CHECK(o.min_depth > 0 && o.max_iterations >= 1 && o.min_keypoints >= 2)
      << "min_depth must be > 0, max_iterations >= 1 and min_keypoints >= 2";
  M3C_CHECK(!std::isnan(o.max_limb_from_3d_m))
      << "max_limb_from_3d_m must be a distance in metres (negative: never re-solve the limbs), got NaN";
  M3C_CHECK(!std::isnan(o.max_turn_from_3d_deg))
      << "max_turn_from_3d_deg must be a number of degrees (negative: never re-solve turned), got NaN";
  const int K = regressor->num_keypoints();
  for (const auto* list : {&o.torso, &o.reference_3d, &o.left_side, &o.right_side, &o.limbs}) {
    for (int k : *list) M3C_CHECK(k >= 0 && k < K) << "keypoint role index " << k << " outside [0, " << K << ")";
  }
  M3C_CHECK(o.torso.size() >= 3 && !o.reference_3d.empty() && o.left_side.size() == o.right_side.size())
      << "need >= 3 torso keypoints, >= 1 3D reference keypoint and as many left as right keypoints";
}

void BodyFitter::Validate(const FrameObservation& obs) const {
  const int K = regressor_->num_keypoints();
  M3C_CHECK(obs.keypoints.rows() == K) << "keypoints must be (" << K << ", 3), got (" << obs.keypoints.rows()
                                       << ", 3)";
  M3C_CHECK(obs.keypoints.allFinite()) << "keypoints contain NaN/Inf (mark missing keypoints with confidence 0)";
  M3C_CHECK(obs.keypoints3d.rows() == 0 || obs.keypoints3d.rows() == K)
      << "keypoints3d must be (" << K << ", 4) or empty, got (" << obs.keypoints3d.rows() << ", 4)";
  M3C_CHECK(obs.keypoints3d.allFinite()) << "keypoints3d contain NaN/Inf (mark missing ones with confidence 0)";
  const Intrinsics& c = obs.intrinsics;
  M3C_CHECK(std::isfinite(c.fx) && std::isfinite(c.fy) && std::isfinite(c.cx) && std::isfinite(c.cy) && c.fx > 0 &&
            c.fy > 0)
      << "intrinsics must be finite with positive focal lengths";
}

BodyFitter::Masked BodyFitter::Mask(const FrameObservation& obs) const {
  Masked m;
  m.keypoints = obs.keypoints;
  for (int k = 0; k < m.keypoints.rows(); ++k) {
    if (m.keypoints(k, 2) < options_.min_confidence) {
      m.keypoints(k, 2) = 0.0;
    } else {
      ++m.num_keypoints;
    }
  }
  if (obs.keypoints3d.rows() > 0 && options_.keypoints3d_weight > 0) {
    Observations4 q = obs.keypoints3d;
    int valid = 0;
    for (int k = 0; k < q.rows(); ++k) {
      if (q(k, 3) < options_.min_confidence) q(k, 3) = 0.0;
      valid += q(k, 3) > 0;
    }
    // The reference (hip centre) must be seen, or every relative point would carry its error.
    bool reference_seen = true;
    for (int r : options_.reference_3d) reference_seen = reference_seen && q(r, 3) > 0;
    if (reference_seen && valid >= 4) m.keypoints3d = std::move(q);
  }
  return m;
}

BodyState BodyFitter::ColdState(const FrameObservation& obs, const Masked& m) const {
  const int J = model_->num_joints(), B = model_->num_betas(), K = regressor_->num_keypoints();
  BodyState state;  // the rest pose at the origin
  state.body = Eigen::VectorXd::Zero(3 * (J - 1));
  state.betas = Eigen::VectorXd::Zero(B);

  // Orientation.
  Eigen::Matrix3d R;
  if (!TorsoTo3d(m, Posed(state, false), &R)) {
    // The model is y-up and faces +z; Rx(pi) turns it upright in the camera frame (y down) facing the camera,
    // with its left side on the image's right. Facing away is a further half turn about the vertical.
    double left_minus_right = 0.0;
    for (size_t i = 0; i < options_.left_side.size(); ++i) {
      const int l = options_.left_side[i], r = options_.right_side[i];
      if (m.keypoints(l, 2) > 0 && m.keypoints(r, 2) > 0) left_minus_right += m.keypoints(l, 0) - m.keypoints(r, 0);
    }
    R = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix();
    if (left_minus_right < 0) R = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix() * R;
  }
  state.root = RotationToAxisAngle(R);

  // Body pose from the 3D observations alone (no translation involved).
  if (m.keypoints3d.rows() > 0) {
    int iterations = 0;
    Solve(obs, m, nullptr, nullptr, true, false, &state, &iterations);
  }

  // Translation: linear least squares on the projection equations of the posed keypoints.
  const Observations3 posed = Posed(state, false);
  const Intrinsics& c = obs.intrinsics;
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  Eigen::Vector3d Atb = Eigen::Vector3d::Zero();
  for (int k = 0; k < K; ++k) {
    const double w = m.keypoints(k, 2);
    if (w <= 0) continue;
    const double du = m.keypoints(k, 0) - c.cx, dv = m.keypoints(k, 1) - c.cy;
    const Eigen::Vector3d x = posed.row(k).transpose();
    const Eigen::Vector3d a1(c.fx, 0.0, -du), a2(0.0, c.fy, -dv);
    const double b1 = du * x.z() - c.fx * x.x(), b2 = dv * x.z() - c.fy * x.y();
    AtA += w * w * (a1 * a1.transpose() + a2 * a2.transpose());
    Atb += w * w * (a1 * b1 + a2 * b2);
  }
  Eigen::Vector3d t = AtA.ldlt().solve(Atb);
  bool in_front = t.allFinite();
  for (int k = 0; k < K && in_front; ++k) {
    if (m.keypoints(k, 2) > 0) in_front = posed(k, 2) + t.z() > options_.min_depth;
  }
  if (!in_front) {
    // Degenerate geometry: place the body's centroid at the depth where its spread matches the keypoints'.
    Eigen::Vector2d ubar = Eigen::Vector2d::Zero();
    Eigen::Vector3d xbar = Eigen::Vector3d::Zero();
    double n = 0;
    for (int k = 0; k < K; ++k) {
      if (m.keypoints(k, 2) <= 0) continue;
      ubar += m.keypoints.block<1, 2>(k, 0).transpose();
      xbar += posed.row(k).transpose();
      n += 1;
    }
    ubar /= n, xbar /= n;
    double s2 = 0, s3 = 0;
    for (int k = 0; k < K; ++k) {
      if (m.keypoints(k, 2) <= 0) continue;
      s2 += (m.keypoints.block<1, 2>(k, 0).transpose() - ubar).squaredNorm();
      s3 += (posed.block<1, 2>(k, 0).transpose() - xbar.head<2>()).squaredNorm();
    }
    const double depth = s2 > 0 ? 0.5 * (c.fx + c.fy) * std::sqrt(s3 / s2) : 3.0;
    const double centroid_depth = std::max(depth, options_.min_depth + 2.0 * std::sqrt(s3 / n));
    t = Eigen::Vector3d((ubar.x() - c.cx) / c.fx * centroid_depth, (ubar.y() - c.cy) / c.fy * centroid_depth,
                        centroid_depth) -
        xbar;
  }
  state.transl = t;
  return state;
}

BodyState BodyFitter::Initialize(const FrameObservation& observation) const {
  Validate(observation);
  return ColdState(observation, Mask(observation));
}

void BodyFitter::AddTerms(const FrameObservation& obs, const Masked& m, const BodyState* previous,
                          const Eigen::Vector3d* predicted_transl, bool use_reprojection, BodyState* state,
                          ceres::Problem* problem_ptr) const {
  const int P = static_cast<int>(state->body.size()), B = static_cast<int>(state->betas.size());
  ceres::Problem& problem = *problem_ptr;
  double* t = state->transl.data();
  double* r = state->root.data();
  double* b = state->body.data();
  double* beta = state->betas.data();
  if (use_reprojection) {
    problem.AddResidualBlock(new KeypointReprojectionCost(model_, regressor_, obs.intrinsics, m.keypoints, 1.0,
                                                          options_.robust_sigma_px, options_.min_depth),
                             nullptr, {t, r, b, beta});
  }
  if (m.keypoints3d.rows() > 0) {
    // The pose from the 3D alone (no reprojection: the cold initialisation, a limb's re-solve) must land in the
    // 3D's basin, so its robust scale is a body's size: at keypoints3d_sigma a foot 0.5 m off barely pulls, and a
    // knee bent backwards (seen from behind) was initialised bent forwards with the keypoints fitting both.
    const double sigma = use_reprojection ? options_.keypoints3d_sigma : std::max(options_.keypoints3d_sigma, 1.0);
    problem.AddResidualBlock(new RelativePointsCost(model_, regressor_, m.keypoints3d, options_.reference_3d,
                                                    options_.keypoints3d_weight, sigma),
                             nullptr, {r, b, beta});
  }
  if (problem.NumResidualBlocks() == 0) return;
  if (use_reprojection && predicted_transl && options_.temporal_transl_weight > 0) {
    problem.AddResidualBlock(
        new WeightedPriorCost(*predicted_transl, Eigen::VectorXd::Constant(3, options_.temporal_transl_weight)),
        nullptr, t);
  }
  if (options_.pose_prior_weight > 0) {
    problem.AddResidualBlock(
        new WeightedPriorCost(Eigen::VectorXd::Zero(P), Eigen::VectorXd::Constant(P, options_.pose_prior_weight)),
        nullptr, b);
  }
  if (vposer_ && options_.vposer_weight > 0) {
    problem.AddResidualBlock(new motion::VPoserLatentCost(vposer_, P, {1.0}, options_.vposer_weight), nullptr, b);
  }
  if (previous && options_.temporal_pose_weight > 0) {
    problem.AddResidualBlock(
        new WeightedPriorCost(previous->body, Eigen::VectorXd::Constant(P, options_.temporal_pose_weight)), nullptr, b);
  }
  if (options_.shape_prior_weight > 0) {
    problem.AddResidualBlock(
        new WeightedPriorCost(Eigen::VectorXd::Zero(B), Eigen::VectorXd::Constant(B, options_.shape_prior_weight)),
        nullptr, beta);
  }
  if (previous && options_.temporal_betas_weight > 0) {
    problem.AddResidualBlock(
        new WeightedPriorCost(previous->betas, Eigen::VectorXd::Constant(B, options_.temporal_betas_weight)), nullptr,
        beta);
  }
}

double BodyFitter::FrameCost(const FrameObservation& obs, const Masked& m, BodyState state) const {
  ceres::Problem problem;
  AddTerms(obs, m, nullptr, nullptr, true, &state, &problem);
  double cost = 0.0;
  if (problem.NumResidualBlocks() > 0) {
    problem.Evaluate(ceres::Problem::EvaluateOptions(), &cost, nullptr, nullptr, nullptr);
  }
  return cost;
}

double BodyFitter::Solve(const FrameObservation& obs, const Masked& m, const BodyState* previous,
                         const Eigen::Vector3d* predicted_transl, bool free_pose, bool use_reprojection,
                         BodyState* state, int* iterations) const {
  ceres::Problem problem;
  AddTerms(obs, m, previous, predicted_transl, use_reprojection, state, &problem);
  if (problem.NumResidualBlocks() == 0) return 0.0;
  double* b = state->body.data();
  double* beta = state->betas.data();
  if (!free_pose) problem.SetParameterBlockConstant(b);
  if (!free_pose || !options_.optimize_betas) problem.SetParameterBlockConstant(beta);

  const BodyState before = *state;
  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = options_.max_iterations;
  solver.num_threads = 1;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);
  *iterations += std::max(0, static_cast<int>(summary.iterations.size()) - 1);
  const bool finite = state->transl.allFinite() && state->root.allFinite() && state->body.allFinite() &&
                      state->betas.allFinite() && std::isfinite(summary.final_cost);
  if (summary.termination_type == ceres::FAILURE || !finite) {
    *state = before;  // keep the start; its cost is what the caller compares
    return summary.initial_cost;
  }
  return summary.final_cost;
}

Observations3 BodyFitter::Posed(const BodyState& s, bool translated) const {
  const int J = model_->num_joints();
  std::vector<double> pose(3 * J);
  std::copy(s.root.data(), s.root.data() + 3, pose.begin());
  std::copy(s.body.data(), s.body.data() + 3 * (J - 1), pose.begin() + 3);
  Observations3 points(regressor_->num_keypoints(), 3);
  body::Keypoints<double>(*model_, *regressor_, 1, pose.data(), s.betas.data(), true,
                          translated ? s.transl.data() : nullptr, points.data());
  return points;
}

bool BodyFitter::TorsoTo3d(const Masked& m, const Observations3& points, Eigen::Matrix3d* R) const {
  if (m.keypoints3d.rows() == 0) return false;
  std::vector<Eigen::Vector3d> p, q;
  for (int k : options_.torso) {
    if (m.keypoints3d(k, 3) <= 0) continue;
    p.push_back(points.row(k).transpose());
    q.push_back(m.keypoints3d.block<1, 3>(k, 0).transpose());
  }
  if (p.size() < 3) return false;
  *R = Kabsch(p, q);
  return true;
}

void BodyFitter::Measure(const FrameObservation& obs, const Masked& m, FrameFitResult* result) const {
  const int K = regressor_->num_keypoints();
  const Observations3 points = Posed(result->state, true);
  const Intrinsics& c = obs.intrinsics;
  result->keypoint_error_px.resize(K);
  double sum = 0.0;
  int used = 0;
  for (int k = 0; k < K; ++k) {
    const double z = points(k, 2);
    if (!(z > 1e-9)) {
      result->keypoint_error_px[k] = -1.0;
      continue;
    }
    const Eigen::Vector2d uv(c.fx * points(k, 0) / z + c.cx, c.fy * points(k, 1) / z + c.cy);
    const double error = (uv - obs.keypoints.block<1, 2>(k, 0).transpose()).norm();
    result->keypoint_error_px[k] = error;
    if (m.keypoints(k, 2) > 0) sum += error, ++used;
  }
  result->num_keypoints = m.num_keypoints;
  result->reprojection_error_px = used > 0 ? sum / used : 0.0;
}

double BodyFitter::LimbErrorFrom3d(const Masked& m, const BodyState& s) const {
  if (m.keypoints3d.rows() == 0) return -1.0;
  Eigen::Vector3d posed_ref = Eigen::Vector3d::Zero(), seen_ref = Eigen::Vector3d::Zero();
  const Observations3 points = Posed(s, false);
  for (int k : options_.reference_3d) {
    if (m.keypoints3d(k, 3) <= 0) return -1.0;
    posed_ref += points.row(k).transpose();
    seen_ref += m.keypoints3d.block<1, 3>(k, 0).transpose();
  }
  double worst = -1.0;
  for (int k : options_.limbs) {
    if (m.keypoints3d(k, 3) <= 0) continue;
    const Eigen::Vector3d d = (points.row(k).transpose() - posed_ref / options_.reference_3d.size()) -
                              (m.keypoints3d.block<1, 3>(k, 0).transpose() - seen_ref / options_.reference_3d.size());
    worst = std::max(worst, d.norm());
  }
  return worst;
}

double BodyFitter::TorsoTurnFrom3d(const Masked& m, const BodyState& s) const {
  Eigen::Matrix3d R;
  if (m.keypoints3d.rows() == 0 || !TorsoTo3d(m, Posed(s, false), &R)) return -1.0;
  return std::acos(std::clamp(0.5 * (R.trace() - 1.0), -1.0, 1.0)) * 180.0 / M_PI;
}

FrameFitResult BodyFitter::Fit(const FrameObservation& obs, const BodyState* previous,
                               const Eigen::Vector3d* predicted_transl) const {
  Validate(obs);
  const int J = model_->num_joints(), B = model_->num_betas();
  if (previous) {
    M3C_CHECK(previous->body.size() == 3 * (J - 1) && previous->betas.size() == B && previous->transl.allFinite() &&
              previous->root.allFinite() && previous->body.allFinite() && previous->betas.allFinite())
        << "previous state must have body (" << 3 * (J - 1) << ") and betas (" << B << "), all finite";
  }
  const Masked m = Mask(obs);
  FrameFitResult result;
  if (m.num_keypoints < options_.min_keypoints) {
    result.status = "too_few_keypoints";
    if (previous) {
      result.state = *previous;
      result.warm_started = true;
    } else {
      result.state.body = Eigen::VectorXd::Zero(3 * (J - 1));
      result.state.betas = Eigen::VectorXd::Zero(B);
    }
    Measure(obs, m, &result);
    return result;
  }
  result.status = "ok";
  auto cold_fit = [&](int* iterations) {
    BodyState state = ColdState(obs, m);
    Solve(obs, m, nullptr, nullptr, false, true, &state, iterations);  // translation and orientation first
    return state;
  };
  if (previous) {
    BodyState warm = *previous;
    result.cost = Solve(obs, m, previous, predicted_transl, true, true, &warm, &result.iterations);
    result.state = warm;
    result.warm_started = true;
    Measure(obs, m, &result);
    // A candidate solved with the warm fit's temporal terms replaces it when the frame's own objective
    // (keypoints, 3D, priors: without the pull towards the previous frame) is the lower one.
    auto resolve_warm = [&](BodyState candidate) {
      const double cost = Solve(obs, m, previous, predicted_transl, true, true, &candidate, &result.iterations);
      if (FrameCost(obs, m, candidate) < FrameCost(obs, m, result.state)) {
        result.state = candidate;
        result.cost = cost;
        Measure(obs, m, &result);
      }
    };
    if (options_.max_turn_from_3d_deg >= 0 && TorsoTurnFrom3d(m, result.state) > options_.max_turn_from_3d_deg) {
      // In a side view the keypoints fit a body turned half a turn about as well as the right one, and the
      // robust 3D term barely pulls a torso that far off: a warm start on the wrong side stays there. The frame
      // is solved again from where the warm fit put the person, turned and posed as the cold initialisation
      // from the 3D torso, with the same temporal terms (a cold fit's depth would jump), and that solution is
      // kept when the frame's own objective (keypoints, 3D, priors: without the pull towards the previous
      // frame) is the lower one.
      BodyState turned = ColdState(obs, m);
      turned.transl = result.state.transl;
      turned.betas = result.state.betas;
      resolve_warm(turned);
    }
    if (options_.max_limb_from_3d_m >= 0 && LimbErrorFrom3d(m, result.state) > options_.max_limb_from_3d_m) {
      // A limb the warm start carried into the wrong basin (a knee bent backwards where the 3D has a step
      // forward): the body pose starts again from the rest pose posed by the 3D alone, where the warm fit put and
      // turned the person, and is solved with the same temporal terms; kept when the frame's own objective is the
      // lower one, as for the turn above.
      BodyState posed = result.state;
      posed.body.setZero();
      Solve(obs, m, nullptr, nullptr, true, false, &posed, &result.iterations);
      posed.transl = result.state.transl;
      resolve_warm(posed);
    }
    if (result.reprojection_error_px > options_.reinit_error_px) {
      // A warm fit this far off the keypoints means the track's motion no longer predicts it (a fast turn, or a
      // depth that drifted: depth is weakly observed, and a constant-velocity prediction of a drifting depth
      // feeds the drift, metres per frame). The cold fit is solved without that prediction and kept when it
      // matches the keypoints better; comparing with the prediction's cost included would keep the drift.
      FrameFitResult cold;
      cold.state = cold_fit(&result.iterations);
      cold.cost = Solve(obs, m, previous, nullptr, true, true, &cold.state, &result.iterations);
      Measure(obs, m, &cold);
      if (cold.reprojection_error_px < result.reprojection_error_px) {
        result.state = cold.state;
        result.cost = cold.cost;
        result.warm_started = false;
      }
    }
  } else {
    result.state = cold_fit(&result.iterations);
    result.cost = Solve(obs, m, nullptr, nullptr, true, true, &result.state, &result.iterations);
  }
  // A unique axis-angle (angle in [0, pi]) for the root; the body pose stays as solved.
  result.state.root = RotationToAxisAngle(AxisAngleToRotationMatrix(result.state.root));
  Measure(obs, m, &result);
  return result;
}

std::vector<FrameFitResult> BodyFitter::FitSequence(const std::vector<FrameObservation>& observations,
                                                    const std::vector<char>& restart,
                                                    const std::vector<double>& times) const {
  const size_t n = observations.size();
  M3C_CHECK(restart.empty() || restart.size() == n)
      << "restart must be empty or have one flag per frame (" << n << "), got " << restart.size();
  M3C_CHECK(times.empty() || times.size() == n) << "times must be empty or have one per frame (" << n << "), got "
                                                << times.size();
  for (size_t i = 1; i < times.size(); ++i) {
    M3C_CHECK(std::isfinite(times[i]) && times[i] > times[i - 1]) << "times must be finite and increasing";
  }
  auto time_of = [&](size_t i) { return times.empty() ? static_cast<double>(i) : times[i]; };
  std::vector<FrameFitResult> results;
  results.reserve(n);
  int last = -1, before_last = -1;  // the last two good frames since the last restart
  for (size_t i = 0; i < n; ++i) {
    if (!restart.empty() && restart[i]) last = before_last = -1;
    const BodyState* previous = last >= 0 ? &results[last].state : nullptr;
    Eigen::Vector3d predicted;
    const Eigen::Vector3d* prediction = nullptr;
    if (previous && before_last >= 0) {  // a prediction needs a velocity: no prior on the first warm frame
      const Eigen::Vector3d velocity = (previous->transl - results[before_last].state.transl) /
                                       (time_of(last) - time_of(before_last));
      predicted = previous->transl + velocity * (time_of(i) - time_of(last));
      prediction = &predicted;
    }
    results.push_back(Fit(observations[i], previous, prediction));
    if (results.back().status == "ok") {
      // A velocity is only read between two warm fits: a cold fit starts the motion afresh (the jump from the
      // last frame is no velocity), and its depth, from the keypoints alone, is off by up to metres, which the
      // next warm fit corrects; that correction extrapolated at the translation prior's weight fed a depth
      // oscillation of metres per frame (the body's size following it) on the video benchmark.
      before_last = results.back().warm_started && last >= 0 && results[last].warm_started ? last : -1;
      last = static_cast<int>(i);
    }
  }
  return results;
}

}  // namespace m3c::fit
