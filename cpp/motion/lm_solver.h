// Levenberg-Marquardt over a ceres::Problem: the iteration of Ceres 2.1's TRUST_REGION / LEVENBERG_MARQUARDT /
// SPARSE_NORMAL_CHOLESKY with Jacobi scaling and its default tolerances (trust region radius and its updates,
// the clamped LM diagonal, step quality, the function, gradient and parameter tolerances), step for step, with
// the normal equations formed differently. Why: in the world optimizer's joint-smoothness stage Ceres spent a
// third of its time forming J^T J one pair of parameter blocks at a time (3 x 3 blocks here, 1.15 M pairs per
// person and iteration) and formed it again after every rejected step. Here each residual block's J^T J is one
// dense product over its row of the Jacobian, added into the normal matrix through precomputed offsets, and it
// is kept across rejected steps. The linear algebra is CHOLMOD's, as in Ceres: a fill-reducing order of the
// parameter blocks (AMD), then the supernodal factorization of J^T J + D^2 in that order.
//
// Takes problems without parameter bounds, manifolds or loss functions (the world optimizer's terms put their
// robustness into their residuals); LmUnsupported says why another cannot be taken.
#pragma once
#include <string>
#include <vector>
#include <ceres/ceres.h>

namespace m3c::motion {

struct LmOptions {
  int max_iterations = 50;
  int num_threads = 1;  // threads of the residual and Jacobian evaluation
  // The problem's evaluation callback (a ceres::Problem does not give its own back), called as Ceres calls it.
  ceres::EvaluationCallback* evaluation_callback = nullptr;
  std::vector<ceres::IterationCallback*> callbacks;  // after every iteration, as Ceres's
  // Ceres 2.1's defaults (ceres::Solver::Options).
  double initial_trust_region_radius = 1e4, max_trust_region_radius = 1e16, min_trust_region_radius = 1e-32;
  double min_lm_diagonal = 1e-6, max_lm_diagonal = 1e32;
  double min_relative_decrease = 1e-3;
  double function_tolerance = 1e-6, gradient_tolerance = 1e-10, parameter_tolerance = 1e-8;
  int max_num_consecutive_invalid_steps = 5;
};

// Empty when SolveLm can take the problem; otherwise what it cannot take (a bound, a manifold, a loss function).
std::string LmUnsupported(const ceres::Problem& problem);

// Minimises the problem's cost over its non-constant parameter blocks, in place. The summary is filled as
// ceres::Solve fills it: initial and final cost (with the cost of the blocks that read only constant
// parameters), one IterationSummary per iteration (iteration 0 the start), termination type and message.
void SolveLm(const LmOptions& options, ceres::Problem* problem, ceres::Solver::Summary* summary);

}  // namespace m3c::motion
