#include "ground/plane_fit.h"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <random>
#include <sstream>

#include "util/check.h"

namespace m3c::ground {

namespace {

// Total least squares plane through the points with mask[i] != 0 (all points when mask is empty).
// Returns false when they span no plane (fewer than 3 distinct points, or all on a line).
bool TotalLeastSquares(const PointsRef& points, const std::vector<uint8_t>& mask, Plane* plane) {
  const int n = static_cast<int>(points.rows());
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  int count = 0;
  for (int i = 0; i < n; ++i) {
    if (mask.empty() || mask[i]) {
      centroid += points.row(i).transpose();
      ++count;
    }
  }
  if (count < 3) return false;
  centroid /= count;
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  for (int i = 0; i < n; ++i) {
    if (mask.empty() || mask[i]) {
      const Eigen::Vector3d r = points.row(i).transpose() - centroid;
      scatter.noalias() += r * r.transpose();
    }
  }
  // Eigenvalues of the scatter matrix are the squared singular values of the centred points, ascending.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(scatter);
  const Eigen::Vector3d lambda = eig.eigenvalues();
  // Second singular value below 1e-6 of the first: the points lie on a line and the normal is undefined.
  if (!(lambda(2) > 0.0) || lambda(1) <= 1e-12 * lambda(2)) return false;
  plane->normal = eig.eigenvectors().col(0).normalized();
  plane->offset = -plane->normal.dot(centroid);
  return true;
}

void OrientUp(const Eigen::Vector3d& up, Plane* plane) {
  if (plane->normal.dot(up) < 0.0) {
    plane->normal = -plane->normal;
    plane->offset = -plane->offset;
  }
}

// Inlier mask of `plane` and its count.
int Inliers(const PointsRef& points, const Plane& plane, double threshold, std::vector<uint8_t>* mask) {
  const int n = static_cast<int>(points.rows());
  mask->assign(n, 0);
  int count = 0;
  for (int i = 0; i < n; ++i) {
    if (std::abs(plane.SignedDistance(points.row(i).transpose())) <= threshold) {
      (*mask)[i] = 1;
      ++count;
    }
  }
  return count;
}

// Best MSAC plane through 3 sampled points; false when every sample was collinear.
bool RansacPlane(const PointsRef& points, const PlaneFitOptions& options, Plane* best) {
  const int n = static_cast<int>(points.rows());
  const double t2 = options.inlier_threshold * options.inlier_threshold;
  std::mt19937_64 rng(options.seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  double best_score = std::numeric_limits<double>::infinity();
  int needed = options.max_iterations;
  for (int iteration = 0; iteration < needed; ++iteration) {
    const int i = pick(rng);
    int j = pick(rng), k = pick(rng);
    while (j == i) j = pick(rng);
    while (k == i || k == j) k = pick(rng);
    const Eigen::Vector3d a = points.row(i), ab = points.row(j).transpose() - a, ac = points.row(k).transpose() - a;
    Eigen::Vector3d normal = ab.cross(ac);
    const double norm = normal.norm();
    if (!(norm > 1e-9 * ab.norm() * ac.norm())) continue;  // (nearly) collinear sample
    normal /= norm;
    const Plane candidate{normal, -normal.dot(a)};
    double score = 0.0;
    int inliers = 0;
    for (int p = 0; p < n; ++p) {
      const double d = candidate.SignedDistance(points.row(p).transpose());
      score += std::min(d * d, t2);
      inliers += d * d <= t2;
    }
    if (score < best_score) {
      best_score = score;
      *best = candidate;
      // Samples needed so that one is all-inlier with probability `confidence`, at this inlier ratio.
      const double w3 = std::pow(static_cast<double>(inliers) / n, 3);
      if (w3 >= 1.0) break;
      if (w3 > 0.0) {
        const double more = std::ceil(std::log(1.0 - options.confidence) / std::log(1.0 - w3));
        needed = static_cast<int>(std::min<double>(options.max_iterations, iteration + 1 + more));
      }
    }
  }
  return std::isfinite(best_score);
}

}  // namespace

void ValidatePlaneFitOptions(const PlaneFitOptions& options) {
  M3C_CHECK(options.min_support >= 3) << "min_support must be >= 3 (a plane needs 3 points), got "
                                      << options.min_support;
  if (options.robust) {
    M3C_CHECK(std::isfinite(options.inlier_threshold) && options.inlier_threshold > 0.0)
        << "inlier_threshold must be a positive, finite distance (metres), got " << options.inlier_threshold;
    M3C_CHECK(options.max_iterations >= 1) << "max_iterations must be >= 1, got " << options.max_iterations;
    M3C_CHECK(options.confidence > 0.0 && options.confidence < 1.0)
        << "confidence must be in (0, 1), got " << options.confidence;
  }
}

PlaneFit FitPlane(const PointsRef& points, const Eigen::Vector3d& up, const PlaneFitOptions& options) {
  ValidatePlaneFitOptions(options);
  M3C_CHECK(up.allFinite() && up.norm() > 0.0) << "up must be a finite, non-zero 3-vector, got (" << up.transpose()
                                               << ")";
  const int n = static_cast<int>(points.rows());
  for (int i = 0; i < n; ++i) {
    M3C_CHECK(points.row(i).allFinite()) << "points[" << i << "] = (" << points.row(i)
                                         << ") is not finite; drop NaN/inf points before fitting";
  }
  PlaneFit fit;
  if (n < options.min_support) {
    fit.status = PlaneFitStatus::kTooFewPoints;
    return fit;
  }
  Plane plane;
  if (!options.robust) {
    if (!TotalLeastSquares(points, {}, &plane)) {
      fit.status = PlaneFitStatus::kDegenerate;
      return fit;
    }
    fit.inliers.assign(n, 1);
    fit.num_inliers = n;
  } else {
    if (!RansacPlane(points, options, &plane)) {
      fit.status = PlaneFitStatus::kDegenerate;
      return fit;
    }
    fit.num_inliers = Inliers(points, plane, options.inlier_threshold, &fit.inliers);
    // Refit on the inliers until they stop changing (a few rounds; the count is capped against cycling).
    for (int round = 0; round < 10; ++round) {
      if (fit.num_inliers < options.min_support) {
        fit.status = PlaneFitStatus::kTooFewInliers;
        return fit;
      }
      if (!TotalLeastSquares(points, fit.inliers, &plane)) {
        fit.status = PlaneFitStatus::kDegenerate;
        return fit;
      }
      std::vector<uint8_t> refit_inliers;
      const int count = Inliers(points, plane, options.inlier_threshold, &refit_inliers);
      const bool unchanged = refit_inliers == fit.inliers;
      fit.inliers.swap(refit_inliers);
      fit.num_inliers = count;
      if (unchanged) break;
    }
    if (fit.num_inliers < options.min_support) {
      fit.status = PlaneFitStatus::kTooFewInliers;
      return fit;
    }
  }
  OrientUp(up, &plane);
  double sum2 = 0.0;
  for (int i = 0; i < n; ++i) {
    if (fit.inliers[i]) sum2 += std::pow(plane.SignedDistance(points.row(i).transpose()), 2);
  }
  fit.plane = plane;
  fit.rms = std::sqrt(sum2 / fit.num_inliers);
  fit.status = PlaneFitStatus::kOk;
  return fit;
}

std::string DescribeFailure(const PlaneFit& fit, int num_points, const PlaneFitOptions& options) {
  std::ostringstream s;
  switch (fit.status) {
    case PlaneFitStatus::kOk:
      s << "the plane fit succeeded";
      break;
    case PlaneFitStatus::kTooFewPoints:
      s << "got " << num_points << " points, fewer than min_support = " << options.min_support;
      break;
    case PlaneFitStatus::kDegenerate:
      s << "the points are (nearly) collinear or coincident, so they define no plane";
      break;
    case PlaneFitStatus::kTooFewInliers:
      s << "only " << fit.num_inliers << " of " << num_points << " points lie within inlier_threshold = "
        << options.inlier_threshold << " m of the best plane, fewer than min_support = " << options.min_support;
      break;
  }
  return s.str();
}

}  // namespace m3c::ground
