#include "fit/costs.h"

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "../body/cost_checks.h"

namespace m3c::fit {
namespace {

using body::testing::CheckGradient;
using body::testing::MakeTestModel;
using body::testing::ThreePointRegressor;

struct Params : body::testing::RandomPoseBlocks {
  Params(const body::BodyModel& m, unsigned seed) : RandomPoseBlocks(m, seed) {
    transl[2] += 5.0;  // in front of the camera
  }
};

// Camera-frame keypoints computed independently of the cost (plain Keypoints<double>).
Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> PointsOf(const body::BodyModel& model,
                                                                   const body::KeypointRegressor& reg,
                                                                   const Params& p) {
  std::vector<double> pose(3 * model.num_joints());
  std::copy(p.root.begin(), p.root.end(), pose.begin());
  std::copy(p.body.begin(), p.body.end(), pose.begin() + 3);
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> out(reg.num_keypoints(), 3);
  body::Keypoints<double>(model, reg, 1, pose.data(), p.betas.data(), true, p.transl.data(), out.data());
  return out;
}

TEST(FitCosts, ReprojectionJacobiansAndValue) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Params p(model, 3);
  const Intrinsics cam{900, 880, 480, 270};
  Observations3 obs(3, 3);
  // Residuals from ~0 to far beyond sigma, and one keypoint with no confidence.
  const auto x = PointsOf(model, reg, p);
  obs << cam.fx * x(0, 0) / x(0, 2) + cam.cx + 0.3, cam.fy * x(0, 1) / x(0, 2) + cam.cy, 0.9, 700, 100, 0.5, 100, 900,
      0.0;
  const double weight = 0.7, sigma = 30.0;
  KeypointReprojectionCost cost(&model, &reg, cam, obs, weight, sigma, 0.05);
  EXPECT_TRUE(CheckGradient(cost, {p.transl.data(), p.root.data(), p.body.data(), p.betas.data()}));

  // |r_k|^2 = weight conf^2 GM(|e|^2) with the pixel error computed here from the plain keypoints.
  std::vector<double> res(6);
  const double* params[4] = {p.transl.data(), p.root.data(), p.body.data(), p.betas.data()};
  ASSERT_TRUE(cost.Evaluate(params, res.data(), nullptr));
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector2d e(cam.fx * x(k, 0) / x(k, 2) + cam.cx - obs(k, 0), cam.fy * x(k, 1) / x(k, 2) + cam.cy - obs(k, 1));
    const double gm = sigma * sigma * e.squaredNorm() / (sigma * sigma + e.squaredNorm());
    const double expected = weight * obs(k, 2) * obs(k, 2) * gm;
    EXPECT_NEAR(res[2 * k] * res[2 * k] + res[2 * k + 1] * res[2 * k + 1], expected, 1e-9 * (1 + expected)) << k;
  }
}

TEST(FitCosts, ReprojectionRejectsPointsBehindTheCamera) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Params p(model, 4);
  p.transl[2] = -5.0;
  Observations3 obs = Observations3::Constant(3, 3, 1.0);
  KeypointReprojectionCost cost(&model, &reg, {900, 900, 480, 270}, obs, 1.0, 30.0, 0.05);
  std::vector<double> res(6);
  const double* params[4] = {p.transl.data(), p.root.data(), p.body.data(), p.betas.data()};
  EXPECT_FALSE(cost.Evaluate(params, res.data(), nullptr));
}

TEST(FitCosts, RelativePointsJacobiansAndTranslationInvariance) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Params p(model, 5);
  Observations4 obs(3, 4);
  obs << 0.1, -0.2, 0.05, 1.0, -0.3, 0.4, 0.2, 0.6, 0.5, 0.5, 0.5, 0.0;
  const double weight = 2.0, sigma = 0.1;
  RelativePointsCost cost(&model, &reg, obs, {0, 1}, weight, sigma);
  EXPECT_TRUE(CheckGradient(cost, {p.root.data(), p.body.data(), p.betas.data()}));

  // The value against the definition, with points from Keypoints<double> at an arbitrary translation.
  const auto x = PointsOf(model, reg, p);
  const Eigen::Vector3d model_ref = 0.5 * (x.row(0) + x.row(1)).transpose();
  const Eigen::Vector3d obs_ref = 0.5 * (obs.block<1, 3>(0, 0) + obs.block<1, 3>(1, 0)).transpose();
  std::vector<double> res(9);
  const double* params[3] = {p.root.data(), p.body.data(), p.betas.data()};
  ASSERT_TRUE(cost.Evaluate(params, res.data(), nullptr));
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d e = (x.row(k).transpose() - model_ref) - (obs.block<1, 3>(k, 0).transpose() - obs_ref);
    const double expected = weight * obs(k, 3) * obs(k, 3) * sigma * sigma * e.squaredNorm() /
                            (sigma * sigma + e.squaredNorm());
    const double got = res[3 * k] * res[3 * k] + res[3 * k + 1] * res[3 * k + 1] + res[3 * k + 2] * res[3 * k + 2];
    EXPECT_NEAR(got, expected, 1e-9 * (1 + expected)) << k;
  }
}

TEST(FitCosts, WeightedPrior) {
  Eigen::VectorXd mean(3), weights(3);
  mean << 1.0, -2.0, 0.5;
  weights << 4.0, 0.0, 9.0;
  WeightedPriorCost cost(mean, weights);
  const double x[3] = {2.0, 5.0, 0.0};
  const double* params[1] = {x};
  double res[3], jac[9];
  double* jacs[1] = {jac};
  ASSERT_TRUE(cost.Evaluate(params, res, jacs));
  EXPECT_DOUBLE_EQ(res[0], 2.0);
  EXPECT_DOUBLE_EQ(res[1], 0.0);
  EXPECT_DOUBLE_EQ(res[2], -1.5);
  EXPECT_DOUBLE_EQ(jac[0], 2.0);
  EXPECT_DOUBLE_EQ(jac[4], 0.0);
  EXPECT_DOUBLE_EQ(jac[8], 3.0);
  EXPECT_DOUBLE_EQ(jac[1], 0.0);
  EXPECT_THROW(WeightedPriorCost(mean, -weights), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::fit
