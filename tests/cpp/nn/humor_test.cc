#include "nn/humor.h"

#include <gtest/gtest.h>

#include <cmath>

#include <Eigen/Geometry>

#include <ceres/jet.h>

#include "body/rotation.h"
#include "jet_gradient.h"
#include "test_files.h"

namespace m3c::nn {
namespace {

using humor::kStateDim;
using testing::JetGradient;
using testing::MaxRelativeError;
using testing::RandomHumorState;
using testing::RandomVector;
using testing::TempFile;

class HumorPriorTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    file_ = new TempFile("humor.safetensors");
    testing::WriteRandomHumor(file_->path(), 32, 4, 3);
    prior_ = new HumorPrior(HumorPrior::FromFile(file_->path()));
  }
  static void TearDownTestSuite() {
    delete prior_;
    delete file_;
  }
  static TempFile* file_;
  static HumorPrior* prior_;
};
TempFile* HumorPriorTest::file_ = nullptr;
HumorPrior* HumorPriorTest::prior_ = nullptr;

TEST_F(HumorPriorTest, BatchedValuesMatchTemplate) {
  const int n = 3;
  std::vector<double> prev, next;
  for (int i = 0; i < n; ++i) {
    auto a = RandomHumorState(10 + i), b = RandomHumorState(20 + i);
    prev.insert(prev.end(), a.begin(), a.end());
    next.insert(next.end(), b.begin(), b.end());
  }
  std::vector<double> values(n), latent_values(n);
  prior_->TransitionNll(n, prev.data(), next.data(), values.data(), nullptr, nullptr);
  const std::vector<double> z = RandomVector(48 * n, 1.0, 5);
  prior_->LatentNll(n, prev.data(), z.data(), latent_values.data(), nullptr, nullptr);
  for (int i = 0; i < n; ++i) {
    const double single = prior_->TransitionNll(&prev[kStateDim * i], &next[kStateDim * i]);
    EXPECT_NEAR(values[i], single, 1e-12 * std::abs(single));
    const double latent = prior_->LatentNll(&prev[kStateDim * i], &z[48 * i]);
    EXPECT_NEAR(latent_values[i], latent, 1e-12 * std::abs(latent));
  }
}

TEST_F(HumorPriorTest, TransitionGradientMatchesJets) {
  const auto prev = RandomHumorState(31), next = RandomHumorState(32);
  std::vector<double> grad_prev(kStateDim), grad_next(kStateDim);
  double value;
  prior_->TransitionNll(1, prev.data(), next.data(), &value, grad_prev.data(), grad_next.data());
  std::vector<double> both(prev);
  both.insert(both.end(), next.begin(), next.end());
  const std::vector<double> expected = JetGradient<32>(both, [&](const auto& x) {
    return prior_->TransitionNll(x.data(), x.data() + kStateDim);
  });
  std::vector<double> got(grad_prev);
  got.insert(got.end(), grad_next.begin(), grad_next.end());
  EXPECT_LT(MaxRelativeError(got, expected), 1e-10);
  // The frame's source moves the canonical frame: its heading entries get a gradient.
  EXPECT_NE(grad_prev[humor::kRootOrient], 0.0);
}

TEST_F(HumorPriorTest, LatentGradientMatchesJets) {
  const auto prev = RandomHumorState(41);
  const std::vector<double> z = RandomVector(48, 1.0, 42);
  std::vector<double> grad_prev(kStateDim), grad_z(48);
  double value;
  prior_->LatentNll(1, prev.data(), z.data(), &value, grad_prev.data(), grad_z.data());
  std::vector<double> both(prev);
  both.insert(both.end(), z.begin(), z.end());
  const std::vector<double> expected =
      JetGradient<32>(both, [&](const auto& x) { return prior_->LatentNll(x.data(), x.data() + kStateDim); });
  std::vector<double> got(grad_prev);
  got.insert(got.end(), grad_z.begin(), grad_z.end());
  EXPECT_LT(MaxRelativeError(got, expected), 1e-10);
}

TEST_F(HumorPriorTest, SequenceIsTheSumOfPairs) {
  const int T = 4;
  std::vector<double> states;
  for (int t = 0; t < T; ++t) {
    auto s = RandomHumorState(50 + t);
    states.insert(states.end(), s.begin(), s.end());
  }
  std::vector<double> grad(T * kStateDim);
  const double total = prior_->SequenceTransitionNll(T, states.data(), grad.data());
  std::vector<double> expected(T * kStateDim, 0.0);
  double expected_total = 0;
  for (int t = 0; t + 1 < T; ++t) {
    std::vector<double> ga(kStateDim), gb(kStateDim);
    double v;
    prior_->TransitionNll(1, &states[t * kStateDim], &states[(t + 1) * kStateDim], &v, ga.data(), gb.data());
    expected_total += v;
    for (int i = 0; i < kStateDim; ++i) {
      expected[t * kStateDim + i] += ga[i];
      expected[(t + 1) * kStateDim + i] += gb[i];
    }
  }
  EXPECT_NEAR(total, expected_total, 1e-12 * std::abs(expected_total));
  EXPECT_LT(MaxRelativeError(grad, expected), 1e-13);
  EXPECT_THROW(prior_->SequenceTransitionNll(1, states.data(), nullptr), std::invalid_argument);
}

