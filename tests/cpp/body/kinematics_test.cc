#include "body/kinematics.h"

#include <ceres/ceres.h>
#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include "body/lbs.h"
#include "body/posing.h"
#include "test_model.h"

namespace m3c::body {
namespace {

using testing::MakeTestModel;
using testing::RandomVector;

// A regressor mixing vertex picks, a dense-ish vertex average and joint picks.
KeypointRegressor MakeRegressor(const BodyModel& model) {
  const int V = model.num_vertices(), J = model.num_joints();
  Eigen::SparseMatrix<double, Eigen::RowMajor> vw(5, V), jw(5, J);
  std::vector<Eigen::Triplet<double>> tv = {{0, 3, 1.0}, {1, V - 1, 1.0}, {2, 17, 0.25}, {2, 40, 0.25},
                                            {2, 41, 0.5}, {4, 100, 0.3}};
  std::vector<Eigen::Triplet<double>> tj = {{3, 20, 1.0}, {4, 7, 0.7}};
  vw.setFromTriplets(tv.begin(), tv.end());
  jw.setFromTriplets(tj.begin(), tj.end());
  return KeypointRegressor(vw, jw);
}

// Autodiff twin of KeypointsWithJacobian built on the templated posing code.
struct KeypointFunctor {
  const BodyModel* model;
  const KeypointRegressor* regressor;
  template <typename T>
  bool operator()(T const* const* params, T* residuals) const {
    PoseKeypoints(*model, *regressor, params[1], params[2], params[0], residuals);
    return true;
  }
};

void CompareWithAutodiff(const std::vector<double>& pose_in) {
  const BodyModel model = MakeTestModel();
  const KeypointRegressor reg = MakeRegressor(model);
  const int J = model.num_joints(), B = model.num_betas(), K = reg.num_keypoints();
  const int D = NumJacobianColumns(model);
  std::vector<double> pose = pose_in, betas = RandomVector(B, 1.0, 12), transl = {0.3, -0.2, 4.0};
  std::vector<double> kp(3 * K), jac(3 * K * D);
  KeypointsWithJacobian(model, reg, pose.data(), betas.data(), transl.data(), kp.data(), jac.data());

  ceres::DynamicAutoDiffCostFunction<KeypointFunctor, 8> cost(new KeypointFunctor{&model, &reg});
  cost.AddParameterBlock(3);
  cost.AddParameterBlock(3 * J);
  cost.AddParameterBlock(B);
  cost.SetNumResiduals(3 * K);
  const double* params[3] = {transl.data(), pose.data(), betas.data()};
  std::vector<double> residuals(3 * K), jt(3 * K * 3), jp(3 * K * 3 * J), jb(3 * K * B);
  double* jacs[3] = {jt.data(), jp.data(), jb.data()};
  ASSERT_TRUE(cost.Evaluate(params, residuals.data(), jacs));
  for (int r = 0; r < 3 * K; ++r) {
    EXPECT_NEAR(kp[r], residuals[r], 1e-12);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(jac[r * D + c], jt[r * 3 + c], 1e-9) << "transl r" << r;
    for (int c = 0; c < 3 * J; ++c) EXPECT_NEAR(jac[r * D + 3 + c], jp[r * 3 * J + c], 1e-9) << "pose r" << r << " c" << c;
    for (int c = 0; c < B; ++c) EXPECT_NEAR(jac[r * D + 3 + 3 * J + c], jb[r * B + c], 1e-9) << "betas r" << r;
  }
}

TEST(Jacobian, KeypointsMatchAutodiff) { CompareWithAutodiff(RandomVector(72, 0.6, 11)); }

// Without the body or betas columns (a cost whose stage holds those blocks): the columns kept equal the full
// Jacobian's to the bit (the same operations), the others are zero, and the keypoints are the same.
TEST(Jacobian, KeypointsWithoutBodyOrBetasColumns) {
  const BodyModel model = MakeTestModel();
  const KeypointRegressor reg = MakeRegressor(model);
  const int J = model.num_joints(), B = model.num_betas(), K = reg.num_keypoints();
  const int D = NumJacobianColumns(model);
  std::vector<double> pose = RandomVector(3 * J, 0.6, 21), betas = RandomVector(B, 1.0, 22), transl = {0.3, -0.2, 4.0};
  std::vector<double> kp(3 * K), full(3 * K * D);
  KeypointsWithJacobian(model, reg, pose.data(), betas.data(), transl.data(), kp.data(), full.data());
  for (const bool body : {true, false}) {
    for (const bool with_betas : {true, false}) {
      std::vector<double> kp2(3 * K), part(3 * K * D, 7.0);  // 7: the skipped columns must be written as zero
      KeypointsWithJacobian(model, reg, pose.data(), betas.data(), transl.data(), kp2.data(), part.data(), body,
                            with_betas);
      EXPECT_EQ(kp, kp2);
      for (int r = 0; r < 3 * K; ++r) {
        for (int c = 0; c < D; ++c) {
          const bool kept = c < 6 || (c < 3 + 3 * J ? body : with_betas);
          EXPECT_EQ(part[r * D + c], kept ? full[r * D + c] : 0.0) << "row " << r << " column " << c << " body "
                                                                     << body << " betas " << with_betas;
        }
      }
    }
  }
}

TEST(Jacobian, KeypointsMatchAutodiffAtRestPose) { CompareWithAutodiff(std::vector<double>(72, 0.0)); }

TEST(Jacobian, KeypointsMatchAutodiffNearSmallAngleBranch) { CompareWithAutodiff(RandomVector(72, 3e-5, 13)); }

TEST(Jacobian, JointsMatchCentralDifferences) {
  const BodyModel model = MakeTestModel();
  const int J = model.num_joints(), B = model.num_betas(), D = NumJacobianColumns(model);
  std::vector<double> x(D);
  auto pose = RandomVector(3 * J, 0.6, 14), betas = RandomVector(B, 1.0, 15);
  x[0] = 0.1, x[1] = 0.2, x[2] = 3.0;
  std::copy(pose.begin(), pose.end(), x.begin() + 3);
  std::copy(betas.begin(), betas.end(), x.begin() + 3 + 3 * J);
  std::vector<double> joints(3 * J), jac(3 * J * D), plus(3 * J), minus(3 * J), dummy(3 * J * D);
  JointsWithJacobian(model, x.data() + 3, x.data() + 3 + 3 * J, x.data(), joints.data(), jac.data());
  const double h = 1e-6;
  double worst = 0.0;
  for (int c = 0; c < D; ++c) {
    std::vector<double> xp = x, xm = x;
    xp[c] += h;
    xm[c] -= h;
    JointsWithJacobian(model, xp.data() + 3, xp.data() + 3 + 3 * J, xp.data(), plus.data(), nullptr);
    JointsWithJacobian(model, xm.data() + 3, xm.data() + 3 + 3 * J, xm.data(), minus.data(), nullptr);
    for (int r = 0; r < 3 * J; ++r) worst = std::max(worst, std::abs((plus[r] - minus[r]) / (2 * h) - jac[r * D + c]));
  }
  EXPECT_LT(worst, 1e-7);
}

// An analytic Ceres cost (3D keypoint fit) checked by ceres::GradientChecker.
class KeypointFitCost : public ceres::CostFunction {
 public:
  KeypointFitCost(const BodyModel* model, const KeypointRegressor* reg, std::vector<double> target)
      : model_(model), reg_(reg), target_(std::move(target)) {
    set_num_residuals(3 * reg->num_keypoints());
    mutable_parameter_block_sizes()->assign({3, 3 * model->num_joints(), model->num_betas()});
  }
  bool Evaluate(double const* const* params, double* residuals, double** jacobians) const override {
    const int R = num_residuals(), J = model_->num_joints(), B = model_->num_betas(), D = NumJacobianColumns(*model_);
    std::vector<double> jac(jacobians ? R * D : 0);
    KeypointsWithJacobian(*model_, *reg_, params[1], params[2], params[0], residuals, jacobians ? jac.data() : nullptr);
    for (int r = 0; r < R; ++r) residuals[r] -= target_[r];
    if (!jacobians) return true;
    const int offsets[3] = {0, 3, 3 + 3 * J}, sizes[3] = {3, 3 * J, B};
    for (int b = 0; b < 3; ++b) {
      if (!jacobians[b]) continue;
      for (int r = 0; r < R; ++r)
        for (int c = 0; c < sizes[b]; ++c) jacobians[b][r * sizes[b] + c] = jac[r * D + offsets[b] + c];
    }
    return true;
  }

