#include "motion/costs.h"

#include <memory>

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "../body/cost_checks.h"

namespace m3c::motion {
namespace {

using body::testing::CheckGradient;
using body::testing::MakeTestModel;
using body::testing::ThreePointRegressor;

using Frame = body::testing::RandomPoseBlocks;

TEST(Costs, ReprojectionJacobians) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame f(model, 1);
  FrameCamera cam;
  cam.cam_from_world_rotation = Eigen::AngleAxisd(0.2, Eigen::Vector3d(0.3, 1.0, 0.1).normalized()).toRotationMatrix();
  cam.centre_in_world = Eigen::Vector3d(0.5, -0.2, -6.0);
  cam.intrinsics = {900, 880, 480, 270};
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> obs(3, 3);
  // Residuals from ~0 to far beyond sigma, and one keypoint with no confidence.
  obs << 480, 270, 0.9, 700, 100, 0.5, 100, 900, 0.0;
  ReprojectionCost cost(&model, &reg, cam, obs, 0.7, 100.0, 0.05);
  double scale = 1.3, offset[3] = {0.1, 0.0, -0.2};
  EXPECT_TRUE(CheckGradient(cost, {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, offset}));

  // The squared residual equals weight * conf^2 * Geman-McClure of the pixel error.
  std::vector<double> res(6);
  const double* params[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, offset};
  ASSERT_TRUE(cost.Evaluate(params, res.data(), nullptr));
  EXPECT_EQ(res[4], 0.0);
  EXPECT_EQ(res[5], 0.0);
}

TEST(Costs, ReprojectionRejectsPointsBehindCamera) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame f(model, 2);
  FrameCamera cam{Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 10.0), 500, 500, 320, 240};
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> obs = Eigen::MatrixXd::Constant(3, 3, 1.0);
  ReprojectionCost cost(&model, &reg, cam, obs, 1.0, 100.0, 0.05);
  double scale = 1.0, offset[3] = {0, 0, 0};
  std::vector<double> res(6);
  const double* params[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, offset};
  EXPECT_FALSE(cost.Evaluate(params, res.data(), nullptr));
}

TEST(Costs, PointStencilJacobians) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame a(model, 3), b(model, 7), c(model, 21);
  PointStencilCost velocity(&model, &reg, {-1.0, 1.0}, {1.0, 4.0, 0.5});
  EXPECT_TRUE(CheckGradient(velocity, {a.transl.data(), a.root.data(), a.body.data(), b.transl.data(), b.root.data(),
                               b.body.data(), a.betas.data()}));
  PointStencilCost acceleration(&model, &reg, {1.0, -2.0, 1.0}, {2.0, 1.0, 3.0});
  EXPECT_TRUE(CheckGradient(acceleration, {a.transl.data(), a.root.data(), a.body.data(), b.transl.data(), b.root.data(),
                                   b.body.data(), c.transl.data(), c.root.data(), c.body.data(), a.betas.data()}));
}

// The robust form: cost weight * GM(|d|^2) per point, d the stencil's unweighted value; Jacobians checked.
TEST(Costs, RobustPointStencilValueAndJacobians) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame a(model, 3), b(model, 7);
  const std::vector<double> weights = {1.0, 4.0, 0.0};
  const double sigma = 0.05;
  PointStencilCost plain(&model, &reg, {-1.0, 1.0}, weights), robust(&model, &reg, {-1.0, 1.0}, weights, sigma);
  const std::vector<const double*> blocks = {a.transl.data(), a.root.data(), a.body.data(), b.transl.data(),
                                             b.root.data(),  b.body.data(),  a.betas.data()};
  EXPECT_TRUE(CheckGradient(robust, blocks));
  std::vector<double> r_plain(9), r_robust(9);
  ASSERT_TRUE(plain.Evaluate(blocks.data(), r_plain.data(), nullptr));
  ASSERT_TRUE(robust.Evaluate(blocks.data(), r_robust.data(), nullptr));
  for (int k = 0; k < 3; ++k) {
    const Eigen::Vector3d d = Eigen::Map<Eigen::Vector3d>(r_plain.data() + 3 * k) / std::max(std::sqrt(weights[k]), 1e-300);
    const double s = weights[k] > 0 ? d.squaredNorm() : 0.0;
    EXPECT_NEAR(Eigen::Map<Eigen::Vector3d>(r_robust.data() + 3 * k).squaredNorm(),
                weights[k] * sigma * sigma * s / (sigma * sigma + s), 1e-12);
  }
}

