#include "fit/frame_fit.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "../body/test_model.h"

namespace m3c::fit {
namespace {

using body::testing::MakeTestModel;
using body::testing::RandomVector;

// 17 keypoints picked from the test model's joints in COCO-17's roles (shoulders 5, 6; hips 11, 12).
const int kJointOfKeypoint[17] = {15, 12, 9, 13, 14, 16, 17, 18, 19, 20, 21, 1, 2, 4, 5, 7, 8};

body::KeypointRegressor JointPicks(const body::BodyModel& model) {
  Eigen::SparseMatrix<double, Eigen::RowMajor> vw(17, model.num_vertices()), jw(17, model.num_joints());
  std::vector<Eigen::Triplet<double>> t;
  for (int k = 0; k < 17; ++k) t.emplace_back(k, kJointOfKeypoint[k], 1.0);
  jw.setFromTriplets(t.begin(), t.end());
  return body::KeypointRegressor(vw, jw);
}

struct Truth {
  BodyState state;
  Observations3 points;  // camera frame
};

Truth MakeTruth(const body::BodyModel& model, const body::KeypointRegressor& reg, unsigned seed, double pose_scale,
                const Eigen::Vector3d& transl) {
  Truth t;
  const Eigen::Vector3d tilt(RandomVector(3, 0.2, seed).data());
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                            Eigen::AngleAxisd(tilt.norm(), tilt.normalized()).toRotationMatrix();
  const Eigen::AngleAxisd aa(R);
  t.state.root = aa.angle() * aa.axis();
  t.state.body = Eigen::Map<const Eigen::VectorXd>(RandomVector(3 * (model.num_joints() - 1), pose_scale, seed + 1).data(),
                                                   3 * (model.num_joints() - 1));
  t.state.betas = Eigen::Map<const Eigen::VectorXd>(RandomVector(model.num_betas(), 0.5, seed + 2).data(), model.num_betas());
  t.state.transl = transl;
  std::vector<double> pose(3 * model.num_joints());
  std::copy(t.state.root.data(), t.state.root.data() + 3, pose.begin());
  std::copy(t.state.body.data(), t.state.body.data() + t.state.body.size(), pose.begin() + 3);
  t.points.resize(reg.num_keypoints(), 3);
  body::Keypoints<double>(model, reg, 1, pose.data(), t.state.betas.data(), true, t.state.transl.data(), t.points.data());
  return t;
}

FrameObservation Observe(const Truth& truth, const Intrinsics& cam, double pixel_noise, double metric_noise,
                         bool with3d, unsigned seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  const int K = static_cast<int>(truth.points.rows());
  FrameObservation o;
  o.intrinsics = cam;
  o.keypoints.resize(K, 3);
  for (int k = 0; k < K; ++k) {
    const Eigen::Vector3d x = truth.points.row(k).transpose();
    o.keypoints.row(k) << cam.fx * x.x() / x.z() + cam.cx + pixel_noise * n(gen),
        cam.fy * x.y() / x.z() + cam.cy + pixel_noise * n(gen), 0.9;
  }
  if (with3d) {
    // MediaPipe-like: metric, camera axes, a different origin (here 1 m away), some noise.
    o.keypoints3d.resize(K, 4);
    for (int k = 0; k < K; ++k) {
      o.keypoints3d.row(k) << truth.points(k, 0) + 1.0 + metric_noise * n(gen), truth.points(k, 1) + metric_noise * n(gen),
          truth.points(k, 2) - 3.0 + metric_noise * n(gen), 0.9;
    }
  }
  return o;
}

Observations3 FittedPoints(const body::BodyModel& model, const body::KeypointRegressor& reg, const BodyState& s) {
  std::vector<double> pose(3 * model.num_joints());
  std::copy(s.root.data(), s.root.data() + 3, pose.begin());
  std::copy(s.body.data(), s.body.data() + s.body.size(), pose.begin() + 3);
  Observations3 out(reg.num_keypoints(), 3);
  body::Keypoints<double>(model, reg, 1, pose.data(), s.betas.data(), true, s.transl.data(), out.data());
  return out;
}

double MeanDistance(const Observations3& a, const Observations3& b) { return (a - b).rowwise().norm().mean(); }

const Intrinsics kCamera{1000.0, 1000.0, 480.0, 270.0};

TEST(BodyFitter, InitializationIsExactOnExactData) {
  // Zero body pose and betas: Kabsch gives the orientation and the linear solve the translation exactly.
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  Truth truth = MakeTruth(model, reg, 1, 0.0, {0.3, -0.2, 4.0});
  truth.state.betas.setZero();
  truth.points = FittedPoints(model, reg, truth.state);
  const BodyFitter fitter(&model, &reg, FitOptions());
  const BodyState init = fitter.Initialize(Observe(truth, kCamera, 0.0, 0.0, true, 1));
  const Eigen::Matrix3d R0 = Eigen::AngleAxisd(truth.state.root.norm(), truth.state.root.normalized()).toRotationMatrix();
  const Eigen::Matrix3d R1 = Eigen::AngleAxisd(init.root.norm(), init.root.normalized()).toRotationMatrix();
  EXPECT_LT(Eigen::AngleAxisd(R0.transpose() * R1).angle(), 1e-6);
  EXPECT_LT((init.transl - truth.state.transl).norm(), 1e-6);
  EXPECT_LT(init.body.norm(), 1e-6);
}

// Root-relative distance: what a monocular fit can recover independently of the size-depth ambiguity.
double MeanRelativeDistance(const Observations3& a, const Observations3& b) {
  const Eigen::RowVector3d ca = a.colwise().mean(), cb = b.colwise().mean();
  return ((a.rowwise() - ca) - (b.rowwise() - cb)).rowwise().norm().mean();
}

double BearingErrorRadians(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::acos(std::clamp(a.normalized().dot(b.normalized()), -1.0, 1.0));
}

TEST(BodyFitter, RecoversPoseAndTranslationFromNoisyKeypointsAnd3D) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  FitOptions options;
  options.pose_prior_weight = 0.5;
  const BodyFitter fitter(&model, &reg, options);
  for (unsigned seed : {10u, 20u, 30u}) {
    for (bool mean_shape : {true, false}) {
      Truth truth = MakeTruth(model, reg, seed, 0.3, {0.3, -0.2, 4.0});
      if (mean_shape) {
        truth.state.betas.setZero();
        truth.points = FittedPoints(model, reg, truth.state);
      }
      const FrameObservation o = Observe(truth, kCamera, 1.0, 0.01, true, seed);
      const FrameFitResult r = fitter.Fit(o, nullptr);
      SCOPED_TRACE("seed " + std::to_string(seed) + (mean_shape ? " mean shape" : " random shape"));
      EXPECT_EQ(r.status, "ok");
      EXPECT_FALSE(r.warm_started);
      EXPECT_EQ(r.num_keypoints, 17);
      // 1 px of noise per axis: the fitted keypoints sit about that far from the observations.
      EXPECT_LT(r.reprojection_error_px, 2.0);
      const Observations3 x = FittedPoints(model, reg, r.state);
      EXPECT_LT(MeanRelativeDistance(x, truth.points), 0.04);
      EXPECT_LT(BearingErrorRadians(r.state.transl, truth.state.transl), 0.01);
      // Depth: close with the prior's mean shape (the pose prior's pull on the limbs still biases it); with
      // another shape, size trades against depth (the betas are pulled to the prior's mean): a relative bound.
      const double depth_error = std::abs(r.state.transl.z() - truth.state.transl.z());
      EXPECT_LT(depth_error, mean_shape ? 0.08 : 0.1 * truth.state.transl.z());
      // The reported per-keypoint errors agree with a projection computed here.
      for (int k = 0; k < 17; ++k) {
        const Eigen::Vector2d uv(kCamera.fx * x(k, 0) / x(k, 2) + kCamera.cx, kCamera.fy * x(k, 1) / x(k, 2) + kCamera.cy);
        EXPECT_NEAR(r.keypoint_error_px[k], (uv - o.keypoints.block<1, 2>(k, 0).transpose()).norm(), 1e-9);
      }
    }
  }
}

TEST(BodyFitter, WarmStartedSequenceTracksAMovingBody) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  FitOptions options;
  options.pose_prior_weight = 0.5;
  options.temporal_pose_weight = 1.0;
  const BodyFitter fitter(&model, &reg, options);
  Truth base = MakeTruth(model, reg, 40, 0.3, {0.0, 0.0, 4.0});
  base.state.betas.setZero();  // the shape prior's mean: depth is then observable (see the test above)
  std::vector<FrameObservation> obs;
  std::vector<Truth> truths;
  for (int f = 0; f < 6; ++f) {
    Truth t = base;
    t.state.transl = Eigen::Vector3d(-0.5 + 0.1 * f, 0.0, 4.0 + 0.05 * f);
    t.state.body *= 1.0 + 0.05 * f;
    t.points = FittedPoints(model, reg, t.state);
    obs.push_back(Observe(t, kCamera, 1.0, 0.01, true, 100 + f));
    truths.push_back(t);
  }
  obs[3].keypoints.col(2).setZero();  // a frame with no keypoints: reported, and skipped for warm starts
  const auto results = fitter.FitSequence(obs, {});
  ASSERT_EQ(results.size(), 6u);
  EXPECT_EQ(results[3].status, "too_few_keypoints");
  for (int f : {0, 1, 2, 4, 5}) {
    EXPECT_EQ(results[f].status, "ok") << f;
    EXPECT_EQ(results[f].warm_started, f > 0) << f;
    EXPECT_LT(results[f].reprojection_error_px, 2.0) << f;
    EXPECT_LT(BearingErrorRadians(results[f].state.transl, truths[f].state.transl), 0.02) << f;
    EXPECT_LT(std::abs(results[f].state.transl.z() - truths[f].state.transl.z()), 0.05 * truths[f].state.transl.z()) << f;
    // The temporal prior makes the fit lag a pose that keeps changing: looser than the single-frame bound.
    EXPECT_LT(MeanRelativeDistance(FittedPoints(model, reg, results[f].state), truths[f].points), 0.08) << f;
  }
  // Frame 4 starts from frame 2's state (the last good one).
  EXPECT_TRUE(results[3].state.transl.isApprox(results[2].state.transl));
}

