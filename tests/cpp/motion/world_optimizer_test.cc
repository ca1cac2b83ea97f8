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