TEST(Costs, StencilOfAConstantVelocityPathIsZero) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame a(model, 3);
  std::vector<double> t1 = {a.transl[0] + 0.1, a.transl[1], a.transl[2]}, t2 = {a.transl[0] + 0.2, a.transl[1], a.transl[2]};
  PointStencilCost acceleration(&model, &reg, {1.0, -2.0, 1.0}, {1.0, 1.0, 1.0});
  const double* params[10] = {a.transl.data(), a.root.data(), a.body.data(), t1.data(), a.root.data(), a.body.data(),
                              t2.data(), a.root.data(), a.body.data(), a.betas.data()};
  double r[9];
  ASSERT_TRUE(acceleration.Evaluate(params, r, nullptr));
  for (double v : r) EXPECT_NEAR(v, 0.0, 1e-12);
}

FrameCamera TestCamera() {
  FrameCamera cam;
  cam.cam_from_world_rotation = Eigen::AngleAxisd(0.3, Eigen::Vector3d(1.0, 0.2, 0.1).normalized()).toRotationMatrix();
  cam.centre_in_world = Eigen::Vector3d(0.4, 1.5, -5.0);
  cam.intrinsics = {1000, 1000, 480, 270};
  return cam;
}

TEST(Costs, ContactHeightJacobiansAndDeadZone) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame f(model, 11);
  double scale = 1.4, offset[3] = {0.1, -0.2, 0.3};
  // A plane far below the points: all residuals active.
  ContactHeightCost cost(&model, &reg, {1.0, 2.0, 3.0}, TestCamera(), Eigen::Vector3d(0.1, -1.0, 0.05), 7.0, 0.08);
  EXPECT_TRUE(CheckGradient(cost, {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, offset}));
  // A world plane y = 0 seen from the camera: a point 5 cm above it is inside the tolerance (zero residual), and
  // the same plane moves with the scale (the camera centre's height scales).
  std::vector<double> pts(9), pose(3 * model.num_joints());
  std::copy(f.root.begin(), f.root.end(), pose.begin());
  std::copy(f.body.begin(), f.body.end(), pose.begin() + 3);
  body::KeypointsWithJacobian(model, reg, pose.data(), f.betas.data(), f.transl.data(), pts.data(), nullptr);
  FrameCamera cam = TestCamera();
  const Eigen::Vector3d up(0, 1, 0);
  const Eigen::Vector3d normal_in_cam = cam.cam_from_world_rotation * up;
  // World plane y = y0 - 0.05 below point 0, expressed in the camera at scale 1 and no offset.
  const double y0 = pts[1] - 0.05;
  const double offset_in_cam = up.dot(cam.centre_in_world) - y0;
  ContactHeightCost flat(&model, &reg, {1.0, 0.0, 0.0}, cam, normal_in_cam, offset_in_cam, 0.08);
  double r[3], unit_scale = 1.0, no_offset[3] = {0, 0, 0};
  const double* params[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &unit_scale, no_offset};
  ASSERT_TRUE(flat.Evaluate(params, r, nullptr));
  EXPECT_EQ(r[0], 0.0);
  double doubled = 2.0;  // the camera is twice as high: the plane drops by the camera height
  const double* params2[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &doubled, no_offset};
  ASSERT_TRUE(flat.Evaluate(params2, r, nullptr));
  EXPECT_NEAR(r[0], std::abs(0.05 - cam.centre_in_world.y()) - 0.08, 1e-9);
}

