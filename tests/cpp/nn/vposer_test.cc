#include "nn/vposer.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "jet_gradient.h"
#include "test_files.h"

namespace m3c::nn {
namespace {

using testing::RandomVector;
using testing::TempFile;

class VPoserTest : public ::testing::TestWithParam<std::string> {};

TEST_P(VPoserTest, DecodesRotationsWithExactDerivatives) {
  TempFile tmp("vposer_" + GetParam() + ".safetensors");
  testing::WriteRandomVPoser(tmp.path(), GetParam(), 16, 4, 5);
  const VPoser vposer = VPoser::FromFile(tmp.path());
  EXPECT_EQ(vposer.version(), GetParam());
  EXPECT_EQ(vposer.latent_dim(), 4);
  const std::vector<double> z = RandomVector(4, 1.0, 6);
  std::vector<double> R(21 * 9);
  vposer.Decode(z.data(), R.data());
  for (int j = 0; j < 21; ++j) {
    Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Rj(&R[9 * j]);
    EXPECT_LT((Rj * Rj.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-13);
    EXPECT_NEAR(Rj.determinant(), 1.0, 1e-13);
  }
  // Jet derivative of one output entry against central differences.
  for (int out : {0, 40, 9 * 20 + 8}) {
    const std::vector<double> grad = testing::JetGradient<4>(z, [&](const auto& zj) {
      using Jet = typename std::decay_t<decltype(zj)>::value_type;
      std::vector<Jet> Rj(21 * 9);
      vposer.Decode(zj.data(), Rj.data());
      return Rj[out];
    });
    for (int d = 0; d < 4; ++d) {
      std::vector<double> zp(z), zm(z), Rp(189), Rm(189);
      const double eps = 1e-6;
      zp[d] += eps;
      zm[d] -= eps;
      vposer.Decode(zp.data(), Rp.data());
      vposer.Decode(zm.data(), Rm.data());
      EXPECT_NEAR(grad[d], (Rp[out] - Rm[out]) / (2 * eps), 1e-7) << "output " << out << " latent " << d;
    }
  }
  // The encoder runs the version's ops; its scale is positive and its derivative exact.
  const std::vector<double> pose = RandomVector(63, 0.4, 7);
  std::vector<double> mean(4), scale(4);
  vposer.Encode(pose.data(), mean.data(), scale.data());
  for (double s : scale) EXPECT_GT(s, 0.0);
  const std::vector<double> grad = testing::JetGradient<63>(pose, [&](const auto& p) {
    using Jet = typename std::decay_t<decltype(p)>::value_type;
    std::vector<Jet> m(4), s(4);
    vposer.Encode(p.data(), m.data(), s.data());
    return m[1] + s[2];
  });
  for (int d : {0, 30, 62}) {
    std::vector<double> pp(pose), pm(pose), mp(4), mm(4), sp(4), sm(4);
    pp[d] += 1e-6;
    pm[d] -= 1e-6;
    vposer.Encode(pp.data(), mp.data(), sp.data());
    vposer.Encode(pm.data(), mm.data(), sm.data());
    EXPECT_NEAR(grad[d], ((mp[1] + sp[2]) - (mm[1] + sm[2])) / 2e-6, 1e-7);
  }
}

INSTANTIATE_TEST_SUITE_P(Versions, VPoserTest, ::testing::Values("v1", "v2"));

TEST(Rotation6d, RowAndColumnConventions) {
  const std::vector<double> x = RandomVector(6, 1.0, 8);
  double Rc[9], Rr[9];
  Rotation6dColumnsToMatrix(x.data(), Rc);
  Rotation6dRowsToMatrix(x.data(), Rr);
  // Columns: first column is (x0, x2, x4) normalised; rows: first row is (x0, x1, x2) normalised.
  const double nc = std::sqrt(x[0] * x[0] + x[2] * x[2] + x[4] * x[4]);
  const double nr = std::sqrt(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(Rc[3 * i], x[2 * i] / nc, 1e-15);
    EXPECT_NEAR(Rr[i], x[i] / nr, 1e-15);
  }
  Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> A(Rr);
  EXPECT_LT((A * A.transpose() - Eigen::Matrix3d::Identity()).norm(), 1e-14);
  EXPECT_NEAR(A.determinant(), 1.0, 1e-14);
  // The second row lies in the plane of x[0:3] and x[3:6].
  const Eigen::Vector3d a(x[0], x[1], x[2]), b(x[3], x[4], x[5]);
  EXPECT_NEAR(A.row(1).dot(a.cross(b)), 0.0, 1e-14);
  EXPECT_GT(A.row(1).dot(b), 0.0);
}

}  // namespace
}  // namespace m3c::nn
