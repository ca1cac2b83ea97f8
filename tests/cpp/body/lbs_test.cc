#include "body/lbs.h"

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "test_model.h"

namespace m3c::body {
namespace {

using testing::MakeTestModel;
using testing::NaiveLbs;
using testing::RandomVector;

TEST(Lbs, MatchesNaiveReferenceInDouble) {
  const BodyModel model = MakeTestModel();
  const int N = 5, J = model.num_joints(), V = model.num_vertices(), B = model.num_betas();
  auto pose = RandomVector(N * 3 * J, 0.5, 1);
  auto betas = RandomVector(N * B, 1.0, 2);
  auto transl = RandomVector(N * 3, 1.0, 3);
  std::vector<double> verts(N * 3 * V), joints(N * 3 * J);
  Forward<double>(model, N, pose.data(), betas.data(), false, transl.data(), verts.data(), joints.data());
  for (int f = 0; f < N; ++f) {
    RowMatrixXd ref_v, ref_j;
    NaiveLbs(model, &pose[3 * J * f], &betas[B * f], &transl[3 * f], &ref_v, &ref_j);
    Eigen::Map<const RowMatrixXd> got_v(&verts[3 * V * f], V, 3), got_j(&joints[3 * J * f], J, 3);
    EXPECT_LT((got_v - ref_v).cwiseAbs().maxCoeff(), 1e-10) << "frame " << f;
    EXPECT_LT((got_j - ref_j).cwiseAbs().maxCoeff(), 1e-10) << "frame " << f;
  }
}

TEST(Lbs, FloatMatchesDouble) {
  const BodyModel model = MakeTestModel();
  const int N = 40, J = model.num_joints(), V = model.num_vertices(), B = model.num_betas();
  auto pose = RandomVector(N * 3 * J, 0.5, 4);
  auto betas = RandomVector(B, 1.0, 5);
  std::vector<double> vd(N * 3 * V), jd(N * 3 * J);
  Forward<double>(model, N, pose.data(), betas.data(), true, nullptr, vd.data(), jd.data());
  std::vector<float> pf(pose.begin(), pose.end()), bf(betas.begin(), betas.end()), vf(N * 3 * V), jf(N * 3 * J);
  Forward<float>(model, N, pf.data(), bf.data(), true, nullptr, vf.data(), jf.data());
  for (size_t i = 0; i < vd.size(); ++i) ASSERT_NEAR(vf[i], vd[i], 1e-5);
  for (size_t i = 0; i < jd.size(); ++i) ASSERT_NEAR(jf[i], jd[i], 1e-5);
}

TEST(Lbs, SharedBetasEqualPerFrameBetasAndBatchesSpanChunks) {
  const BodyModel model = MakeTestModel();
  const int N = 70, J = model.num_joints(), V = model.num_vertices(), B = model.num_betas();
  auto pose = RandomVector(N * 3 * J, 0.5, 6);
  auto beta = RandomVector(B, 1.0, 7);
  std::vector<double> tiled;
  for (int f = 0; f < N; ++f) tiled.insert(tiled.end(), beta.begin(), beta.end());
  std::vector<double> v1(N * 3 * V), v2(N * 3 * V), j1(N * 3 * J), j2(N * 3 * J);
  Forward<double>(model, N, pose.data(), beta.data(), true, nullptr, v1.data(), j1.data());
  Forward<double>(model, N, pose.data(), tiled.data(), false, nullptr, v2.data(), j2.data());
  for (size_t i = 0; i < v1.size(); ++i) ASSERT_NEAR(v1[i], v2[i], 1e-12);
  RowMatrixXd ref_v, ref_j;
  const double zero[3] = {0, 0, 0};
  NaiveLbs(model, &pose[3 * J * (N - 1)], beta.data(), zero, &ref_v, &ref_j);
  Eigen::Map<const RowMatrixXd> last(&v1[3 * V * (N - 1)], V, 3);
  EXPECT_LT((last - ref_v).cwiseAbs().maxCoeff(), 1e-10);
}

TEST(Lbs, RestPoseGivesTemplate) {
  const BodyModel model = MakeTestModel();
  const int J = model.num_joints(), V = model.num_vertices(), B = model.num_betas();
  std::vector<double> pose(3 * J, 0.0), betas(B, 0.0), transl = {0.5, -1.0, 2.0}, verts(3 * V), joints(3 * J);
  Forward<double>(model, 1, pose.data(), betas.data(), true, transl.data(), verts.data(), joints.data());
  for (int v = 0; v < V; ++v)
    for (int c = 0; c < 3; ++c) ASSERT_NEAR(verts[3 * v + c], model.arrays_d().v_template[3 * v + c] + transl[c], 1e-12);
}

TEST(Lbs, ForwardKinematicsEqualsSkinnedJoints) {
  const BodyModel model = MakeTestModel();
  const int N = 300, J = model.num_joints(), V = model.num_vertices(), B = model.num_betas();
  auto pose = RandomVector(N * 3 * J, 0.7, 8);
  auto betas = RandomVector(N * B, 1.0, 9);
  auto transl = RandomVector(N * 3, 1.0, 10);
  std::vector<double> verts(N * 3 * V), joints(N * 3 * J), fk(N * 3 * J);
  Forward<double>(model, N, pose.data(), betas.data(), false, transl.data(), verts.data(), joints.data());
  ForwardKinematics<double>(model, N, pose.data(), betas.data(), false, transl.data(), fk.data());
  for (size_t i = 0; i < fk.size(); ++i) ASSERT_NEAR(fk[i], joints[i], 1e-12);
}

TEST(BodyModel, RejectsBadParents) {
  RowMatrixXd vt = RowMatrixXd::Zero(2, 3), w = RowMatrixXd::Constant(2, 2, 0.5);
  Eigen::SparseMatrix<double, Eigen::RowMajor> jr(2, 2);
  jr.setIdentity();
  Eigen::MatrixXd sd = Eigen::MatrixXd::Zero(6, 1), pd = Eigen::MatrixXd::Zero(6, 9);
  EXPECT_THROW(BodyModel(vt, sd, pd, jr, w, {-1, 1}, RowMatrixXi(0, 3)), std::invalid_argument);
  EXPECT_THROW(BodyModel(vt, sd, pd, jr, w, {0, 0}, RowMatrixXi(0, 3)), std::invalid_argument);
  EXPECT_NO_THROW(BodyModel(vt, sd, pd, jr, w, {-1, 0}, RowMatrixXi(0, 3)));
  Eigen::MatrixXd bad_pd = Eigen::MatrixXd::Zero(6, 8);
  EXPECT_THROW(BodyModel(vt, sd, bad_pd, jr, w, {-1, 0}, RowMatrixXi(0, 3)), std::invalid_argument);
  RowMatrixXd nan_vt = vt;
  nan_vt(0, 0) = std::nan("");
  EXPECT_THROW(BodyModel(nan_vt, sd, pd, jr, w, {-1, 0}, RowMatrixXi(0, 3)), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::body
