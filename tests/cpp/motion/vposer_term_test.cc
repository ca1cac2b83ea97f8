#include "motion/vposer_term.h"

#include <cmath>
#include <memory>

#include <gtest/gtest.h>

#include "body/rotation.h"
#include "motion/costs.h"
#include "../body/cost_checks.h"
#include "../nn/test_files.h"

namespace m3c::motion {
namespace {

using nn::testing::RandomVector;
using nn::testing::TempFile;

class VPoserTermTest : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    file_ = std::make_unique<TempFile>("vposer_term_" + GetParam() + ".safetensors");
    nn::testing::WriteRandomVPoser(file_->path(), GetParam(), 24, 6, 11);
    vposer_ = std::make_unique<nn::VPoser>(nn::VPoser::FromFile(file_->path()));
  }
  std::unique_ptr<TempFile> file_;
  std::unique_ptr<nn::VPoser> vposer_;
};

constexpr int kBodySize = 69;  // SMPL: 23 body joints, VPoser sees the first 21

TEST_P(VPoserTermTest, ResidualIsTheEncoderMeanAndItsJacobianIsExact) {
  const nn::VPoser& vp = *vposer_;
  const std::vector<double> a = RandomVector(kBodySize, 0.4, 3), b = RandomVector(kBodySize, 0.4, 4);
  // Values: the templated encoder (the one the parity tests check against torch) is the reference.
  std::vector<double> za(6), zb(6), scale(6);
  vp.Encode(a.data(), za.data(), scale.data());
  vp.Encode(b.data(), zb.data(), scale.data());
  std::vector<double> r(6);
  const double* prior_params[] = {a.data()};
  VPoserLatentCost prior(&vp, kBodySize, {1.0}, 0.04);
  ASSERT_TRUE(prior.Evaluate(prior_params, r.data(), nullptr));
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(r[i], 0.2 * za[i], 1e-12);
  const double* pair[] = {a.data(), b.data()};
  VPoserLatentCost smooth(&vp, kBodySize, {-1.0, 1.0}, 2.0);
  ASSERT_TRUE(smooth.Evaluate(pair, r.data(), nullptr));
  for (int i = 0; i < 6; ++i) EXPECT_NEAR(r[i], std::sqrt(2.0) * (zb[i] - za[i]), 1e-12);

  // Jacobians against small central differences, both costs. (Not ceres::GradientChecker: its Ridders
  // extrapolation starts from steps of 1% of each parameter, which cross the kinks of the LeakyReLU network.)
  for (const auto* cost : {&prior, &smooth}) {
    const int blocks = static_cast<int>(cost->parameter_block_sizes().size());
    std::vector<std::vector<double>> x = {a, b}, jac(blocks, std::vector<double>(6 * kBodySize));
    std::vector<const double*> params = {x[0].data(), x[1].data()};
    std::vector<double*> jp;  // one Jacobian per block (the prior has one: jac[1] would read past jac's end)
    for (auto& j : jac) jp.push_back(j.data());
    ASSERT_TRUE(cost->Evaluate(params.data(), r.data(), jp.data()));
    for (int blk = 0; blk < blocks; ++blk) {
      for (int k = 0; k < kBodySize; ++k) {
        std::vector<double> plus(6), minus(6);
        const double old = x[blk][k], eps = 1e-7;
        x[blk][k] = old + eps;
        ASSERT_TRUE(cost->Evaluate(params.data(), plus.data(), nullptr));
        x[blk][k] = old - eps;
        ASSERT_TRUE(cost->Evaluate(params.data(), minus.data(), nullptr));
        x[blk][k] = old;
        for (int i = 0; i < 6; ++i) {
          const double numeric = (plus[i] - minus[i]) / (2 * eps), analytic = jac[blk][i * kBodySize + k];
          EXPECT_NEAR(analytic, numeric, 1e-7 * std::max(1.0, std::abs(numeric))) << blk << ", " << i << ", " << k;
          // The hand joints (values 63..68) are outside VPoser: exactly zero columns.
          if (k >= 63) EXPECT_EQ(analytic, 0.0);
        }
      }
    }
  }
}

