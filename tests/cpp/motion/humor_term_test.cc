#include "motion/humor_term.h"

#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "../body/test_model.h"
#include "../nn/test_files.h"

namespace m3c::motion {
namespace {

using body::testing::MakeTestModel;
using body::testing::RandomVector;

struct Window {
  std::vector<std::vector<double>> transl, root, body;
  std::vector<double> betas;
  std::vector<const double*> Pointers() const {
    std::vector<const double*> p;
    for (int f = 0; f < 4; ++f) p.insert(p.end(), {transl[f].data(), root[f].data(), body[f].data()});
    p.push_back(betas.data());
    return p;
  }
};

// Four frames of a body moving forward with small pose changes.
Window MakeWindow(const body::BodyModel& model) {
  Window w;
  const auto base_body = RandomVector(3 * (model.num_joints() - 1), 0.3, 3);
  for (int f = 0; f < 4; ++f) {
    w.transl.push_back({0.05 * f, 0.9 + 0.01 * f, 0.02 * f});
    w.root.push_back({0.1, 0.3 + 0.02 * f, -0.05});
    auto body = base_body;
    const auto delta = RandomVector(body.size(), 0.02, 10 + f);
    for (size_t i = 0; i < body.size(); ++i) body[i] += delta[i];
    w.body.push_back(body);
  }
  w.betas = RandomVector(model.num_betas(), 0.5, 7);
  return w;
}

class HumorTermTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    file_ = new nn::testing::TempFile("humor_term.safetensors");
    nn::testing::WriteRandomHumor(file_->path(), 32, 4, 3);
    prior_ = new nn::HumorPrior(nn::HumorPrior::FromFile(file_->path()));
  }
  static void TearDownTestSuite() {
    delete prior_;
    delete file_;
  }
  static nn::testing::TempFile* file_;
  static nn::HumorPrior* prior_;
};
nn::testing::TempFile* HumorTermTest::file_ = nullptr;
nn::HumorPrior* HumorTermTest::prior_ = nullptr;

TEST_F(HumorTermTest, JacobiansMatchNumericDifferences) {
  const body::BodyModel model = MakeTestModel();
  const Window w = MakeWindow(model);
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  GroundFrame(Eigen::Vector3d(0.05, 1.0, -0.1), 0.95, &R, &t);
  HumorTransitionCost probe(&model, prior_, 30.0, R, t, 0.075, 0.0);
  const auto params = w.Pointers();
  const double nll = probe.Nll(params.data());
  ASSERT_TRUE(std::isfinite(nll));
  HumorTransitionCost cost(&model, prior_, 30.0, R, t, 0.075, nll - 100.0);
  double r;
  ASSERT_TRUE(cost.Evaluate(params.data(), &r, nullptr));
  EXPECT_NEAR(r * r, 0.075 * 100.0, 1e-9);  // r^2 = w (nll - level)
  // Central differences, block by block. (ceres::GradientChecker reports large errors on this cost while these
  // differences agree to ~1e-9; the cause was not found, see the issue note.)
  std::vector<std::vector<double>> jac(13);
  std::vector<double*> jp(13);
  for (int b = 0; b < 13; ++b) {
    jac[b].resize(cost.parameter_block_sizes()[b]);
    jp[b] = jac[b].data();
  }
  ASSERT_TRUE(cost.Evaluate(params.data(), &r, jp.data()));
  Window probe_window = w;
  auto ptrs = probe_window.Pointers();
  for (int b = 0; b < 13; ++b) {
    double* x = const_cast<double*>(ptrs[b]);
    for (int i = 0; i < cost.parameter_block_sizes()[b]; ++i) {
      const double old = x[i];
      double plus, minus;
      x[i] = old + 1e-6;
      ASSERT_TRUE(cost.Evaluate(ptrs.data(), &plus, nullptr));
      x[i] = old - 1e-6;
      ASSERT_TRUE(cost.Evaluate(ptrs.data(), &minus, nullptr));
      x[i] = old;
      EXPECT_NEAR(jac[b][i], (plus - minus) / 2e-6, 1e-7 * std::max(1.0, std::abs(jac[b][i])))
          << "block " << b << " entry " << i;
    }
  }
}

