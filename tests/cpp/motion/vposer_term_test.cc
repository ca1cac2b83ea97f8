#include "motion/vposer_term.h"

#include <cmath>
#include <memory>

#include <gtest/gtest.h>

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
    std::vector<double*> jp = {jac[0].data(), jac[1].data()};
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

}  // namespace
}  // namespace m3c::motion