TEST_P(VPoserTermTest, AnalyticEncoderJacobianMatchesJets) {
  const nn::VPoser& vp = *vposer_;
  const std::vector<double> pose = RandomVector(63, 0.5, 9);
  std::vector<double> mean(6), jac(6 * 63);
  vp.EncodeMean(pose.data(), mean.data(), jac.data());
  using Jet = ceres::Jet<double, 63>;
  std::vector<Jet> pj(63), mj(6), sj(6);
  for (int i = 0; i < 63; ++i) pj[i] = Jet(pose[i], i);
  vp.Encode(pj.data(), mj.data(), sj.data());
  for (int i = 0; i < 6; ++i) {
    EXPECT_NEAR(mean[i], mj[i].a, 1e-12);
    for (int k = 0; k < 63; ++k) EXPECT_NEAR(jac[i * 63 + k], mj[i].v[k], 1e-12) << i << ", " << k;
  }
}

TEST_P(VPoserTermTest, RejectsABodyWithoutVPoserJoints) {
  EXPECT_THROW(VPoserLatentCost(vposer_.get(), 60, {1.0}, 1.0), std::invalid_argument);
  EXPECT_THROW(VPoserLatentCost(vposer_.get(), kBodySize, {}, 1.0), std::invalid_argument);
}

INSTANTIATE_TEST_SUITE_P(Versions, VPoserTermTest, ::testing::Values("v1", "v2"));

// Latent pose variables: VPoser with its real 32-d latent (small hidden layers).
class LatentPoseTest : public ::testing::TestWithParam<std::string> {
 protected:
  void SetUp() override {
    file_ = std::make_unique<TempFile>("latent_pose_" + GetParam() + ".safetensors");
    nn::testing::WriteRandomVPoser(file_->path(), GetParam(), 24, LatentPoseDecoder::kLatentDim, 12);
    vposer_ = std::make_unique<nn::VPoser>(nn::VPoser::FromFile(file_->path()));
  }
  std::unique_ptr<TempFile> file_;
  std::unique_ptr<nn::VPoser> vposer_;
};

TEST_P(LatentPoseTest, DecoderWritesTheDecodedPoseAndKeepsTheHands) {
  constexpr int L = LatentPoseDecoder::kLatentDim;
  std::vector<double> z = RandomVector(L, 0.8, 1), body = RandomVector(kBodySize, 0.3, 2);
  const std::vector<double> hands(body.begin() + 63, body.end());
  LatentPoseDecoder decoder(vposer_.get(), kBodySize, 2);
  ASSERT_EQ(decoder.AddFrame(z.data(), body.data()), 0);
  decoder.DecodeAll(true);
  // exp(decoded axis-angle) is the decoder's rotation (an independent path: VPoser::Decode to matrices).
  std::vector<double> rotations(9 * 21);
  vposer_->Decode(z.data(), rotations.data());
  for (int j = 0; j < 21; ++j) {
    double R[9];
    AxisAngleToRotation(body.data() + 3 * j, R);
    for (int k = 0; k < 9; ++k) EXPECT_NEAR(R[k], rotations[9 * j + k], 1e-10) << "joint " << j;
  }
  for (int k = 0; k < 6; ++k) EXPECT_EQ(body[63 + k], hands[k]);
  // Get: the cache at the decoded latent, a fresh decoding at another.
  std::vector<double> scratch;
  const double *cached = nullptr, *jac = nullptr;
  decoder.Get(0, z.data(), &cached, &jac, &scratch);
  EXPECT_TRUE(scratch.empty());
  for (int k = 0; k < kBodySize; ++k) EXPECT_EQ(cached[k], body[k]);
  std::vector<double> other = z;
  other[3] += 0.5;
  const double* fresh = nullptr;
  decoder.Get(0, other.data(), &fresh, nullptr, &scratch);
  std::vector<double> other_body = body;
  LatentPoseDecoder second(vposer_.get(), kBodySize, 1);
  second.AddFrame(other.data(), other_body.data());
  second.DecodeAll(false);
  for (int k = 0; k < kBodySize; ++k) EXPECT_NEAR(fresh[k], other_body[k], 1e-14);
  EXPECT_GT(std::abs(fresh[0] - body[0]) + std::abs(fresh[1] - body[1]) + std::abs(fresh[2] - body[2]), 1e-6);
}

