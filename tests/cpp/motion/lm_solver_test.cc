#include "motion/lm_solver.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace m3c::motion {
namespace {

// A test problem shaped like the world optimizer's: a chain of 3-vectors (the frames) coupled to their
// neighbours and to one shared block (the shape), a block held constant, a residual block that reads only the
// constant (Ceres's fixed cost), and terms that read values an evaluation callback prepares (the shared
// joints): a solver that calls the callback at the wrong time evaluates those terms at stale values.
constexpr int kBlocks = 40;

struct Chain {
  double a, b;
  template <typename T>
  bool operator()(const T* x, const T* y, const T* g, T* r) const {
    r[0] = x[0] * exp(0.2 * y[1]) + g[0] - a;
    r[1] = sin(x[1]) * y[2] + g[1] * x[2] - b;
    r[2] = 10.0 * (x[2] - y[0] * y[0]);  // Rosenbrock's valley: rejected steps on the way
    return true;
  }
};

struct Stencil {
  template <typename T>
  bool operator()(const T* x, const T* y, const T* z, T* r) const {
    for (int i = 0; i < 3; ++i) r[i] = 0.5 * (x[i] - 2.0 * y[i] + z[i]);
    return true;
  }
};

struct Prior {
  double mu[3];
  template <typename T>
  bool operator()(const T* x, T* r) const {
    for (int i = 0; i < 3; ++i) r[i] = 0.1 * (x[i] - mu[i]);
    return true;
  }
};

struct ScaledByConstant {
  template <typename T>
  bool operator()(const T* x, const T* c, T* r) const {
    r[0] = x[0] * c[0] - 1.0;
    return true;
  }
};

struct ConstantOnly {
  template <typename T>
  bool operator()(const T* c, T* r) const {
    r[0] = c[0] - 2.0;
    return true;
  }
};

// sin(x0 + x1) of every block, prepared per evaluation point; with Jacobians, also its derivative.
class SineCache : public ceres::EvaluationCallback {
 public:
  explicit SineCache(std::vector<double*> blocks) : blocks_(std::move(blocks)), value_(blocks_.size()),
                                                      slope_(blocks_.size()) {}
  void PrepareForEvaluation(bool jacobians, bool new_point) override {
    ++calls;
    if (jacobians) ++jacobian_calls;
    if (!new_point && !jacobians) ++needless_calls;
    for (size_t i = 0; i < blocks_.size(); ++i) {
      value_[i] = std::sin(blocks_[i][0] + blocks_[i][1]);
      slope_[i] = jacobians ? std::cos(blocks_[i][0] + blocks_[i][1]) : std::nan("");
    }
  }
  double value(int i) const { return value_[i]; }
  double slope(int i) const { return slope_[i]; }
  int calls = 0, jacobian_calls = 0, needless_calls = 0;

 private:
  std::vector<double*> blocks_;
  std::vector<double> value_, slope_;
};

class CachedSine : public ceres::SizedCostFunction<1, 3> {
 public:
  CachedSine(const SineCache* cache, int index, double target) : cache_(cache), index_(index), target_(target) {}
  bool Evaluate(double const* const* /*parameters*/, double* residuals, double** jacobians) const override {
    residuals[0] = 2.0 * (cache_->value(index_) - target_);
    if (jacobians && jacobians[0]) {
      const double d = 2.0 * cache_->slope(index_);
      jacobians[0][0] = d;
      jacobians[0][1] = d;
      jacobians[0][2] = 0.0;
    }
    return true;
  }

 private:
  const SineCache* cache_;
  int index_;
  double target_;
};

// Fails (as a cost function may, e.g. behind the camera) where the first coordinate of its block exceeds a limit.
class Fails : public ceres::SizedCostFunction<1, 3> {
 public:
  explicit Fails(double limit) : limit_(limit) {}
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    if (parameters[0][0] > limit_) return false;
    residuals[0] = 0.3 * parameters[0][0];
    if (jacobians && jacobians[0]) {
      jacobians[0][0] = 0.3;
      jacobians[0][1] = jacobians[0][2] = 0.0;
    }
    return true;
  }

 private:
  double limit_;
};

struct Setup {
  std::vector<std::vector<double>> x;
  std::vector<double> g = {0.5, -0.3}, c = {1.7};
  std::unique_ptr<SineCache> cache;
  std::unique_ptr<ceres::Problem> problem;
};