TEST_F(HumorTermTest, InvariantToHeadingAndHorizontalPlacement) {
  // HuMoR canonicalises each transition: turning the whole window about the up axis and sliding it along the
  // ground leaves the likelihood unchanged.
  const body::BodyModel model = MakeTestModel();
  Window w = MakeWindow(model);
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  GroundFrame(Eigen::Vector3d(0, 1, 0), 0.0, &R, &t);
  HumorTransitionCost cost(&model, prior_, 30.0, R, t, 1.0, 0.0);
  const double before = cost.Nll(w.Pointers().data());
  const Eigen::AngleAxisd yaw(0.7, Eigen::Vector3d::UnitY());
  for (int f = 0; f < 4; ++f) {
    // Rotate the body about the world origin (pelvis offsets included) by turning root and translation.
    Eigen::Vector3d aa(w.root[f][0], w.root[f][1], w.root[f][2]);
    const Eigen::AngleAxisd root(aa.norm(), aa.normalized());
    const Eigen::AngleAxisd turned(yaw * root);
    const Eigen::Vector3d axis = turned.angle() * turned.axis();
    // The root rotates about the rest pelvis, so the translation follows the pelvis: use the FK pelvis.
    std::vector<double> pose(3 * model.num_joints(), 0.0), pelvis(3);
    for (int c = 0; c < 3; ++c) pose[c] = w.root[f][c];
    std::copy(w.body[f].begin(), w.body[f].end(), pose.begin() + 3);
    body::KeypointRegressor first = body::IdentityJointRegressor(model);
    std::vector<double> joints(3 * model.num_joints());
    const double zero[3] = {0, 0, 0};
    body::KeypointsWithJacobian(model, first, pose.data(), w.betas.data(), zero, joints.data(), nullptr);
    const Eigen::Vector3d j0(joints[0], joints[1], joints[2]);
    const Eigen::Vector3d tr(w.transl[f][0], w.transl[f][1], w.transl[f][2]);
    const Eigen::Vector3d moved = yaw * (tr + j0) - j0 + Eigen::Vector3d(1.5, 0.0, -2.0);
    for (int c = 0; c < 3; ++c) {
      w.root[f][c] = axis[c];
      w.transl[f][c] = moved[c];
    }
  }
  EXPECT_NEAR(cost.Nll(w.Pointers().data()), before, 1e-8 * std::max(1.0, std::abs(before)));
}



// A person's sequence of n frames, walking with a changing pose, as per-frame parameter blocks.
struct Sequence {
  std::vector<std::vector<double>> transl, root, body;
  std::vector<double> betas;
  std::vector<double*> Blocks(std::vector<std::vector<double>>& v) {
    std::vector<double*> p;
    for (auto& x : v) p.push_back(x.data());
    return p;
  }
};

Sequence MakeSequence(const body::BodyModel& model, int n, unsigned seed) {
  Sequence s;
  const auto base = RandomVector(3 * (model.num_joints() - 1), 0.3, seed);
  for (int f = 0; f < n; ++f) {
    s.transl.push_back({0.04 * f, 0.9 + 0.01 * std::sin(0.5 * f), 0.01 * f});
    s.root.push_back({0.1, 0.3 + 0.03 * f, -0.05});
    auto body = base;
    const auto delta = RandomVector(body.size(), 0.05, seed + 100 + f);
    for (size_t i = 0; i < body.size(); ++i) body[i] += delta[i];
    s.body.push_back(body);
  }
  s.betas = RandomVector(model.num_betas(), 0.5, seed + 7);
  return s;
}

// Two people (7 and 5 frames) on two slightly different grounds: the batch tests' scene.
struct TwoTracks {
  Sequence a, b;
  Eigen::Matrix3d Ra, Rb;
  Eigen::Vector3d ta, tb;
  explicit TwoTracks(const body::BodyModel& model) : a(MakeSequence(model, 7, 1)), b(MakeSequence(model, 5, 2)) {
    GroundFrame(Eigen::Vector3d(0.05, 1.0, -0.1), 0.95, &Ra, &ta);
    GroundFrame(Eigen::Vector3d(0.0, 1.0, 0.0), 0.9, &Rb, &tb);
  }
  void AddTo(HumorTransitionBatch* batch) {
    batch->AddTrack(a.Blocks(a.transl), a.Blocks(a.root), a.Blocks(a.body), a.betas.data(), Ra, ta);
    batch->AddTrack(b.Blocks(b.transl), b.Blocks(b.root), b.Blocks(b.body), b.betas.data(), Rb, tb);
  }
};