TEST(Costs, ContactHeightAboveRestHeightsAndBelowOnly) {
  // Each point's height is measured above its standing height h_k; below_only counts only the depth under it.
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  Frame f(model, 12);
  std::vector<double> pts(9), pose(3 * model.num_joints());
  std::copy(f.root.begin(), f.root.end(), pose.begin());
  std::copy(f.body.begin(), f.body.end(), pose.begin() + 3);
  body::KeypointsWithJacobian(model, reg, pose.data(), f.betas.data(), f.transl.data(), pts.data(), nullptr);
  const FrameCamera cam = TestCamera();
  const Eigen::Vector3d up(0, 1, 0);
  const Eigen::Vector3d normal_in_cam = cam.cam_from_world_rotation * up;
  // The world plane y = y0, 4 cm under point 0: offset in the camera at scale 1, no offset.
  const double y0 = pts[1] - 0.04, offset_in_cam = up.dot(cam.centre_in_world) - y0;
  const std::vector<double> weights = {4.0, 1.0, 9.0};
  const Eigen::Vector3d heights(0.07, pts[4] - y0 - 0.05, pts[7] - y0 + 0.03);
  double scale = 1.0, no_offset[3] = {0, 0, 0}, r[3];
  const double* params[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, no_offset};
  for (const bool below_only : {false, true}) {
    ContactHeightCost cost(&model, &reg, weights, cam, normal_in_cam, offset_in_cam, 0.01, heights, below_only);
    ASSERT_TRUE(cost.Evaluate(params, r, nullptr));
    for (int k = 0; k < 3; ++k) {
      const double h = pts[3 * k + 1] - y0 - heights[k];  // height above the standing height
      const double excess = (below_only ? -h : std::abs(h)) - 0.01;
      EXPECT_NEAR(r[k], excess > 0 ? std::sqrt(weights[k]) * excess : 0.0, 1e-9) << k << below_only;
    }
    // Point 0 stands 3 cm under its standing height (4 cm up, 7 expected): counted either way. Point 2 stands
    // 3 cm under its own: counted either way too; point 1 stands 5 cm above its own: only both-sided.
    EXPECT_NEAR(r[0], 2.0 * 0.02, 1e-9);
    EXPECT_NEAR(r[2], 3.0 * 0.02, 1e-9);
    EXPECT_NEAR(r[1], below_only ? 0.0 : 0.04, 1e-9);
    // Jacobians against numeric differentiation, scale and offset included, on a tilted plane far above and far
    // below the points (all residuals active on one side at least).
    double scale2 = 1.3, offset2[3] = {0.02, -0.03, 0.01};
    const double* params2[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale2, offset2};
    int active = 0;
    for (const double plane_offset : {7.0, -7.0}) {
      ContactHeightCost far(&model, &reg, weights, cam, Eigen::Vector3d(0.1, -1.0, 0.05), plane_offset, 0.01, heights,
                            below_only);
      EXPECT_TRUE(CheckGradient(far, {params2[0], params2[1], params2[2], params2[3], params2[4], params2[5]}));
      ASSERT_TRUE(far.Evaluate(params2, r, nullptr));
      active += (r[0] > 0) + (r[1] > 0) + (r[2] > 0);
    }
    EXPECT_EQ(active, below_only ? 3 : 6);
  }
}