// The problem over its own copy of the parameters (the same start every time).
std::unique_ptr<Setup> MakeProblem(unsigned seed, double fails_above = 1e300) {
  auto s = std::make_unique<Setup>();
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  s->x.resize(kBlocks);
  for (auto& block : s->x) block = {2.0 * normal(rng), 2.0 * normal(rng), 2.0 * normal(rng)};
  std::vector<double*> blocks;
  for (auto& block : s->x) blocks.push_back(block.data());
  s->cache = std::make_unique<SineCache>(blocks);
  ceres::Problem::Options options;
  options.evaluation_callback = s->cache.get();
  s->problem = std::make_unique<ceres::Problem>(options);
  ceres::Problem& p = *s->problem;
  for (int i = 0; i + 1 < kBlocks; ++i) {
    p.AddResidualBlock(new ceres::AutoDiffCostFunction<Chain, 3, 3, 3, 2>(new Chain{normal(rng), normal(rng)}),
                       nullptr, blocks[i], blocks[i + 1], s->g.data());
  }
  for (int i = 1; i + 1 < kBlocks; ++i) {
    p.AddResidualBlock(new ceres::AutoDiffCostFunction<Stencil, 3, 3, 3, 3>(new Stencil), nullptr, blocks[i - 1],
                       blocks[i], blocks[i + 1]);
  }
  for (int i = 0; i < kBlocks; ++i) {
    p.AddResidualBlock(new ceres::AutoDiffCostFunction<Prior, 3, 3>(new Prior{{normal(rng), normal(rng), 0.0}}),
                       nullptr, blocks[i]);
    if (i % 3 == 0) p.AddResidualBlock(new CachedSine(s->cache.get(), i, 0.4 * normal(rng)), nullptr, blocks[i]);
  }
  p.AddResidualBlock(new ceres::AutoDiffCostFunction<ScaledByConstant, 1, 3, 1>(new ScaledByConstant), nullptr,
                     blocks[5], s->c.data());
  p.AddResidualBlock(new ceres::AutoDiffCostFunction<ConstantOnly, 1, 1>(new ConstantOnly), nullptr, s->c.data());
  p.SetParameterBlockConstant(s->c.data());
  if (fails_above < 1e300) p.AddResidualBlock(new Fails(fails_above), nullptr, blocks[7]);
  return s;
}

void SolveWithCeres(Setup* s, int max_iterations, ceres::IterationCallback* callback, ceres::Solver::Summary* out) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  options.max_num_iterations = max_iterations;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  if (callback) options.callbacks.push_back(callback);
  ceres::Solve(options, s->problem.get(), out);
}

void SolveWithLm(Setup* s, int max_iterations, ceres::IterationCallback* callback, ceres::Solver::Summary* out,
                 int threads = 1) {
  LmOptions options;
  options.max_iterations = max_iterations;
  options.num_threads = threads;
  options.evaluation_callback = s->cache.get();
  if (callback) options.callbacks.push_back(callback);
  SolveLm(options, s->problem.get(), out);
}