TEST(BodyFitter, TranslationPriorExtrapolatesAtConstantVelocityOverTheFrameTimes) {
  // With an overwhelming translation prior, frame 3 lands on the prediction from frames 1 and 2, spaced by the
  // given times (frame 3 comes two time units after frame 2 here). Frame 2 has no prediction: frame 0 was a cold
  // fit, and no velocity is read across one.
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  FitOptions options;
  options.temporal_transl_weight = 1e9;
  const BodyFitter fitter(&model, &reg, options);
  std::vector<FrameObservation> obs;
  for (int f = 0; f < 4; ++f) {
    const Truth t = MakeTruth(model, reg, 50, 0.2, {-0.3 + 0.1 * f, 0.1, 4.0 + 0.2 * f});
    obs.push_back(Observe(t, kCamera, 0.5, 0.01, true, 200 + f));
  }
  const auto results = fitter.FitSequence(obs, {}, {0.0, 1.0, 2.0, 4.0});
  const Eigen::Vector3d r0 = results[0].state.transl, r1 = results[1].state.transl, r2 = results[2].state.transl;
  EXPECT_LT((results[3].state.transl - (r2 + 2.0 * (r2 - r1))).norm(), 1e-3);
  EXPECT_GT((r2 - (r1 + (r1 - r0))).norm(), 1e-2);  // frame 2 is fitted to its keypoints, not to frames 0-1
  EXPECT_THROW(fitter.FitSequence(obs, {}, {0.0, 2.0, 1.0, 3.0}), std::invalid_argument);
}