TEST(HumorState, CanonicalFrameFacesForwardAtTheOrigin) {
  const auto x = RandomHumorState(60);
  double c[kStateDim];
  humor::ToCanonical(humor::ComputeCanonicalFrame(x.data()), x.data(), c);
  EXPECT_NEAR(c[0], 0.0, 1e-15);
  EXPECT_NEAR(c[1], 0.0, 1e-15);
  EXPECT_EQ(c[2], x[2]);
  EXPECT_NEAR(c[humor::kRootOrient + 3], 0.0, 1e-15);  // R'[1][0] = 0: the right direction lies on x
  EXPECT_LT(c[humor::kRootOrient], 0.0);               // ... pointing to +x (right = -first column)
  // The pelvis keeps its horizontal offset from the translation.
  EXPECT_NEAR(c[humor::kJoints] - c[0], x[humor::kJoints] - x[0], 1e-14);
  EXPECT_NEAR(c[humor::kJoints + 1] - c[1], x[humor::kJoints + 1] - x[1], 1e-14);
}

// Three frames of a motion with constant angular velocity w and quadratic translation/joints.
struct Frames {
  double trans[3][3], root[3][3], joints[3][66], pose[63];
};

Frames ConstantMotion(const double* w, double h) {
  Frames f;
  const double r0[3] = {0.3, -0.2, 0.5};
  const auto joints0 = RandomVector(66, 1.0, 70);
  const double b[3] = {1.0, -0.5, 0.2}, a[3] = {0.3, 0.7, -0.4};
  for (int k = 0; k < 3; ++k) {
    const double t = (k - 1) * h;
    // R(t) = Exp(t w) R0, expressed back as axis-angle through matrices.
    double tw[3] = {t * w[0], t * w[1], t * w[2]}, Rt[9], R0[9];
    AxisAngleToRotation(tw, Rt);
    AxisAngleToRotation(r0, R0);
    using Mat3 = Eigen::Matrix<double, 3, 3, Eigen::RowMajor>;
    const Mat3 R = Eigen::Map<const Mat3>(Rt) * Eigen::Map<const Mat3>(R0);
    const Eigen::AngleAxisd aa(R);
    for (int i = 0; i < 3; ++i) {
      f.root[k][i] = aa.angle() * aa.axis()[i];
      f.trans[k][i] = 0.5 + b[i] * t + a[i] * t * t;
    }
    for (int i = 0; i < 66; ++i) f.joints[k][i] = joints0[i] + b[i % 3] * t + a[i % 3] * t * t;
  }
  const auto pose = RandomVector(63, 0.4, 71);
  std::copy(pose.begin(), pose.end(), f.pose);
  return f;
}

TEST(HumorState, BuildStateMatchesClosedForms) {
  const double fps = 30.0, h = 1.0 / fps, w[3] = {0.4, -1.2, 2.0};
  const Frames f = ConstantMotion(w, h);
  const double* trans[3] = {f.trans[0], f.trans[1], f.trans[2]};
  const double* root[3] = {f.root[0], f.root[1], f.root[2]};
  const double* joints[3] = {f.joints[0], f.joints[1], f.joints[2]};
  double x[kStateDim];
  humor::BuildState(trans, root, joints, f.pose, fps, static_cast<const double*>(nullptr),
                    static_cast<const double*>(nullptr), x);
  const double b[3] = {1.0, -0.5, 0.2};
  const double norm = std::sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2]);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(x[humor::kTransVel + i], b[i], 1e-12);  // central differences are exact on quadratics
    // (Exp(hw) - Exp(-hw)) / 2h = [w]x sin(h|w|) / (h|w|)
    EXPECT_NEAR(x[humor::kRootOrientVel + i], w[i] * std::sin(h * norm) / (h * norm), 1e-9);
  }
  for (int i = 0; i < 66; ++i) EXPECT_NEAR(x[humor::kJointsVel + i], b[i % 3], 1e-11);
  double R[9];
  AxisAngleToRotation(f.pose + 3 * 20, R);
  for (int i = 0; i < 9; ++i) EXPECT_EQ(x[humor::kPoseBody + 9 * 20 + i], R[i]);
}