TEST(Costs, UprightJacobiansAndValue) {
  const body::BodyModel model = MakeTestModel();
  Frame f(model, 5);
  const double weight = 2.5, sigma = 0.2;
  const Eigen::Vector3d up(0.2, 1.0, -0.1);
  UprightCost cost(&model, 0, 12, up, weight, sigma);
  EXPECT_TRUE(CheckGradient(cost, {f.transl.data(), f.root.data(), f.body.data(), f.betas.data()}));
  // The value against the joints computed directly: |r|^2 = weight GM(|h|^2), h the spine across up.
  const body::KeypointRegressor joints = body::IdentityJointRegressor(model);
  std::vector<double> pts(3 * model.num_joints()), pose(3 * model.num_joints());
  std::copy(f.root.begin(), f.root.end(), pose.begin());
  std::copy(f.body.begin(), f.body.end(), pose.begin() + 3);
  body::KeypointsWithJacobian(model, joints, pose.data(), f.betas.data(), f.transl.data(), pts.data(), nullptr);
  const Eigen::Vector3d spine = Eigen::Map<Eigen::Vector3d>(pts.data() + 36) - Eigen::Map<Eigen::Vector3d>(pts.data());
  const Eigen::Vector3d u = up.normalized(), across = spine - spine.dot(u) * u;
  const double s = across.squaredNorm();
  ASSERT_GT(s, 1e-4);  // the test pose leans
  double r[2];
  const double* params[4] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data()};
  ASSERT_TRUE(cost.Evaluate(params, r, nullptr));
  EXPECT_NEAR(r[0] * r[0] + r[1] * r[1], weight * sigma * sigma * s / (sigma * sigma + s), 1e-12);
  // Up along the spine: no lean, no cost; the translation does not move the spine.
  UprightCost along(&model, 0, 12, spine, weight, sigma);
  ASSERT_TRUE(along.Evaluate(params, r, nullptr));
  EXPECT_NEAR(r[0], 0.0, 1e-12);
  EXPECT_NEAR(r[1], 0.0, 1e-12);
  std::vector<double> moved = {f.transl[0] + 3.0, f.transl[1] - 1.0, f.transl[2] + 0.5};
  const double* params_moved[4] = {moved.data(), f.root.data(), f.body.data(), f.betas.data()};
  double r_moved[2];
  ASSERT_TRUE(cost.Evaluate(params_moved, r_moved, nullptr));
  ASSERT_TRUE(cost.Evaluate(params, r, nullptr));
  EXPECT_NEAR(r_moved[0], r[0], 1e-12);
  EXPECT_NEAR(r_moved[1], r[1], 1e-12);
}

TEST(Costs, PriorsJacobians) {
  GaussianPriorCost prior(Eigen::VectorXd::LinSpaced(4, -1, 1), 0.3);
  std::vector<double> x = {0.1, 0.2, -0.3, 2.0}, y = {1.0, -2.0, 0.5, 0.0};
  EXPECT_TRUE(CheckGradient(prior, {x.data()}));
  BlockDifferenceCost diff(4, 2.5);
  EXPECT_TRUE(CheckGradient(diff, {x.data(), y.data()}));
  // A step held to a target: sqrt(weight) (y - x - target).
  const Eigen::Vector4d target(0.5, -1.0, 0.25, 3.0);
  BlockDifferenceCost held(4, 2.5, target);
  EXPECT_TRUE(CheckGradient(held, {x.data(), y.data()}));
  const double* params[] = {x.data(), y.data()};
  double r[4];
  ASSERT_TRUE(held.Evaluate(params, r, nullptr));
  for (int i = 0; i < 4; ++i) EXPECT_NEAR(r[i], std::sqrt(2.5) * (y[i] - x[i] - target[i]), 1e-14);
  EXPECT_THROW(BlockDifferenceCost(4, 1.0, Eigen::Vector3d::Zero()), std::invalid_argument);
}

TEST(Costs, LogPriorValueJacobianAndDomain) {
  const double mean = 1.7, sigma = 0.05, weight = 4.0;
  LogPriorCost prior(std::log(mean), sigma, weight);
  double scale = 1.9;
  EXPECT_TRUE(CheckGradient(prior, {&scale}));
  const double* params[] = {&scale};
  double residual = 0.0;
  ASSERT_TRUE(prior.Evaluate(params, &residual, nullptr));
  EXPECT_NEAR(residual, 2.0 * std::log(1.9 / 1.7) / 0.05, 1e-12);  // sqrt(weight) log(x / mean) / sigma
  scale = -0.5;  // no log-normal density at a negative scale: the step is rejected, not NaN
  EXPECT_FALSE(prior.Evaluate(params, &residual, nullptr));
}