 private:
  const BodyModel* model_;
  const KeypointRegressor* reg_;
  std::vector<double> target_;
};

TEST(Jacobian, GradientCheckerAcceptsAnalyticCost) {
  const BodyModel model = MakeTestModel();
  const KeypointRegressor reg = MakeRegressor(model);
  KeypointFitCost cost(&model, &reg, RandomVector(3 * reg.num_keypoints(), 1.0, 16));
  auto pose = RandomVector(72, 0.5, 17), betas = RandomVector(model.num_betas(), 1.0, 18);
  std::vector<double> transl = {0.0, 0.0, 2.0};
  const double* params[3] = {transl.data(), pose.data(), betas.data()};
  ceres::NumericDiffOptions options;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(&cost, no_manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  EXPECT_TRUE(checker.Probe(params, 1e-7, &results)) << results.error_log;
}

TEST(Keypoints, EqualRegressorAppliedToSkinnedMesh) {
  const BodyModel model = MakeTestModel();
  const KeypointRegressor reg = MakeRegressor(model);
  const int N = 3, J = model.num_joints(), V = model.num_vertices(), B = model.num_betas(), K = reg.num_keypoints();
  auto pose = RandomVector(N * 3 * J, 0.6, 19), betas = RandomVector(B, 1.0, 20), transl = RandomVector(3 * N, 1.0, 21);
  std::vector<double> verts(N * 3 * V), joints(N * 3 * J), kp(N * 3 * K);
  Forward<double>(model, N, pose.data(), betas.data(), true, transl.data(), verts.data(), joints.data());
  Keypoints<double>(model, reg, N, pose.data(), betas.data(), true, transl.data(), kp.data());
  for (int f = 0; f < N; ++f) {
    Eigen::Map<const RowMatrixXd> vf(&verts[f * 3 * V], V, 3), jf(&joints[f * 3 * J], J, 3);
    RowMatrixXd expected = reg.vertex_weights() * vf + reg.joint_weights() * jf;
    // Translation enters once per unit of regressor weight; the test regressor's rows sum to 1 except row 4.
    Eigen::Map<const RowMatrixXd> got(&kp[f * 3 * K], K, 3);
    EXPECT_LT((got - expected).cwiseAbs().maxCoeff(), 1e-10);
  }
}

}  // namespace
}  // namespace m3c::body
