#include "ground/plane_fit.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <Eigen/SVD>
#include <cmath>
#include <random>
#include <stdexcept>

namespace m3c::ground {
namespace {

constexpr double kDeg = M_PI / 180.0;

// `n` points on the plane {normal . x + offset = 0}: a `size` x `size` patch around the point of the plane nearest
// to (0.3, 1.2, 2.5), with Gaussian noise along the normal, then `outliers` points 5..40 cm above the plane (like
// false contacts on shins and hands, they all sit on one side and would bias a plain fit).
Points3 NoisyPlane(const Eigen::Vector3d& normal, double offset, int n, double size, double noise, int outliers,
                   unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> along(-size / 2, size / 2), off(0.05, 0.40);
  std::normal_distribution<double> gauss(0.0, noise);
  const Eigen::Vector3d u = normal.unitOrthogonal(), v = normal.cross(u);
  const Eigen::Vector3d q(0.3, 1.2, 2.5), centre = q - (normal.dot(q) + offset) * normal;
  Points3 x(n + outliers, 3);
  for (int i = 0; i < n + outliers; ++i) {
    const double h = i < n ? gauss(rng) : off(rng);
    x.row(i) = (centre + along(rng) * u + along(rng) * v + h * normal).transpose();
  }
  return x;
}

double AngleBetween(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

TEST(PlaneFit, TotalLeastSquaresMatchesSvdOfCentredPoints) {
  const Eigen::Vector3d normal = Eigen::Vector3d(0.1, -1.0, 0.2).normalized();
  const Points3 x = NoisyPlane(normal, 1.4, 300, 1.0, 0.02, 0, 1);
  PlaneFitOptions options;
  options.robust = false;
  const PlaneFit fit = FitPlane(x, Eigen::Vector3d(0, -1, 0), options);
  ASSERT_TRUE(fit.ok());
  // Independent route: the right singular vector of the centred N x 3 matrix with the smallest singular value.
  const Eigen::RowVector3d centroid = x.colwise().mean();
  const Eigen::MatrixXd centred = x.rowwise() - centroid;
  Eigen::JacobiSVD<Eigen::MatrixXd> svd(centred, Eigen::ComputeThinV);
  Eigen::Vector3d ref = svd.matrixV().col(2);
  if (ref.dot(Eigen::Vector3d(0, -1, 0)) < 0) ref = -ref;
  EXPECT_LT((fit.plane.normal - ref).norm(), 1e-10);
  EXPECT_NEAR(fit.plane.offset, -ref.dot(centroid.transpose()), 1e-10);
  EXPECT_EQ(fit.num_inliers, 300);
  EXPECT_NEAR(fit.rms, svd.singularValues()(2) / std::sqrt(300.0), 1e-10);
}

TEST(PlaneFit, RobustRecoversPlaneWithinOneCentimetreAndHalfDegree) {
  for (unsigned seed = 0; seed < 5; ++seed) {
    const Eigen::Vector3d normal = Eigen::Vector3d(0.2 * seed - 0.4, -1.0, 0.3).normalized();
    const double offset = 1.2 + 0.1 * seed;
    const Points3 x = NoisyPlane(normal, offset, 400, 1.2, 0.005, 120, seed);  // 23% outliers
    const PlaneFit fit = FitPlane(x, Eigen::Vector3d(0, -1, 0));
    ASSERT_TRUE(fit.ok()) << seed;
    EXPECT_LT(AngleBetween(fit.plane.normal, normal), 0.5 * kDeg) << seed;
    EXPECT_LT(std::abs(fit.plane.offset - offset), 0.01) << seed;
    EXPECT_GE(fit.num_inliers, 380);
    EXPECT_LE(fit.num_inliers, 430);
    // Plain least squares is pulled off by the same outliers: the robust option is what makes the difference.
    PlaneFitOptions plain;
    plain.robust = false;
    const PlaneFit naive = FitPlane(x, Eigen::Vector3d(0, -1, 0), plain);
    const Eigen::Vector3d q(0.3, 1.2, 2.5), centre = q - (normal.dot(q) + offset) * normal;
    EXPECT_GT(std::abs(naive.plane.SignedDistance(centre)), 0.02) << seed;
  }
}

TEST(PlaneFit, NormalPointsUp) {
  const Points3 x = NoisyPlane(Eigen::Vector3d(0, 1, 0), -1.5, 100, 1.0, 0.001, 0, 3);
  const PlaneFit down = FitPlane(x, Eigen::Vector3d(0, -1, 0));  // OpenCV camera frame: up is -y
  ASSERT_TRUE(down.ok());
  EXPECT_LT(down.plane.normal.y(), -0.999);
  EXPECT_NEAR(down.plane.offset, 1.5, 0.002);  // camera 1.5 m above the floor
  const PlaneFit up = FitPlane(x, Eigen::Vector3d(0, 2, 0));
  EXPECT_GT(up.plane.normal.y(), 0.999);
  EXPECT_NEAR(up.plane.offset, -1.5, 0.002);
}

TEST(PlaneFit, SupportRule) {
  const Eigen::Vector3d normal(0, -1, 0), up(0, -1, 0);
  PlaneFitOptions options;
  options.min_support = 50;
  EXPECT_EQ(FitPlane(NoisyPlane(normal, 1.0, 49, 1.0, 0.001, 0, 0), up, options).status,
            PlaneFitStatus::kTooFewPoints);
  EXPECT_TRUE(FitPlane(NoisyPlane(normal, 1.0, 50, 1.0, 0.001, 0, 0), up, options).ok());
  // 30 plane points and 40 scattered ones: the best plane has too few inliers.
  const PlaneFit sparse = FitPlane(NoisyPlane(normal, 1.0, 30, 1.0, 0.001, 40, 0), up, options);
  EXPECT_EQ(sparse.status, PlaneFitStatus::kTooFewInliers);
  EXPECT_NE(DescribeFailure(sparse, 70, options).find("min_support = 50"), std::string::npos);
  Points3 line(30, 3);
  for (int i = 0; i < 30; ++i) line.row(i) = Eigen::RowVector3d(0.1 * i, 1.0, 2.0 + 0.05 * i);
  options.min_support = 3;
  EXPECT_EQ(FitPlane(line, up, options).status, PlaneFitStatus::kDegenerate);
  options.robust = false;
  EXPECT_EQ(FitPlane(line, up, options).status, PlaneFitStatus::kDegenerate);
}

TEST(PlaneFit, DeterministicForASeed) {
  const Points3 x = NoisyPlane(Eigen::Vector3d(0, -1, 0), 1.0, 200, 1.0, 0.01, 100, 4);
  const PlaneFit a = FitPlane(x, Eigen::Vector3d(0, -1, 0)), b = FitPlane(x, Eigen::Vector3d(0, -1, 0));
  EXPECT_EQ(a.plane.normal, b.plane.normal);
  EXPECT_EQ(a.plane.offset, b.plane.offset);
  EXPECT_EQ(a.inliers, b.inliers);
}

TEST(PlaneFit, RejectsBadInput) {
  Points3 x = NoisyPlane(Eigen::Vector3d(0, -1, 0), 1.0, 50, 1.0, 0.01, 0, 5);
  EXPECT_THROW(FitPlane(x, Eigen::Vector3d::Zero()), std::invalid_argument);
  PlaneFitOptions options;
  options.inlier_threshold = 0.0;
  EXPECT_THROW(FitPlane(x, Eigen::Vector3d(0, -1, 0), options), std::invalid_argument);
  options = {};
  options.min_support = 2;
  EXPECT_THROW(FitPlane(x, Eigen::Vector3d(0, -1, 0), options), std::invalid_argument);
  x(3, 2) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(FitPlane(x, Eigen::Vector3d(0, -1, 0)), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::ground
