// Shared by the cost-function tests of the fit and motion areas: a small keypoint regressor, random parameter
// blocks of one posed body, and ceres::GradientChecker with its error log reported as a test failure.
#pragma once

#include <vector>

#include <Eigen/Sparse>
#include <ceres/gradient_checker.h>
#include <gtest/gtest.h>

#include "body/kinematics.h"
#include "test_model.h"

namespace m3c::body::testing {

// Three points: a vertex, a vertex average and a joint.
inline KeypointRegressor ThreePointRegressor(const BodyModel& model) {
  Eigen::SparseMatrix<double, Eigen::RowMajor> vw(3, model.num_vertices()), jw(3, model.num_joints());
  std::vector<Eigen::Triplet<double>> tv = {{0, 5, 1.0}, {1, 30, 0.5}, {1, 31, 0.5}};
  std::vector<Eigen::Triplet<double>> tj = {{2, 10, 1.0}};
  vw.setFromTriplets(tv.begin(), tv.end());
  jw.setFromTriplets(tj.begin(), tj.end());
  return KeypointRegressor(vw, jw);
}

// Random translation, root orientation, body pose and betas of one frame.
struct RandomPoseBlocks {
  std::vector<double> transl, root, body, betas;
  RandomPoseBlocks(const BodyModel& m, unsigned seed)
      : transl(RandomVector(3, 0.3, seed)),
        root(RandomVector(3, 0.4, seed + 1)),
        body(RandomVector(3 * (m.num_joints() - 1), 0.4, seed + 2)),
        betas(RandomVector(m.num_betas(), 1.0, seed + 3)) {}
};

inline bool CheckGradient(const ceres::CostFunction& cost, const std::vector<const double*>& params,
                          double precision = 1e-6) {
  ceres::NumericDiffOptions options;
  const std::vector<const ceres::Manifold*>* no_manifolds = nullptr;
  ceres::GradientChecker checker(&cost, no_manifolds, options);
  ceres::GradientChecker::ProbeResults results;
  const bool ok = checker.Probe(params.data(), precision, &results);
  if (!ok) ADD_FAILURE() << results.error_log;
  return ok;
}

}  // namespace m3c::body::testing