TEST(BodyFitter, DriftingWarmStartRestartsColdWithoutTheVelocityPrediction) {
  // A person 2.5 m closer in the second frame than in all the others: the velocity of the second and third
  // (warm) frames, extrapolated, pulls the depth away while the keypoints say it stays. Once the warm fit is more than
  // reinit_error_px off, the cold fit (without the prediction) must win and restart the velocity; compared with the
  // prediction's cost included, the drift was kept and grew by metres per frame.
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  FitOptions options;
  options.temporal_transl_weight = 3000.0;  // the old default, under which the prediction carries the depth
  const BodyFitter fitter(&model, &reg, options);
  Truth base = MakeTruth(model, reg, 60, 0.2, {0.0, 0.0, 4.0});
  base.state.betas.setZero();
  std::vector<FrameObservation> obs;
  const int n = 30;
  for (int f = 0; f < n; ++f) {
    Truth t = base;
    t.state.transl.z() = f == 1 ? 1.5 : 4.0;
    t.points = FittedPoints(model, reg, t.state);
    obs.push_back(Observe(t, kCamera, 0.5, 0.01, false, 300 + f));
  }
  const auto results = fitter.FitSequence(obs, {});
  bool restarted = false;
  for (int f = 3; f < n; ++f) restarted |= !results[f].warm_started;
  EXPECT_TRUE(restarted);
  for (int f = 1; f < n; ++f) {
    EXPECT_LT(results[f].state.transl.z(), 8.0) << f;
    EXPECT_LE(results[f].reprojection_error_px, FitOptions().reinit_error_px) << f;
  }
  for (int f = n - 10; f < n; ++f) {
    EXPECT_LT(results[f].reprojection_error_px, 2.0) << f;
    EXPECT_LT(std::abs(results[f].state.transl.z() - 4.0), 0.5) << f;
  }
}

double RootAngleRadians(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const auto R = [](const Eigen::Vector3d& v) -> Eigen::Matrix3d {
    if (v.norm() < 1e-12) return Eigen::Matrix3d::Identity();
    return Eigen::AngleAxisd(v.norm(), v.normalized()).toRotationMatrix();
  };
  return Eigen::AngleAxisd(R(a).transpose() * R(b)).angle();
}