// Residual and Jacobian blocks of a cost at its parameters.
struct Evaluation {
  double r = 0.0;
  std::vector<std::vector<double>> jac;
};

Evaluation EvaluateCost(const ceres::CostFunction& cost, const std::vector<double*>& params) {
  Evaluation e;
  std::vector<double*> jp;
  for (int32_t size : cost.parameter_block_sizes()) e.jac.emplace_back(size);
  for (auto& j : e.jac) jp.push_back(j.data());
  EXPECT_TRUE(cost.Evaluate(params.data(), &e.r, jp.data()));
  return e;
}

TEST_F(HumorTermTest, BatchMatchesSingleBlocks) {
  const body::BodyModel model = MakeTestModel();
  TwoTracks scene(model);
  Sequence& a = scene.a;
  const Eigen::Matrix3d &Ra = scene.Ra, &Rb = scene.Rb;
  const Eigen::Vector3d &ta = scene.ta, &tb = scene.tb;
  HumorTransitionBatch batch(&model, prior_, 30.0, 2);
  scene.AddTo(&batch);
  ASSERT_EQ(batch.num_transitions(), (7 - 3) + (5 - 3));
  const std::vector<double> nll = batch.Nll();
  // Ceres asks for values only at a trial point; the batch evaluates the gradients with them (an accepted step
  // asks for them next), and the blocks read both from it.
  batch.PrepareForEvaluation(false, true);
  const int packed = 4 * (6 + 3 * (model.num_joints() - 1)) + model.num_betas();
  for (int i = 0; i < batch.num_transitions(); ++i) {
    const bool first = i < 4;
    HumorTransitionCost single(&model, prior_, 30.0, first ? Ra : Rb, first ? ta : tb, 0.075, nll[i] - 50.0);
    HumorTransitionCost batched(&batch, i, 0.075, nll[i] - 50.0);
    const std::vector<double*> params = batch.Parameters(i);
    EXPECT_NEAR(single.Nll(params.data()), nll[i], 1e-9 * std::abs(nll[i]));
    double looked_up = 0.0;
    std::vector<double> gradient(packed);
    EXPECT_TRUE(batch.Lookup(i, params.data(), &looked_up, gradient.data())) << "transition " << i;
    EXPECT_NEAR(looked_up, nll[i], 1e-9 * std::abs(nll[i]));
    const Evaluation s = EvaluateCost(single, params), t = EvaluateCost(batched, params);
    EXPECT_NEAR(s.r, t.r, 1e-9 * s.r);
    for (size_t blk = 0; blk < s.jac.size(); ++blk) {
      for (size_t k = 0; k < s.jac[blk].size(); ++k) {
        EXPECT_NEAR(s.jac[blk][k], t.jac[blk][k], 1e-8 * std::max(1.0, std::abs(s.jac[blk][k])))
            << "transition " << i << " block " << blk << " entry " << k;
      }
    }
  }
  // A moved value makes the cache stale for the transitions that read it: the block computes itself.
  a.body[3][5] += 0.2;
  const std::vector<double*> params = batch.Parameters(2);  // frames 1..4 of track a
  double stale = 0.0;
  EXPECT_FALSE(batch.Lookup(2, params.data(), &stale, nullptr));
  HumorTransitionCost single(&model, prior_, 30.0, Ra, ta, 0.075, nll[2] - 50.0);
  HumorTransitionCost batched(&batch, 2, 0.075, nll[2] - 50.0);
  EXPECT_NEAR(EvaluateCost(batched, params).r, EvaluateCost(single, params).r, 1e-12);
  EXPECT_NE(EvaluateCost(single, params).r, std::sqrt(0.075 * 50.0));
}

