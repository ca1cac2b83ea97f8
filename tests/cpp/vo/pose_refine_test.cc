#include "vo/pose_refine.h"

#include <gtest/gtest.h>

#include <random>

namespace m3c::vo {
namespace {

const Intrinsics kK{300.0, 300.0, 160.0, 120.0};

void MakeObservations(const Rigid3& cam_from_world, bool at_infinity, unsigned seed, std::vector<Eigen::Vector4d>* pts,
                      std::vector<Eigen::Vector2d>* uvs) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0), z(2.0, 8.0);
  while (pts->size() < 60) {
    Eigen::Vector4d x(2.0 * u(rng), 1.5 * u(rng), z(rng), 1.0);
    if (at_infinity) x.w() = 0.0;
    const Eigen::Vector3d y = cam_from_world.rotation * x.head<3>() + x.w() * cam_from_world.translation;
    if (y.z() <= 0.1) continue;
    pts->push_back(x);
    uvs->push_back(kK.Project(y));
  }
}

TEST(RefinePose, RecoversSixDofPose) {
  const Rigid3 truth(ExpSO3(Eigen::Vector3d(0.05, -0.1, 0.02)), Eigen::Vector3d(0.3, -0.1, 0.2));
  std::vector<Eigen::Vector4d> pts;
  std::vector<Eigen::Vector2d> uvs;
  MakeObservations(truth, false, 1, &pts, &uvs);
  // A few gross outliers the Cauchy weights must ignore.
  for (int i = 0; i < 6; ++i) uvs[i * 7] += Eigen::Vector2d(30.0, -25.0);
  Eigen::Matrix<double, 6, 1> offset;
  offset << 0.1, -0.05, 0.08, 0.03, 0.02, -0.04;
  const Rigid3 init = LeftPlus(truth, offset);
  PoseRefineOptions o;
  o.max_iterations = 30;
  const PoseRefineResult r = RefinePose(kK, pts, uvs, init, o);
  EXPECT_TRUE(r.improved);
  EXPECT_LT(LeftMinus(r.cam_from_world, truth).norm(), 1e-3);
}

TEST(RefinePose, RotationOnlyKeepsTranslation) {
  const Rigid3 truth(ExpSO3(Eigen::Vector3d(0.01, 0.03, -0.02)), Eigen::Vector3d::Zero());
  std::vector<Eigen::Vector4d> pts;
  std::vector<Eigen::Vector2d> uvs;
  MakeObservations(truth, true, 2, &pts, &uvs);
  const Rigid3 init(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.5, 0.0, 0.0));
  PoseRefineOptions o;
  o.rotation_only = true;
  const PoseRefineResult r = RefinePose(kK, pts, uvs, init, o);
  EXPECT_TRUE(r.improved);
  EXPECT_LT(LogSO3(r.cam_from_world.rotation * truth.rotation.conjugate()).norm(), 1e-8);
  EXPECT_LT((r.cam_from_world.translation - init.translation).norm(), 1e-12);
  EXPECT_LT(r.rms_px, 1e-6);
}

TEST(RefinePose, RejectsMismatchedInput) {
  std::vector<Eigen::Vector4d> pts(3, Eigen::Vector4d(0, 0, 1, 1));
  std::vector<Eigen::Vector2d> uvs(2);
  EXPECT_THROW(RefinePose(kK, pts, uvs, Rigid3(), {}), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::vo