// The same iterations as Ceres's, step for step, round-off apart: J^T J is summed in another order, and over
// 80 iterations of a slow tail the trust region's radius drifts by 1e-7 relative.
void ExpectSameRun(const ceres::Solver::Summary& ceres, const ceres::Solver::Summary& ours, const Setup& a,
                   const Setup& b) {
  EXPECT_EQ(ours.termination_type, ceres.termination_type) << ours.message << " / " << ceres.message;
  EXPECT_NEAR(ours.fixed_cost, ceres.fixed_cost, 1e-12);
  EXPECT_NEAR(ours.initial_cost, ceres.initial_cost, 1e-10 * ceres.initial_cost);
  EXPECT_NEAR(ours.final_cost, ceres.final_cost, 1e-8 * ceres.final_cost);
  EXPECT_EQ(ours.num_successful_steps, ceres.num_successful_steps);
  EXPECT_EQ(ours.num_unsuccessful_steps, ceres.num_unsuccessful_steps);
  ASSERT_EQ(ours.iterations.size(), ceres.iterations.size());
  for (size_t i = 0; i < ceres.iterations.size(); ++i) {
    const ceres::IterationSummary &c = ceres.iterations[i], &o = ours.iterations[i];
    EXPECT_EQ(o.iteration, c.iteration);
    EXPECT_EQ(o.step_is_successful, c.step_is_successful) << "iteration " << i;
    EXPECT_EQ(o.step_is_valid, c.step_is_valid) << "iteration " << i;
    EXPECT_NEAR(o.cost, c.cost, 1e-8 * c.cost) << "iteration " << i;
    EXPECT_NEAR(o.trust_region_radius, c.trust_region_radius, 1e-5 * c.trust_region_radius) << "iteration " << i;
    EXPECT_NEAR(o.gradient_max_norm, c.gradient_max_norm, 1e-5 * c.gradient_max_norm + 1e-12) << "iteration " << i;
    EXPECT_NEAR(o.step_norm, c.step_norm, 1e-5 * c.step_norm + 1e-12) << "iteration " << i;
    if (c.step_is_valid && i > 0) {
      EXPECT_NEAR(o.relative_decrease, c.relative_decrease, 1e-6 * std::abs(c.relative_decrease) + 1e-9)
          << "iteration " << i;
    }
  }
  for (int i = 0; i < kBlocks; ++i) {
    for (int k = 0; k < 3; ++k) EXPECT_NEAR(b.x[i][k], a.x[i][k], 1e-7) << "block " << i << " value " << k;
  }
  EXPECT_NEAR(b.g[0], a.g[0], 1e-7);
  EXPECT_NEAR(b.g[1], a.g[1], 1e-7);
  EXPECT_EQ(b.c[0], 1.7);  // constant
}

TEST(LmSolver, TakesCeresStepsToTheSameCosts) {
  for (unsigned seed : {1u, 2u, 3u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    auto a = MakeProblem(seed), b = MakeProblem(seed);
    ceres::Solver::Summary ceres, ours;
    SolveWithCeres(a.get(), 100, nullptr, &ceres);
    SolveWithLm(b.get(), 100, nullptr, &ours);
    EXPECT_GT(ceres.num_unsuccessful_steps, 0) << "the test problem must exercise rejected steps";
    EXPECT_GT(ceres.iterations.size(), 10u);
    EXPECT_GT(ceres.fixed_cost, 0.0);
    ExpectSameRun(ceres, ours, *a, *b);
    EXPECT_EQ(b->cache->needless_calls, 0);
    EXPECT_EQ(b->cache->calls, a->cache->calls);  // the callback as often as Ceres calls it
    EXPECT_EQ(b->cache->jacobian_calls, a->cache->jacobian_calls);
  }
}

TEST(LmSolver, IterationCapAndThreads) {
  auto a = MakeProblem(4), b = MakeProblem(4), c = MakeProblem(4);
  ceres::Solver::Summary ceres, ours, threaded;
  SolveWithCeres(a.get(), 7, nullptr, &ceres);
  SolveWithLm(b.get(), 7, nullptr, &ours);
  SolveWithLm(c.get(), 7, nullptr, &threaded, 3);
  EXPECT_EQ(ceres.termination_type, ceres::NO_CONVERGENCE);
  EXPECT_EQ(ours.iterations.size(), 8u);  // iteration 0, the start, and 7
  ExpectSameRun(ceres, ours, *a, *b);
  ExpectSameRun(ceres, threaded, *a, *c);  // evaluated on several threads: the same sums, in order
}

// A cost function that fails at a candidate: the step counts as one with infinite cost (rejected).
TEST(LmSolver, FailedEvaluationRejectsTheStep) {
  auto a = MakeProblem(5, 0.2), b = MakeProblem(5, 0.2);
  a->x[7][0] = b->x[7][0] = 0.0;
  ceres::Solver::Summary ceres, ours;
  SolveWithCeres(a.get(), 60, nullptr, &ceres);
  SolveWithLm(b.get(), 60, nullptr, &ours);
  const bool failed_once = std::any_of(ceres.iterations.begin(), ceres.iterations.end(),
                                       [](const ceres::IterationSummary& i) { return i.cost > 1e300; });
  EXPECT_TRUE(failed_once) << "the test must step where the cost function fails";
  ExpectSameRun(ceres, ours, *a, *b);
  EXPECT_LE(b->x[7][0], 0.2);
}

// At a start where a cost function fails, neither solves: FAILURE, and the parameters are left as they were.
TEST(LmSolver, FailureAtTheStartLeavesTheParameters) {
  auto a = MakeProblem(6, 0.2), b = MakeProblem(6, 0.2);
  a->x[7][0] = b->x[7][0] = 0.5;
  const std::vector<std::vector<double>> start = b->x;
  ceres::Solver::Summary ceres, ours;
  SolveWithCeres(a.get(), 20, nullptr, &ceres);
  SolveWithLm(b.get(), 20, nullptr, &ours);
  EXPECT_EQ(ceres.termination_type, ceres::FAILURE);
  EXPECT_EQ(ours.termination_type, ceres::FAILURE);
  EXPECT_EQ(b->x, start);
}

// A callback that aborts: USER_FAILURE and the start restored; one that ends the solve: USER_SUCCESS, the point
// reached kept. Both as Ceres.
class StopAt : public ceres::IterationCallback {
 public:
  StopAt(int iteration, ceres::CallbackReturnType answer) : iteration_(iteration), answer_(answer) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& summary) override {
    return summary.iteration == iteration_ ? answer_ : ceres::SOLVER_CONTINUE;
  }

 private:
  int iteration_;
  ceres::CallbackReturnType answer_;
};

