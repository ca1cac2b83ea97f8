// Plane fitting: total least squares, optionally inside RANSAC, with a minimum-support rule.
//
// Total least squares minimises sum_i (n . (x_i - c))^2 over unit n: c is the centroid and n the right singular
// vector of the centred points with the smallest singular value (here: the eigenvector of their 3x3 scatter matrix
// with the smallest eigenvalue, the same vector). Robust mode scores random 3-point planes with the truncated
// quadratic sum_i min(d_i^2, t^2) (MSAC), then refits by total least squares on the inliers (|d| <= t) until the
// inlier set stops changing.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "ground/types.h"

namespace m3c::ground {

struct PlaneFitOptions {
  bool robust = true;             // RANSAC (MSAC scoring) + total least squares refit on the inliers
  double inlier_threshold = 0.02;  // metres: |signed distance| <= threshold is an inlier (robust mode)
  int min_support = 20;           // fewer points (robust: inliers) than this -> no plane
  int max_iterations = 1000;      // RANSAC samples at most; fewer once `confidence` is reached
  double confidence = 0.999;      // probability of drawing at least one all-inlier sample
  uint64_t seed = 0;              // RANSAC sampling is deterministic for a given seed
};

enum class PlaneFitStatus { kOk, kTooFewPoints, kDegenerate, kTooFewInliers };

struct PlaneFit {
  PlaneFitStatus status = PlaneFitStatus::kTooFewPoints;
  Plane plane;                   // valid when status == kOk
  std::vector<uint8_t> inliers;  // per point (all 1 without robust mode)
  int num_inliers = 0;
  double rms = 0.0;              // root mean square distance of the inliers to the plane, metres

  bool ok() const { return status == PlaneFitStatus::kOk; }
};

// Checks the options; throws std::invalid_argument naming the bad field.
void ValidatePlaneFitOptions(const PlaneFitOptions& options);

// Fits a plane to `points`; `up` (any length > 0, in the points' frame) only chooses the normal's sign:
// normal . up >= 0. Too little support or (near-)collinear points give a status other than kOk, not an exception;
// invalid arguments (non-finite points, zero up vector, bad options) throw std::invalid_argument.
PlaneFit FitPlane(const PointsRef& points, const Eigen::Vector3d& up, const PlaneFitOptions& options = {});

// A sentence explaining a failed fit, for error messages.
std::string DescribeFailure(const PlaneFit& fit, int num_points, const PlaneFitOptions& options);

}  // namespace m3c::ground