TEST(HumorState, BuildStateRunsOnJets) {
  // d state / d (root orientation of frame t+1) by Jets against central differences.
  using Jet = ceres::Jet<double, 3>;
  const double fps = 30.0, w[3] = {0.5, 0.2, -0.7};
  const Frames f = ConstantMotion(w, 1.0 / fps);
  const double aa[3] = {0.2, 0.1, -0.3}, t[3] = {0.1, 0.2, 0.3};
  double G[9];
  AxisAngleToRotation(aa, G);
  auto build = [&](const auto* next_root, auto* out) {
    using T = std::decay_t<decltype(*out)>;
    std::vector<T> tr(9), ro(9), jo(198), pose(63), gR(9), gt(3);
    for (int k = 0; k < 3; ++k) {
      for (int i = 0; i < 3; ++i) {
        tr[3 * k + i] = T(f.trans[k][i]);
        ro[3 * k + i] = k == 2 ? next_root[i] : T(f.root[k][i]);
      }
      for (int i = 0; i < 66; ++i) jo[66 * k + i] = T(f.joints[k][i]);
    }
    for (int i = 0; i < 63; ++i) pose[i] = T(f.pose[i]);
    for (int i = 0; i < 9; ++i) gR[i] = T(G[i]);
    for (int i = 0; i < 3; ++i) gt[i] = T(t[i]);
    const T* trans[3] = {&tr[0], &tr[3], &tr[6]};
    const T* root[3] = {&ro[0], &ro[3], &ro[6]};
    const T* joints[3] = {&jo[0], &jo[66], &jo[132]};
    humor::BuildState(trans, root, joints, pose.data(), fps, gR.data(), gt.data(), out);
  };
  Jet root_jet[3];
  for (int i = 0; i < 3; ++i) root_jet[i] = Jet(f.root[2][i], i);
  std::vector<Jet> state(kStateDim);
  build(root_jet, state.data());
  for (int i = 0; i < 3; ++i) {
    double plus[3] = {f.root[2][0], f.root[2][1], f.root[2][2]}, minus[3] = {plus[0], plus[1], plus[2]};
    plus[i] += 1e-6;
    minus[i] -= 1e-6;
    double xp[kStateDim], xm[kStateDim];
    build(plus, xp);
    build(minus, xm);
    for (int k = 0; k < kStateDim; ++k) {
      EXPECT_NEAR(state[k].v[i], (xp[k] - xm[k]) / 2e-6, 1e-6 * (1 + std::abs(state[k].v[i]))) << k;
    }
  }
  // Only the angular velocity depends on the next frame's root orientation.
  EXPECT_GT(std::abs(state[humor::kRootOrientVel].v[0]), 1.0);
  EXPECT_EQ(state[humor::kRootOrient].v[0], 0.0);
}

TEST(HumorState, GroundTransformMovesTheStateRigidly) {
  const double fps = 30.0, w[3] = {0.1, 0.3, -0.2};
  const Frames f = ConstantMotion(w, 1.0 / fps);
  const double* trans[3] = {f.trans[0], f.trans[1], f.trans[2]};
  const double* root[3] = {f.root[0], f.root[1], f.root[2]};
  const double* joints[3] = {f.joints[0], f.joints[1], f.joints[2]};
  const double aa[3] = {0.7, -0.3, 0.4}, t[3] = {0.2, -1.0, 0.5};
  double G[9];
  AxisAngleToRotation(aa, G);
  double x[kStateDim], y[kStateDim];
  humor::BuildState(trans, root, joints, f.pose, fps, static_cast<const double*>(nullptr),
                    static_cast<const double*>(nullptr), x);
  humor::BuildState(trans, root, joints, f.pose, fps, G, t, y);
  Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Gm(G);
  auto vec = [](const double* p) { return Eigen::Vector3d(p[0], p[1], p[2]); };
  // Velocities (linear and angular) rotate as vectors; joints move rigidly; rotations compose.
  EXPECT_LT((vec(y + humor::kTransVel) - Gm * vec(x + humor::kTransVel)).norm(), 1e-12);
  EXPECT_LT((vec(y + humor::kRootOrientVel) - Gm * vec(x + humor::kRootOrientVel)).norm(), 1e-10);
  for (int j = 0; j < 22; ++j) {
    EXPECT_LT((vec(y + humor::kJoints + 3 * j) - (Gm * vec(x + humor::kJoints + 3 * j) + vec(t))).norm(), 1e-12);
    EXPECT_LT((vec(y + humor::kJointsVel + 3 * j) - Gm * vec(x + humor::kJointsVel + 3 * j)).norm(), 1e-11);
  }
  Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Rx(x + humor::kRootOrient), Ry(y + humor::kRootOrient);
  EXPECT_LT((Ry - Gm * Rx).norm(), 1e-14);
  // SMPL's translation follows its rest pelvis: pelvis - trans is unchanged.
  EXPECT_LT((vec(y + humor::kJoints) - vec(y) - (vec(x + humor::kJoints) - vec(x))).norm(), 1e-12);
}

TEST(HumorPrior, FileWithoutManifestIsRejected) {
  TempFile tmp("humor_nometa.safetensors");
  Tensor t{"F64", {1}, {0.0}};
  WriteSafetensors(tmp.path(), {{"x", t}}, {});
  try {
    HumorPrior::FromFile(tmp.path());
    FAIL();
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("python -m m3c.models.export"), std::string::npos);
  }
}

}  // namespace
}  // namespace m3c::nn