TEST(BodyFitter, WarmStartTurnedAwayFromThe3DTorsoIsTurnedBack) {
  // A side view of a straight-limbed body, its face unseen: the 2D keypoints fit the body turned half a turn
  // about the vertical about as well as the truth (only the depth order of its left and right sides differs),
  // and the robust 3D term barely pulls a torso that far off. Warm-started on the wrong side, the old fit stayed
  // there; a warm fit turned more than max_turn_from_3d_deg from the 3D torso is solved again turned as the 3D.
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  Truth truth;
  const Eigen::Matrix3d side_on = Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix() *
                                  Eigen::AngleAxisd(0.5 * M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix();
  const Eigen::AngleAxisd aa(side_on);
  truth.state.root = aa.angle() * aa.axis();
  truth.state.body = Eigen::VectorXd::Zero(3 * (model.num_joints() - 1));
  truth.state.betas = Eigen::VectorXd::Zero(model.num_betas());
  truth.state.transl = Eigen::Vector3d(0.0, 0.0, 6.0);
  truth.points = FittedPoints(model, reg, truth.state);
  FrameObservation o = Observe(truth, kCamera, 0.3, 0.01, true, 7);
  for (int k : {0, 1, 2, 3, 4}) o.keypoints(k, 2) = 0.0, o.keypoints3d(k, 3) = 0.0;  // the head unseen
  BodyState wrong_side = truth.state;
  const Eigen::AngleAxisd turned(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY()).toRotationMatrix() * side_on);
  wrong_side.root = turned.angle() * turned.axis();
  FitOptions old_rule;
  old_rule.max_turn_from_3d_deg = -1.0;
  old_rule.max_limb_from_3d_m = -1.0;  // the limb check re-solves a half-turned body's limbs (and turns it) too
  const FrameFitResult kept = BodyFitter(&model, &reg, old_rule).Fit(o, &wrong_side);
  const FrameFitResult restarted = BodyFitter(&model, &reg, FitOptions()).Fit(o, &wrong_side);
  // The premise: the warm fit ends half a turn off yet on the keypoints, so only the 3D can tell.
  EXPECT_TRUE(kept.warm_started);
  EXPECT_GT(RootAngleRadians(kept.state.root, truth.state.root), 0.75 * M_PI);
  EXPECT_LT(kept.reprojection_error_px, FitOptions().reinit_error_px);
  EXPECT_LT(RootAngleRadians(restarted.state.root, truth.state.root), 0.1);
  EXPECT_LT(restarted.reprojection_error_px, 1.0);
  // Re-solved from where the warm fit put the person, not from a cold depth: it stays a warm fit.
  EXPECT_TRUE(restarted.warm_started);
  EXPECT_LT((restarted.state.transl - truth.state.transl).norm(), 0.1);
  // A warm start on the right side is kept.
  const FrameFitResult right = BodyFitter(&model, &reg, FitOptions()).Fit(o, &truth.state);
  EXPECT_TRUE(right.warm_started);
  EXPECT_LT(RootAngleRadians(right.state.root, truth.state.root), 0.1);
}

TEST(BodyFitter, RejectsBadInput) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = JointPicks(model);
  const BodyFitter fitter(&model, &reg, FitOptions());
  FrameObservation o;
  o.intrinsics = kCamera;
  o.keypoints = Observations3::Constant(16, 3, 1.0);
  EXPECT_THROW(fitter.Fit(o, nullptr), std::invalid_argument);
  o.keypoints = Observations3::Constant(17, 3, 1.0);
  o.keypoints(3, 0) = std::nan("");
  EXPECT_THROW(fitter.Fit(o, nullptr), std::invalid_argument);
  o.keypoints(3, 0) = 1.0;
  o.intrinsics.fx = 0.0;
  EXPECT_THROW(fitter.Fit(o, nullptr), std::invalid_argument);
  FitOptions bad;
  bad.torso = {0, 1, 40};
  EXPECT_THROW(BodyFitter(&model, &reg, bad), std::invalid_argument);
  FitOptions no_turn;
  no_turn.max_turn_from_3d_deg = std::nan("");  // NaN would silently switch the rule off
  EXPECT_THROW(BodyFitter(&model, &reg, no_turn), std::invalid_argument);
  FitOptions no_limbs;
  no_limbs.max_limb_from_3d_m = std::nan("");
  EXPECT_THROW(BodyFitter(&model, &reg, no_limbs), std::invalid_argument);
  FitOptions bad_limb;
  bad_limb.limbs = {7, 17};
  EXPECT_THROW(BodyFitter(&model, &reg, bad_limb), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::fit
