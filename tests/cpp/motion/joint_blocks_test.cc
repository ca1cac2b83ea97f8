#include "motion/joint_blocks.h"

#include <dlfcn.h>
#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "motion/costs.h"
#include "util/blas_threads.h"
#include "../body/cost_checks.h"

namespace m3c::motion {
namespace {

using body::testing::CheckGradient;
using body::testing::MakeTestModel;
using body::testing::ThreePointRegressor;
using Frame = body::testing::RandomPoseBlocks;

TEST(JointBlocks, ChainsCoverEveryJointOnceAndFollowTheTree) {
  const body::BodyModel model = MakeTestModel();
  const body::KeypointRegressor joints = body::IdentityJointRegressor(model);
  SharedJoints shared(&model, &joints, 1);
  std::vector<int> seen(model.num_joints(), 0);
  for (const auto& chain : shared.Chains()) {
    for (size_t k = 0; k < chain.size(); ++k) {
      ++seen[chain[k]];
      if (k > 0) EXPECT_EQ(model.parents()[chain[k]], chain[k - 1]);  // each joint the child of the one before
    }
  }
  for (int j = 0; j < model.num_joints(); ++j) EXPECT_EQ(seen[j], 1) << "joint " << j;
  // SMPL's layout: the pelvis, two legs, the spine, neck and head, two arms.
  EXPECT_EQ(shared.Chains().size(), 7u);
  EXPECT_EQ(shared.Chains()[0], (std::vector<int>{0}));
  EXPECT_EQ(shared.Chains()[1], (std::vector<int>{1, 4, 7, 10}));
  EXPECT_EQ(shared.Ancestors(10), (std::vector<int>{1, 4, 7}));  // left foot: hip, knee, ankle
  EXPECT_TRUE(shared.Ancestors(0).empty());
}

TEST(JointBlocks, SelectedJoints) {
  const body::BodyModel model = MakeTestModel();
  Eigen::SparseMatrix<double, Eigen::RowMajor> vw(2, model.num_vertices()), jw(2, model.num_joints());
  jw.insert(0, 7) = 1.0;
  jw.insert(1, 11) = 1.0;
  EXPECT_EQ(SelectedJoints(body::KeypointRegressor(vw, jw)), (std::vector<int>{7, 11}));
  jw.coeffRef(1, 11) = 0.5;  // a weighted joint is not a selection
  EXPECT_TRUE(SelectedJoints(body::KeypointRegressor(vw, jw)).empty());
  EXPECT_TRUE(SelectedJoints(ThreePointRegressor(model)).empty());  // vertices
}

// The chain stencils over all chains against PointStencilCost over all joints (the unshared path): the same
// residuals and Jacobians, from the shared evaluation and from a block's own; sigma > 0: both robust.
void CheckChainStencilsEqualTheWholeBodyStencil(double sigma) {
  const body::BodyModel model = MakeTestModel();
  const body::KeypointRegressor joints = body::IdentityJointRegressor(model);
  const int J = model.num_joints(), B = model.num_betas();
  std::vector<Frame> frames = {Frame(model, 3), Frame(model, 7), Frame(model, 21)};
  for (Frame& f : frames) f.betas = frames[0].betas;  // one person
  const std::vector<double> stencil = {1.0, -2.0, 1.0};
  const double weight = 2.5;
  PointStencilCost whole(&model, &joints, stencil, std::vector<double>(J, weight), sigma);
  std::vector<const double*> whole_params;
  for (const Frame& f : frames) whole_params.insert(whole_params.end(), {f.transl.data(), f.root.data(), f.body.data()});
  whole_params.push_back(frames[0].betas.data());
  std::vector<double> whole_res(3 * J);
  std::vector<std::vector<double>> whole_jac(10);
  std::vector<double*> whole_jac_ptr(10);
  for (int b = 0; b < 10; ++b) {
    whole_jac[b].resize(3 * J * whole.parameter_block_sizes()[b]);
    whole_jac_ptr[b] = whole_jac[b].data();
  }
  ASSERT_TRUE(whole.Evaluate(whole_params.data(), whole_res.data(), whole_jac_ptr.data()));

  SharedJoints shared(&model, &joints, 2);
  for (const Frame& f : frames) shared.AddFrame(f.transl.data(), f.root.data(), f.body.data(), f.betas.data());
  enum { kNotEvaluated, kEvaluated, kReleased };
  for (const int state : {kNotEvaluated, kEvaluated, kReleased}) {
    if (state == kEvaluated) shared.EvaluateAll(true);
    if (state == kReleased) shared.Release();  // a block computes its joints again
    for (const auto& chain : shared.Chains()) {
      JointStencilCost cost(&shared, {0, 1, 2}, stencil, chain, std::vector<double>(chain.size(), weight), sigma);
      const int A = static_cast<int>(cost.ancestors().size()), per = 2 + A;
      std::vector<const double*> params;
      for (const Frame& f : frames) {
        params.insert(params.end(), {f.transl.data(), f.root.data()});
        for (int a : cost.ancestors()) params.push_back(f.body.data() + 3 * (a - 1));
      }
      params.push_back(frames[0].betas.data());
      const int rows = cost.num_residuals(), blocks = static_cast<int>(params.size());
      std::vector<double> res(rows);
      std::vector<std::vector<double>> jac(blocks);
      std::vector<double*> jac_ptr(blocks);
      for (int b = 0; b < blocks; ++b) {
        jac[b].resize(rows * cost.parameter_block_sizes()[b]);
        jac_ptr[b] = jac[b].data();
      }
      ASSERT_TRUE(cost.Evaluate(params.data(), res.data(), jac_ptr.data()));
      for (size_t n = 0; n < chain.size(); ++n) {
        for (int c = 0; c < 3; ++c) {
          const int r = 3 * static_cast<int>(n) + c, wr = 3 * chain[n] + c;
          EXPECT_NEAR(res[r], whole_res[wr], 1e-12);
          for (int f = 0; f < 3; ++f) {
            for (int i = 0; i < 3; ++i) {
              EXPECT_NEAR(jac[f * per][3 * r + i], whole_jac[3 * f][3 * wr + i], 1e-12);
              EXPECT_NEAR(jac[f * per + 1][3 * r + i], whole_jac[3 * f + 1][3 * wr + i], 1e-12);
            }
            // The chain's blocks are the only body values its joints depend on.
            for (int k = 1; k < J; ++k) {
              const auto it = std::find(cost.ancestors().begin(), cost.ancestors().end(), k);
              for (int i = 0; i < 3; ++i) {
                const double expected = whole_jac[3 * f + 2][wr * 3 * (J - 1) + 3 * (k - 1) + i];
                if (it == cost.ancestors().end()) {
                  EXPECT_EQ(expected, 0.0) << "joint " << chain[n] << " moves with body joint " << k;
                } else {
                  EXPECT_NEAR(jac[f * per + 2 + (it - cost.ancestors().begin())][3 * r + i], expected, 1e-12);
                }
              }
            }
          }
          for (int i = 0; i < B; ++i) EXPECT_NEAR(jac[blocks - 1][B * r + i], whole_jac[9][B * wr + i], 1e-12);
        }
      }
      EXPECT_TRUE(CheckGradient(cost, params));
    }
  }
}

TEST(JointBlocks, ChainStencilsEqualTheWholeBodyStencil) { CheckChainStencilsEqualTheWholeBodyStencil(0.0); }

// The robust form (contact_velocity_sigma): the test model's joints move by about 0.1-0.5 per frame, so a sigma of
// 0.05 puts the residuals well into the bounded part of the loss.
TEST(JointBlocks, RobustChainStencilsEqualTheWholeBodyStencil) { CheckChainStencilsEqualTheWholeBodyStencil(0.05); }

TEST(JointBlocks, SplitBodyCostEqualsTheWholeBlockCost) {
  const body::BodyModel model = MakeTestModel();
  const auto reg = ThreePointRegressor(model);
  const int J = model.num_joints(), body = 3 * (J - 1);
  Frame f(model, 5);
  FrameCamera cam{Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.2, -0.1, -5.0), 800, 800, 320, 240};
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> obs(3, 3);
  obs << 300, 250, 0.9, 350, 200, 0.7, 280, 300, 0.8;
  double scale = 1.2, offset[3] = {0.05, 0.0, 0.1};
  ReprojectionCost whole(&model, &reg, cam, obs, 0.5, 100.0, 0.05);
  SplitBodyCost split(new ReprojectionCost(&model, &reg, cam, obs, 0.5, 100.0, 0.05), {2});
  ASSERT_EQ(split.parameter_block_sizes().size(), 5u + (J - 1));
  const double* whole_params[6] = {f.transl.data(), f.root.data(), f.body.data(), f.betas.data(), &scale, offset};
  std::vector<const double*> params = {f.transl.data(), f.root.data()};
  for (int k = 0; k + 1 < J; ++k) params.push_back(f.body.data() + 3 * k);
  params.insert(params.end(), {f.betas.data(), &scale, offset});
  const int rows = whole.num_residuals();
  std::vector<double> whole_res(rows), res(rows), whole_body_jac(rows * body);
  std::vector<std::vector<double>> jac(params.size());
  std::vector<double*> jac_ptr(params.size(), nullptr);
  for (int k = 0; k + 1 < J; ++k) {
    jac[2 + k].resize(rows * 3);
    jac_ptr[2 + k] = jac[2 + k].data();
  }
  double* whole_jac_ptr[6] = {nullptr, nullptr, whole_body_jac.data(), nullptr, nullptr, nullptr};
  ASSERT_TRUE(whole.Evaluate(whole_params, whole_res.data(), whole_jac_ptr));
  ASSERT_TRUE(split.Evaluate(params.data(), res.data(), jac_ptr.data()));
  for (int r = 0; r < rows; ++r) {
    EXPECT_EQ(res[r], whole_res[r]);
    for (int k = 0; k + 1 < J; ++k) {
      for (int i = 0; i < 3; ++i) EXPECT_EQ(jac[2 + k][3 * r + i], whole_body_jac[r * body + 3 * k + i]);
    }
  }
  EXPECT_TRUE(CheckGradient(split, params));
}

TEST(JointBlocks, MovingJoints) {
  const body::BodyModel model = MakeTestModel();
  const int J = model.num_joints();
  Eigen::SparseMatrix<double, Eigen::RowMajor> vw(2, model.num_vertices()), jw(2, J);
  jw.insert(0, 7) = 1.0;   // left ankle: moved by the hip and the knee
  jw.insert(1, 13) = 0.5;  // left collar: moved by the spine
  EXPECT_EQ(MovingJoints(model, body::KeypointRegressor(vw, jw)), (std::vector<int>{1, 3, 4, 6, 9}));
  EXPECT_EQ(MovingJoints(model, JointDifference(model, 0, 12)), (std::vector<int>{3, 6, 9}));  // pelvis to neck
  std::vector<int> all;
  for (int j = 1; j < J; ++j) all.push_back(j);
  EXPECT_EQ(MovingJoints(model, ThreePointRegressor(model)), all);  // vertices: the test model's pose blend shapes
}

// MovingJoints against the points' own Jacobian at a random pose: a body joint moves a point exactly when its
// Jacobian columns are nonzero. For vertices on a model with pose blend shapes (every joint) and on the same model
// without them (skinning only), and for joints.
TEST(JointBlocks, MovingJointsAreTheJointsWithANonzeroJacobian) {
  const body::BodyModel with_blend = MakeTestModel();
  const int J = with_blend.num_joints(), V = with_blend.num_vertices();
  const body::ModelArrays<double>& a = with_blend.arrays_d();
  body::RowMatrixXd v_template(V, 3), weights = body::RowMatrixXd::Zero(V, J);
  for (int v = 0; v < V; ++v) {
    v_template.row(v) = a.v_template.segment<3>(3 * v).transpose();
    for (int i = with_blend.weight_offsets()[v]; i < with_blend.weight_offsets()[v + 1]; ++i) {
      weights(v, with_blend.weight_joints()[i]) = a.weight_values[i];
    }
  }
  const body::BodyModel no_blend(v_template, a.shapedirs, Eigen::MatrixXd::Zero(a.posedirs.rows(), a.posedirs.cols()),
                                 with_blend.j_regressor(), weights, with_blend.parents(), with_blend.faces());
  Eigen::SparseMatrix<double, Eigen::RowMajor> one_vertex(1, V), no_joints(1, J), no_vertices(1, V), two_joints(1, J);
  one_vertex.insert(0, V / 3) = 1.0;
  two_joints.insert(0, 20) = 0.5;
  two_joints.insert(0, 5) = 0.5;
  int checked = 0;
  for (const body::BodyModel* model : {&with_blend, &no_blend}) {
    for (const body::KeypointRegressor& reg : {body::KeypointRegressor(one_vertex, no_joints),
                                               body::KeypointRegressor(no_vertices, two_joints)}) {
      Frame f(*model, 17);
      body::BlockPoints points;
      points.Evaluate(*model, reg, {f.transl.data(), f.root.data(), f.body.data(), f.betas.data()}, true);
      std::vector<int> nonzero;
      for (int j = 1; j < J; ++j) {
        if (points.jacobian(0, 2).middleCols<3>(3 * (j - 1)).cwiseAbs().maxCoeff() > 0.0) nonzero.push_back(j);
      }
      EXPECT_EQ(MovingJoints(*model, reg), nonzero);
      EXPECT_FALSE(nonzero.empty());
      ++checked;
    }
  }
  EXPECT_EQ(checked, 4);
  // Without blend shapes a vertex is not moved by every joint.
  EXPECT_LT(MovingJoints(no_blend, body::KeypointRegressor(one_vertex, no_joints)).size(), static_cast<size_t>(J - 1));
}

// A cost given blocks only for the joints that move it (the upright term: the spine) against the same cost on every
// joint's block: the same residuals, the same Jacobian on the joints it keeps, exact zeros on the others.
TEST(JointBlocks, SplitBodyCostOnTheMovingJointsEqualsTheWholeSplit) {
  const body::BodyModel model = MakeTestModel();
  const int J = model.num_joints();
  const std::vector<int> movers = MovingJoints(model, JointDifference(model, 0, 12));
  const Eigen::Vector3d up(0.1, 1.0, -0.2);
  SplitBodyCost all(new UprightCost(&model, 0, 12, up, 3.0, 0.2), {2});
  SplitBodyCost moved(new UprightCost(&model, 0, 12, up, 3.0, 0.2), {2}, movers);
  ASSERT_EQ(moved.parameter_block_sizes().size(), 3u + movers.size());
  Frame f(model, 11);
  std::vector<const double*> all_params = {f.transl.data(), f.root.data()}, params = all_params;
  for (int j = 1; j < J; ++j) all_params.push_back(f.body.data() + 3 * (j - 1));
  for (int j : movers) params.push_back(f.body.data() + 3 * (j - 1));
  all_params.push_back(f.betas.data());
  params.push_back(f.betas.data());
  const int rows = all.num_residuals();
  auto evaluate = [&](const ceres::CostFunction& cost, const std::vector<const double*>& p,
                      std::vector<double>* res, std::vector<std::vector<double>>* jac) {
    res->assign(rows, 0.0);
    jac->assign(p.size(), {});
    std::vector<double*> ptr;
    for (size_t b = 0; b < p.size(); ++b) {
      (*jac)[b].assign(rows * cost.parameter_block_sizes()[b], std::nan(""));
      ptr.push_back((*jac)[b].data());
    }
    return cost.Evaluate(p.data(), res->data(), ptr.data());
  };
  std::vector<double> all_res, res;
  std::vector<std::vector<double>> all_jac, jac;
  ASSERT_TRUE(evaluate(all, all_params, &all_res, &all_jac));
  ASSERT_TRUE(evaluate(moved, params, &res, &jac));
  EXPECT_EQ(res, all_res);
  EXPECT_GT(std::abs(res[0]) + std::abs(res[1]), 0.0);
  EXPECT_EQ(jac[0], all_jac[0]);  // transl
  EXPECT_EQ(jac[1], all_jac[1]);  // root
  EXPECT_EQ(jac.back(), all_jac.back());  // betas
  size_t k = 0;
  for (int j = 1; j < J; ++j) {
    const std::vector<double>& whole = all_jac[2 + (j - 1)];
    if (k < movers.size() && movers[k] == j) {
      EXPECT_EQ(jac[2 + k], whole) << "joint " << j;
      ++k;
    } else {
      for (double v : whole) EXPECT_EQ(v, 0.0) << "joint " << j << " does not move the spine";
    }
  }
  EXPECT_TRUE(CheckGradient(moved, params));
}

TEST(BlasThreads, FixedInsideTheScopeAndRestoredAfter) {
  void* lib = dlopen("libopenblas.so.0", RTLD_LAZY);  // loaded here as the optimizer's CHOLMOD loads it
  if (lib == nullptr) GTEST_SKIP() << "OpenBLAS is not installed: nothing to fix";
  const auto get = reinterpret_cast<int (*)()>(dlsym(lib, "openblas_get_num_threads"));
  const auto set = reinterpret_cast<void (*)(int)>(dlsym(lib, "openblas_set_num_threads"));
  ASSERT_TRUE(get != nullptr && set != nullptr);
  set(1);
  {
    const util::ScopedBlasThreads scope(2);
    EXPECT_EQ(get(), 2);
  }
  EXPECT_EQ(get(), 1);
  dlclose(lib);
}

}  // namespace
}  // namespace m3c::motion