TEST(Costs, RayAccelerationValueJacobianAndNothingAcrossTheRay) {
  const Eigen::Vector3d ray = Eigen::Vector3d(0.3, -0.2, 0.9).normalized();
  const std::vector<double> stencil = {0.9, -2.1, 1.2};  // uneven frame steps: still summing to zero
  const double weight = 40.0;
  RayAccelerationCost cost(stencil, ray, weight);
  std::vector<double> a = {0.1, 1.0, 5.0}, b = {0.25, 0.95, 5.3}, c = {0.3, 1.1, 5.2};
  EXPECT_TRUE(CheckGradient(cost, {a.data(), b.data(), c.data()}));
  const double* params[] = {a.data(), b.data(), c.data()};
  double residual = 0.0;
  ASSERT_TRUE(cost.Evaluate(params, &residual, nullptr));
  Eigen::Vector3d acc = Eigen::Vector3d::Zero();
  for (int k = 0; k < 3; ++k) acc += stencil[k] * Eigen::Map<const Eigen::Vector3d>(params[k]);
  EXPECT_NEAR(residual, std::sqrt(weight) * ray.dot(acc), 1e-12);
  // Moving the middle frame across the line of sight costs nothing; along it, it does.
  const Eigen::Vector3d across = ray.cross(Eigen::Vector3d::UnitY()).normalized();
  std::vector<double> moved = b;
  Eigen::Map<Eigen::Vector3d>(moved.data()) += 0.5 * across;
  const double* moved_params[] = {a.data(), moved.data(), c.data()};
  double moved_residual = 0.0;
  ASSERT_TRUE(cost.Evaluate(moved_params, &moved_residual, nullptr));
  EXPECT_NEAR(moved_residual, residual, 1e-12);
  Eigen::Map<Eigen::Vector3d>(moved.data()) += 0.5 * ray;
  ASSERT_TRUE(cost.Evaluate(moved_params, &moved_residual, nullptr));
  EXPECT_NEAR(moved_residual - residual, std::sqrt(weight) * stencil[1] * 0.5, 1e-12);
}

TEST(Costs, HeadingAnchorMeasuresTheTurnAboutUpOnly) {
  const Eigen::Vector3d up = Eigen::Vector3d(0.1, -1.0, 0.2).normalized();
  const Eigen::Vector3d reference(0.4, 2.1, -0.3);  // a root orientation (axis-angle), facing well off up
  const double weight = 4.0;
  std::unique_ptr<ceres::CostFunction> cost(HeadingAnchorCost::Create(up, reference, weight));
  ASSERT_NE(cost, nullptr);
  const Eigen::Matrix3d r0 = Eigen::AngleAxisd(reference.norm(), reference.normalized()).toRotationMatrix();
  auto residual_at = [&](const Eigen::Matrix3d& rotation) {
    const Eigen::AngleAxisd aa(rotation);
    Eigen::Vector3d root = aa.angle() * aa.axis();
    const double* params[] = {root.data()};
    double r = 0.0;
    EXPECT_TRUE(cost->Evaluate(params, &r, nullptr));
    // Away from the turn of pi, where the residual wraps to -pi and finite differences straddle the jump.
    if (std::abs(r) < 2.5 * std::sqrt(weight)) EXPECT_TRUE(CheckGradient(*cost, {root.data()}));
    return r;
  };
  EXPECT_NEAR(residual_at(r0), 0.0, 1e-12);
  // Turned about up by alpha: the residual is sqrt(weight) alpha, with its sign, up to +-pi.
  for (double alpha : {-2.9, -0.6, 0.05, 1.3, 3.0}) {
    EXPECT_NEAR(residual_at(Eigen::AngleAxisd(alpha, up) * r0), std::sqrt(weight) * alpha, 1e-9) << alpha;
  }
  // Leaning (about the horizontal axis across the facing direction) or rolling about the facing direction
  // itself leaves the heading: no residual.
  const Eigen::Vector3d facing = r0 * Eigen::Vector3d::UnitZ();
  const Eigen::Vector3d level = (facing - up.dot(facing) * up).normalized();
  for (double beta : {-0.4, 0.3}) {
    EXPECT_NEAR(residual_at(Eigen::AngleAxisd(beta, up.cross(level)) * r0), 0.0, 1e-9) << beta;
    EXPECT_NEAR(residual_at(Eigen::AngleAxisd(beta, facing) * r0), 0.0, 1e-9) << beta;
  }
  // A reference facing along up (a person lying face up) has no heading: no cost.
  const Eigen::Vector3d lying = Eigen::Vector3d::UnitZ().cross(up).normalized() *
                                std::acos(Eigen::Vector3d::UnitZ().dot(up));
  EXPECT_EQ(HeadingAnchorCost::Create(up, lying, weight), nullptr);
}

}  // namespace
}  // namespace m3c::motion
