#include "motion/world_optimizer.h"

#include <cmath>

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "../body/test_model.h"

namespace m3c::motion {
namespace {

using body::testing::MakeTestModel;
using body::testing::RandomVector;

// A person standing still in front of a camera that slides sideways; keypoints are the 24 joints.
const body::BodyModel& Model() {
  static const body::BodyModel model = MakeTestModel();
  return model;
}

struct Scene {
  const body::BodyModel& model = Model();
  body::KeypointRegressor joints = body::IdentityJointRegressor(Model());
  TrackInput truth, init;
  CameraInput cameras;
};

Scene MakeScene(int n) {
  Scene s;  // returned by guaranteed copy elision
  const int J = s.model.num_joints(), B = s.model.num_betas();
  s.truth.transl = RowMatrixXd::Zero(n, 3);
  s.truth.root = RowMatrixXd::Zero(n, 3);
  s.truth.body = RowMatrixXd::Zero(n, 3 * (J - 1));
  s.truth.betas = Eigen::VectorXd::Zero(B);
  auto body_pose = RandomVector(3 * (J - 1), 0.3, 5);
  for (int f = 0; f < n; ++f) {
    s.truth.transl.row(f) << 0.02 * f, 0.0, 0.0;
    s.truth.root.row(f) << 0.0, 0.05 * f, 0.0;
    s.truth.body.row(f) = Eigen::Map<const Eigen::RowVectorXd>(body_pose.data(), 3 * (J - 1));
  }
  s.cameras.intrinsics = RowMatrixXd(n, 4);
  s.truth.keypoints = RowMatrixXd(n, 3 * J);
  for (int f = 0; f < n; ++f) {
    Eigen::Matrix4d world_from_cam = Eigen::Matrix4d::Identity();
    world_from_cam.topRightCorner<3, 1>() << 0.1 * f, 0.0, -4.0;
    s.cameras.world_from_cam.push_back(world_from_cam);
    s.cameras.intrinsics.row(f) << 800, 800, 320, 240;
    std::vector<double> pose(3 * J), pts(3 * J);
    pose[0] = s.truth.root(f, 0), pose[1] = s.truth.root(f, 1), pose[2] = s.truth.root(f, 2);
    for (int k = 0; k < 3 * (J - 1); ++k) pose[3 + k] = s.truth.body(f, k);
    body::KeypointsWithJacobian(s.model, s.joints, pose.data(), s.truth.betas.data(), s.truth.transl.row(f).data(),
                                pts.data(), nullptr);
    for (int j = 0; j < J; ++j) {
      const Eigen::Vector3d xc = Eigen::Vector3d(pts[3 * j], pts[3 * j + 1], pts[3 * j + 2]) -
                                 world_from_cam.topRightCorner<3, 1>();
      s.truth.keypoints(f, 3 * j) = 800 * xc.x() / xc.z() + 320;
      s.truth.keypoints(f, 3 * j + 1) = 800 * xc.y() / xc.z() + 240;
      s.truth.keypoints(f, 3 * j + 2) = 1.0;
    }
  }
  s.init = s.truth;
  for (int f = 0; f < n; ++f) s.init.transl.row(f) += Eigen::RowVector3d(0.15, -0.1, 0.4);
  return s;
}

OptimizerConfig RootOnlyConfig() {
  OptimizerConfig config = DefaultOptimizerConfig();
  config.stages.resize(2);  // translation, then translation + orientation
  config.stages[1].scale = false;
  // Keypoints alone, so that the truth is the exact minimum (the default's joint acceleration would bias the
  // turning body's joints by a fraction of a millimetre).
  for (auto& stage : config.stages) stage.weights.erase("joint_acceleration");
  return config;
}

TEST(WorldOptimizer, RecoversTranslationFromKeypoints) {
  Scene s = MakeScene(12);
  WorldOptimizer opt(&s.model, &s.joints, nullptr, RootOnlyConfig());
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  ASSERT_EQ(result.stages.size(), 2u);
  for (const auto& stage : result.stages) {
    EXPECT_EQ(stage.status, "ok") << stage.message;
    EXPECT_LE(stage.objective_after, stage.objective_before);
  }
  EXPECT_LT((result.tracks[0].transl - s.truth.transl).cwiseAbs().maxCoeff(), 1e-4);
}

// A term whose residual is NaN as soon as the first frame's translation differs from `start`
// (start = NaN: always).
struct NanWhenMoved : ceres::SizedCostFunction<1, 3> {
  double start;
  explicit NanWhenMoved(double s) : start(s) {}
  bool Evaluate(double const* const* p, double* r, double** j) const override {
    r[0] = p[0][0] == start ? 0.0 : std::nan("");
    if (j && j[0]) j[0][0] = j[0][1] = j[0][2] = 0.0;
    return true;
  }
};

TEST(WorldOptimizer, StageWhoseObjectiveIsNaNIsRevertedAndStops) {
  Scene s = MakeScene(6);
  OptimizerConfig config = RootOnlyConfig();
  config.stages[1].weights["broken"] = 1.0;
  config.stages.push_back(config.stages[0]);
  config.stages[2].name = "after";
  WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
  opt.AddTerm("broken", [](ceres::Problem* problem, const WorldOptimizer::Variables& v, double) {
    problem->AddResidualBlock(new NanWhenMoved(std::nan("")), nullptr, v.transl[0][0]);
  });
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  EXPECT_EQ(result.stages[0].status, "ok");
  EXPECT_EQ(result.stages[1].status, "reverted");
  EXPECT_NE(result.stages[1].message.find("not finite"), std::string::npos) << result.stages[1].message;
  EXPECT_EQ(result.stages[2].status, "skipped");
  EXPECT_TRUE(result.stopped_early);
  EXPECT_TRUE(result.tracks[0].transl.allFinite());
  // The state is the one stage 0 left: translation already recovered.
  EXPECT_LT((result.tracks[0].transl - s.truth.transl).cwiseAbs().maxCoeff(), 1e-4);
}

TEST(WorldOptimizer, NaNTrialStepsAreRejectedBySolver) {
  Scene s = MakeScene(6);
  OptimizerConfig config = RootOnlyConfig();
  config.stages.resize(1);
  config.stages[0].weights["broken"] = 1.0;
  WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
  opt.AddTerm("broken", [](ceres::Problem* problem, const WorldOptimizer::Variables& v, double) {
    problem->AddResidualBlock(new NanWhenMoved(v.transl[0][0][0]), nullptr, v.transl[0][0]);
  });
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  EXPECT_EQ(result.stages[0].status, "ok");
  EXPECT_TRUE(result.tracks[0].transl.allFinite());
  EXPECT_EQ(result.tracks[0].transl(0, 0), s.init.transl(0, 0));  // the NaN region was never entered
}

TEST(WorldOptimizer, StageThatMakesTheWorldWorseIsRevertedAndTheNextGoesOn) {
  Scene s = MakeScene(8);
  OptimizerConfig config = RootOnlyConfig();
  config.world_check = {{"reprojection", 1e-3}};
  // Velocity smoothing alone at a huge weight: its own objective falls by stopping the sliding person, the
  // images then disagree (the world check rises far beyond max_world_increase).
  StageConfig flatten{"flatten", true, false, false, false, false, false, {{"joint_smoothness", 1e6}}, 20};
  StageConfig after = config.stages[0];
  after.name = "after";
  config.stages.insert(config.stages.begin() + 1, flatten);
  config.stages.push_back(after);
  WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  ASSERT_EQ(result.stages.size(), 4u);
  EXPECT_EQ(result.stages[0].status, "ok");
  EXPECT_EQ(result.stages[1].status, "reverted");
  EXPECT_NE(result.stages[1].message.find("world check rose"), std::string::npos) << result.stages[1].message;
  EXPECT_EQ(result.stages[1].world_after, result.stages[1].world_before);
  EXPECT_EQ(result.stages[2].status, "ok");  // not stopped: the next stage starts from the state before
  EXPECT_EQ(result.stages[3].status, "ok");
  EXPECT_FALSE(result.stopped_early);
  EXPECT_LE(result.stages[2].world_after, result.stages[0].world_after * 1.05);
  EXPECT_LT((result.tracks[0].transl - s.truth.transl).cwiseAbs().maxCoeff(), 1e-4);
}

// A person gliding at constant speed through frames taken at irregular times: with the times, the joint
// acceleration (and the velocity's change) is zero on both the per-joint and the whole-pose blocks; treated as
// equally spaced, the longer steps look like accelerations.
TEST(WorldOptimizer, StencilsFollowTheFrameTimes) {
  const std::vector<double> times = {0.0, 0.033, 0.1, 0.133, 0.2, 0.3, 0.333, 0.4};
  Scene s = MakeScene(static_cast<int>(times.size()));
  for (int f = 0; f < static_cast<int>(times.size()); ++f) {
    s.truth.transl.row(f) << 1.2 * times[f], 0.0, 0.3 * times[f];
    s.truth.root.row(f).setZero();
  }
  s.init = s.truth;
  for (const bool body_free : {true, false}) {  // per-joint blocks, whole pose blocks
    OptimizerConfig config;
    config.world_check.clear();
    config.stages = {{"accel", true, false, body_free, false, false, false, {{"joint_acceleration", 1.0}}, 0}};
    WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
    s.cameras.times = times;
    const double timed = opt.Optimize({s.init}, s.cameras).stages[0].objective_before;
    s.cameras.times.clear();
    const double equal = opt.Optimize({s.init}, s.cameras).stages[0].objective_before;
    EXPECT_LT(timed, 1e-20) << "body free: " << body_free;
    EXPECT_GT(equal, 1e-4) << "body free: " << body_free;
  }
  s.cameras.times = {0.0, 0.1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6};  // not increasing
  OptimizerConfig config;
  config.stages = {{"accel", true, false, false, false, false, false, {{"joint_acceleration", 1.0}}, 0}};
  EXPECT_THROW(WorldOptimizer(&s.model, &s.joints, nullptr, config).Optimize({s.init}, s.cameras),
               std::invalid_argument);
}

// sqrt(w) (scale - target): a pull of the camera scale towards `target`.
struct PullScale : ceres::SizedCostFunction<1, 1> {
  double target, sqrt_w;
  PullScale(double t, double w) : target(t), sqrt_w(std::sqrt(w)) {}
  bool Evaluate(double const* const* p, double* r, double** j) const override {
    r[0] = sqrt_w * (p[0][0] - target);
    if (j && j[0]) j[0][0] = sqrt_w;
    return true;
  }
};

TEST(WorldOptimizer, ScalePriorHoldsTheScaleWithinTheEstimatesUncertainty) {
  Scene s = MakeScene(4);
  s.cameras.initial_scale = 2.0;
  s.cameras.scale_sigma = 0.05;
  const double prior_weight = 3.0, pull_weight = 50.0, target = 3.0;
  OptimizerConfig config = RootOnlyConfig();
  config.world_check.clear();
  config.stages = {{"scale", false, false, false, false, true, false, {{"scale_prior", prior_weight}, {"pull", 1.0}}, 50}};
  WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
  opt.AddTerm("pull", [&](ceres::Problem* problem, const WorldOptimizer::Variables& v, double) {
    problem->AddResidualBlock(new PullScale(target, pull_weight), nullptr, v.scale);
  });
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  ASSERT_EQ(result.stages[0].status, "ok") << result.stages[0].message;
  // The minimum of 1/2 w_p (log(s / s0) / sigma)^2 + 1/2 w (s - target)^2: its derivative's root, by bisection.
  auto derivative = [&](double x) {
    return prior_weight * std::log(x / 2.0) / (0.05 * 0.05 * x) + pull_weight * (x - target);
  };
  double lo = 2.0, hi = target;
  for (int k = 0; k < 200; ++k) (derivative(0.5 * (lo + hi)) > 0 ? hi : lo) = 0.5 * (lo + hi);
  EXPECT_NEAR(result.scale, 0.5 * (lo + hi), 2e-4);  // Ceres's function tolerance
  EXPECT_GT(result.scale, 2.0);
  EXPECT_LT(result.scale, 2.0 * std::exp(3 * 0.05));  // held within a few sigmas of the estimate

  // Without an uncertainty there is no prior: the pull alone decides.
  s.cameras.scale_sigma = 0.0;
  EXPECT_NEAR(opt.Optimize({s.init}, s.cameras).scale, target, 1e-6);
}

TEST(WorldOptimizer, UnknownTermIsReportedNotFatal) {
  Scene s = MakeScene(4);
  OptimizerConfig config = RootOnlyConfig();
  config.stages[1].weights["motion_prior"] = 1.0;
  WorldOptimizer opt(&s.model, &s.joints, nullptr, config);
  const OptimizerResult result = opt.Optimize({s.init}, s.cameras);
  EXPECT_EQ(result.stages[1].status, "ok");
  EXPECT_NE(result.stages[1].message.find("motion_prior unavailable"), std::string::npos);
}

TEST(WorldOptimizer, RejectsBadInputWithMessages) {
  Scene s = MakeScene(4);
  WorldOptimizer opt(&s.model, &s.joints, nullptr, RootOnlyConfig());
  TrackInput bad = s.init;
  bad.transl(1, 2) = std::nan("");
  EXPECT_THROW(opt.Optimize({bad}, s.cameras), std::invalid_argument);
  TrackInput late = s.init;
  late.first_frame = 2;
  EXPECT_THROW(opt.Optimize({late}, s.cameras), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::motion