TEST_P(LatentPoseTest, WrappedCostsHaveExactLatentJacobians) {
  constexpr int L = LatentPoseDecoder::kLatentDim;
  const body::BodyModel model = body::testing::MakeTestModel();
  ASSERT_EQ(3 * (model.num_joints() - 1), kBodySize);
  const auto reg = body::testing::ThreePointRegressor(model);
  std::vector<double> z0 = RandomVector(L, 0.7, 3), z1 = RandomVector(L, 0.7, 4);
  std::vector<double> b0 = RandomVector(kBodySize, 0.3, 5), b1 = RandomVector(kBodySize, 0.3, 6);
  std::vector<double> t0 = RandomVector(3, 0.3, 7), t1 = RandomVector(3, 0.3, 8), r0 = RandomVector(3, 0.4, 9),
                      r1 = RandomVector(3, 0.4, 10), betas = RandomVector(model.num_betas(), 0.5, 11);
  LatentPoseDecoder decoder(vposer_.get(), kBodySize, 2);
  decoder.AddFrame(z0.data(), b0.data());
  decoder.AddFrame(z1.data(), b1.data());
  decoder.DecodeAll(true);
  struct Case {
    std::unique_ptr<ceres::CostFunction> cost;
    std::vector<double*> params;
  };
  std::vector<Case> cases;
  // A body block alone, two frames' bodies, and bodies among other blocks (a joint velocity stencil).
  cases.push_back({std::make_unique<LatentBodyCost>(new GaussianPriorCost(Eigen::VectorXd::Constant(kBodySize, 0.1), 2.0),
                                                    &decoder, std::vector<int>{0}, std::vector<int>{1}),
                   {z1.data()}});
  cases.push_back({std::make_unique<LatentBodyCost>(new BlockDifferenceCost(kBodySize, 0.5), &decoder,
                                                    std::vector<int>{0, 1}, std::vector<int>{0, 1}),
                   {z0.data(), z1.data()}});
  cases.push_back({std::make_unique<LatentBodyCost>(new PointStencilCost(&model, &reg, {-1.0, 1.0}, {1.0, 2.0, 3.0}),
                                                    &decoder, std::vector<int>{2, 5}, std::vector<int>{0, 1}),
                   {t0.data(), r0.data(), z0.data(), t1.data(), r1.data(), z1.data(), betas.data()}});
  for (auto& c : cases) {
    const ceres::CostFunction& cost = *c.cost;
    const int R = cost.num_residuals(), blocks = static_cast<int>(cost.parameter_block_sizes().size());
    std::vector<std::vector<double>> jac(blocks);
    std::vector<double*> jp(blocks);
    for (int b = 0; b < blocks; ++b) {
      jac[b].resize(static_cast<size_t>(R) * cost.parameter_block_sizes()[b]);
      jp[b] = jac[b].data();
    }
    std::vector<double> r(R), plus(R), minus(R);
    ASSERT_TRUE(cost.Evaluate(c.params.data(), r.data(), jp.data()));
    for (int b = 0; b < blocks; ++b) {
      const int size = cost.parameter_block_sizes()[b];
      for (int k = 0; k < size; ++k) {
        double* x = c.params[b] + k;
        const double old = *x, eps = 1e-6;
        *x = old + eps;  // moved latents miss the cache: the cost decodes them itself
        ASSERT_TRUE(cost.Evaluate(c.params.data(), plus.data(), nullptr));
        *x = old - eps;
        ASSERT_TRUE(cost.Evaluate(c.params.data(), minus.data(), nullptr));
        *x = old;
        for (int i = 0; i < R; ++i) {
          const double numeric = (plus[i] - minus[i]) / (2 * eps), analytic = jac[b][static_cast<size_t>(i) * size + k];
          EXPECT_NEAR(analytic, numeric, 1e-6 * std::max(1.0, std::abs(numeric))) << "block " << b << " row " << i << " col " << k;
        }
      }
    }
  }
}

TEST_P(LatentPoseTest, RejectsOtherLatentSizesWithAFix) {
  TempFile small("latent_pose_small.safetensors");
  nn::testing::WriteRandomVPoser(small.path(), GetParam(), 24, 6, 13);
  const nn::VPoser vp = nn::VPoser::FromFile(small.path());
  try {
    LatentPoseDecoder decoder(&vp, kBodySize, 1);
    FAIL() << "no error";
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("latent_pose = false"), std::string::npos) << err.what();
  }
}

INSTANTIATE_TEST_SUITE_P(Versions, LatentPoseTest, ::testing::Values("v1", "v2"));

}  // namespace
}  // namespace m3c::motion