TEST(LmSolver, CallbacksStopAsCeres) {
  for (const auto answer : {ceres::SOLVER_ABORT, ceres::SOLVER_TERMINATE_SUCCESSFULLY}) {
    auto a = MakeProblem(7), b = MakeProblem(7);
    const std::vector<std::vector<double>> start = b->x;
    StopAt stop_a(3, answer), stop_b(3, answer);
    ceres::Solver::Summary ceres, ours;
    SolveWithCeres(a.get(), 50, &stop_a, &ceres);
    SolveWithLm(b.get(), 50, &stop_b, &ours);
    ExpectSameRun(ceres, ours, *a, *b);
    EXPECT_EQ(ours.iterations.size(), 4u);
    if (answer == ceres::SOLVER_ABORT) {
      EXPECT_EQ(ours.termination_type, ceres::USER_FAILURE);
      EXPECT_EQ(b->x, start);
    } else {
      EXPECT_EQ(ours.termination_type, ceres::USER_SUCCESS);
      EXPECT_NE(b->x, start);
    }
  }
}

// The same result every run: Problem::GetParameterBlocks orders blocks by address, and an order taken from it
// gave AMD other ties, and the results other round-off, from one run to the next.
TEST(LmSolver, TheSameResultEveryRun) {
  std::vector<std::vector<double>> first;
  std::vector<std::unique_ptr<char[]>> heap;  // other addresses for each run's blocks
  for (int run = 0; run < 6; ++run) {
    heap.emplace_back(new char[24 * run + 8]);
    auto s = MakeProblem(1);
    ceres::Solver::Summary ours;
    SolveWithLm(s.get(), 100, nullptr, &ours);
    if (run == 0) {
      first = s->x;
    } else {
      EXPECT_EQ(s->x, first) << "run " << run;
    }
  }
}

TEST(LmSolver, EveryBlockConstant) {
  auto s = MakeProblem(8);
  for (auto& block : s->x) s->problem->SetParameterBlockConstant(block.data());
  s->problem->SetParameterBlockConstant(s->g.data());
  ceres::Solver::Summary ours;
  SolveWithLm(s.get(), 10, nullptr, &ours);
  EXPECT_EQ(ours.termination_type, ceres::CONVERGENCE);
  EXPECT_GT(ours.fixed_cost, 0.0);
  EXPECT_EQ(ours.final_cost, ours.fixed_cost);
}

TEST(LmSolver, SaysWhatItCannotTake) {
  auto s = MakeProblem(9);
  EXPECT_EQ(LmUnsupported(*s->problem), "");
  s->problem->SetParameterLowerBound(s->g.data(), 1, -1.0);
  EXPECT_EQ(LmUnsupported(*s->problem), "a parameter has a bound");
  auto t = MakeProblem(9);
  t->problem->SetManifold(t->g.data(), new ceres::SubsetManifold(2, {0}));
  EXPECT_EQ(LmUnsupported(*t->problem), "a parameter block has a manifold");
  auto u = MakeProblem(9);
  u->problem->AddResidualBlock(new ceres::AutoDiffCostFunction<Prior, 3, 3>(new Prior{{0, 0, 0}}),
                               new ceres::HuberLoss(1.0), u->x[0].data());
  EXPECT_EQ(LmUnsupported(*u->problem), "a residual block has a loss function");
}

}  // namespace
}  // namespace m3c::motion