TEST_F(HumorTermTest, BatchInChunksMatchesOneChunk) {
  // Chunks of 3 transitions over tracks of 4 and 2: the second chunk spans both tracks, and the frames and states
  // at the chunk's edge are evaluated for each chunk that reads them.
  const body::BodyModel model = MakeTestModel();
  TwoTracks scene(model);
  HumorTransitionBatch whole(&model, prior_, 30.0, 2), chunked(&model, prior_, 30.0, 2, 3);
  for (HumorTransitionBatch* batch : {&whole, &chunked}) {
    scene.AddTo(batch);
    batch->PrepareForEvaluation(true, true);
  }
  const int packed = 4 * (6 + 3 * (model.num_joints() - 1)) + model.num_betas();
  for (int i = 0; i < whole.num_transitions(); ++i) {
    const std::vector<double*> params = whole.Parameters(i);
    double nll[2];
    std::vector<double> grad[2] = {std::vector<double>(packed), std::vector<double>(packed)};
    ASSERT_TRUE(whole.Lookup(i, params.data(), &nll[0], grad[0].data()));
    ASSERT_TRUE(chunked.Lookup(i, params.data(), &nll[1], grad[1].data()));
    EXPECT_NEAR(nll[1], nll[0], 1e-12 * std::abs(nll[0])) << "transition " << i;
    for (int k = 0; k < packed; ++k) {
      EXPECT_NEAR(grad[1][k], grad[0][k], 1e-12 * std::max(1.0, std::abs(grad[0][k])))
          << "transition " << i << " entry " << k;
    }
  }
  const std::vector<double> values = chunked.Nll(), reference = whole.Nll();  // values only
  for (size_t i = 0; i < values.size(); ++i) EXPECT_NEAR(values[i], reference[i], 1e-12 * std::abs(reference[i]));
}

TEST_F(HumorTermTest, BatchedSolveFollowsTheSameSteps) {
  // The same problem with the batch as evaluation callback and with independent blocks takes the same
  // Levenberg-Marquardt steps (to round-off, which the iterations amplify: ~1e-12 after 12, ~1e-3 after 25).
  const body::BodyModel model = MakeTestModel();
  Eigen::Matrix3d R;
  Eigen::Vector3d t;
  GroundFrame(Eigen::Vector3d(0.0, 1.0, 0.0), 0.9, &R, &t);
  double final_cost[2];
  std::vector<double> final_body[2];
  for (int use_batch = 0; use_batch < 2; ++use_batch) {
    Sequence s = MakeSequence(model, 8, 3);
    HumorTransitionBatch batch(&model, prior_, 30.0, 2);
    batch.AddTrack(s.Blocks(s.transl), s.Blocks(s.root), s.Blocks(s.body), s.betas.data(), R, t);
    const std::vector<double> nll = batch.Nll();
    ceres::Problem::Options options;
    if (use_batch) options.evaluation_callback = &batch;
    ceres::Problem problem(options);
    for (int i = 0; i < batch.num_transitions(); ++i) {
      ceres::CostFunction* cost = use_batch ? static_cast<ceres::CostFunction*>(new HumorTransitionCost(&batch, i, 0.1, nll[i] - 100.0))
                                            : new HumorTransitionCost(&model, prior_, 30.0, R, t, 0.1, nll[i] - 100.0);
      problem.AddResidualBlock(cost, nullptr, batch.Parameters(i));
    }
    problem.SetParameterBlockConstant(s.betas.data());
    ceres::Solver::Options solver;
    solver.max_num_iterations = 12;  // the first steps are rejected (a rank-one model of a 100-nat drop)
    solver.linear_solver_type = ceres::DENSE_QR;
    ceres::Solver::Summary summary;
    ceres::Solve(solver, &problem, &summary);
    EXPECT_LT(summary.final_cost, summary.initial_cost) << summary.FullReport();
    final_cost[use_batch] = summary.final_cost;
    final_body[use_batch] = s.body[4];
  }
  EXPECT_NEAR(final_cost[1], final_cost[0], 1e-9 * final_cost[0]);
  for (size_t i = 0; i < final_body[0].size(); ++i) EXPECT_NEAR(final_body[1][i], final_body[0][i], 1e-8);
}

}  // namespace
}  // namespace m3c::motion
