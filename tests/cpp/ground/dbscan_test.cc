#include "ground/dbscan.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace m3c::ground {
namespace {

// Textbook DBSCAN with O(n^2) neighbourhoods and scikit-learn's expansion order (clusters seeded from core points
// in index order, depth-first, points never relabelled): the reference the grid version must match exactly.
std::vector<int> BruteForceDbscan(const Points3& x, double eps, int min_samples, std::vector<uint8_t>* is_core) {
  const int n = static_cast<int>(x.rows());
  std::vector<std::vector<int>> nbrs(n);
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      if ((x.row(i) - x.row(j)).squaredNorm() <= eps * eps) nbrs[i].push_back(j);
    }
  }
  is_core->assign(n, 0);
  for (int i = 0; i < n; ++i) (*is_core)[i] = static_cast<int>(nbrs[i].size()) >= min_samples;
  std::vector<int> labels(n, -1);
  int next = 0;
  for (int i = 0; i < n; ++i) {
    if (labels[i] != -1 || !(*is_core)[i]) continue;
    std::vector<int> stack{i};
    while (!stack.empty()) {
      const int p = stack.back();
      stack.pop_back();
      if (labels[p] != -1) continue;
      labels[p] = next;
      if (!(*is_core)[p]) continue;
      for (int q : nbrs[p]) {
        if (labels[q] == -1) stack.push_back(q);
      }
    }
    ++next;
  }
  return labels;
}

// Blobs of `per_blob` points around random centres, plus uniform background and exact duplicates.
Points3 MakeCloud(int blobs, int per_blob, int background, int duplicates, double spread, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> normal(0.0, spread);
  std::uniform_real_distribution<double> uniform(-2.0, 2.0);
  Points3 x(blobs * per_blob + background + duplicates, 3);
  int row = 0;
  for (int b = 0; b < blobs; ++b) {
    const Eigen::RowVector3d centre(uniform(rng), uniform(rng), uniform(rng));
    for (int i = 0; i < per_blob; ++i, ++row) {
      x.row(row) = centre + Eigen::RowVector3d(normal(rng), normal(rng), normal(rng));
    }
  }
  for (int i = 0; i < background; ++i, ++row) {
    x.row(row) = Eigen::RowVector3d(uniform(rng), uniform(rng), uniform(rng));
  }
  std::uniform_int_distribution<int> pick(0, std::max(row - 1, 0));
  for (int i = 0; i < duplicates; ++i, ++row) x.row(row) = x.row(pick(rng));
  return x;
}

void ExpectSameAsBruteForce(const Points3& x, double eps, int min_samples) {
  std::vector<uint8_t> ref_core;
  const std::vector<int> ref = BruteForceDbscan(x, eps, min_samples, &ref_core);
  const DbscanResult got = Dbscan(x, eps, min_samples);
  ASSERT_EQ(got.labels.size(), ref.size());
  int mismatches = 0;
  for (size_t i = 0; i < ref.size(); ++i) mismatches += got.labels[i] != ref[i] || got.is_core[i] != ref_core[i];
  EXPECT_EQ(mismatches, 0) << "eps " << eps << " min_samples " << min_samples << " n " << x.rows();
  int ref_clusters = 0;
  for (int l : ref) ref_clusters = std::max(ref_clusters, l + 1);
  EXPECT_EQ(got.num_clusters, ref_clusters);
}

TEST(Dbscan, MatchesBruteForceOnClusteredClouds) {
  for (unsigned seed = 0; seed < 6; ++seed) {
    const Points3 x = MakeCloud(4, 150, 200, 30, 0.08, seed);
    for (double eps : {0.03, 0.1, 0.25}) {
      for (int min_samples : {1, 2, 5, 12}) ExpectSameAsBruteForce(x, eps, min_samples);
    }
  }
}

TEST(Dbscan, MatchesBruteForceOnUniformClouds) {
  for (unsigned seed = 10; seed < 14; ++seed) {
    const Points3 x = MakeCloud(0, 0, 800, 50, 0.0, seed);
    for (double eps : {0.1, 0.3, 0.5}) {
      for (int min_samples : {3, 8}) ExpectSameAsBruteForce(x, eps, min_samples);
    }
  }
}

TEST(Dbscan, DistanceExactlyEpsIsANeighbour) {
  // Integer lattice: squared distances are exact, so neighbours at distance exactly eps must count.
  Points3 x(27, 3);
  int row = 0;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      for (int k = 0; k < 3; ++k) x.row(row++) = Eigen::RowVector3d(i, j, k);
  const DbscanResult got = Dbscan(x, 1.0, 7);  // only the centre (1,1,1) has 6 axis neighbours + itself
  int cores = 0;
  for (uint8_t c : got.is_core) cores += c;
  EXPECT_EQ(cores, 1);
  EXPECT_TRUE(got.is_core[13]);
  ExpectSameAsBruteForce(x, 1.0, 7);
  ExpectSameAsBruteForce(x, 1.0, 4);
}

TEST(Dbscan, BorderPointJoinsTheClusterSeededFirst) {
  // Two clusters on a line and one border point between them, within eps of a core of each.
  auto scene = [](bool b_first) {
    Points3 x(9, 3);
    const double a[4] = {0.0, 0.02, 0.04, 0.06}, b[4] = {0.54, 0.56, 0.58, 0.60};
    for (int i = 0; i < 4; ++i) {
      x.row(i) = Eigen::RowVector3d(b_first ? b[i] : a[i], 0, 0);
      x.row(4 + i) = Eigen::RowVector3d(b_first ? a[i] : b[i], 0, 0);
    }
    x.row(8) = Eigen::RowVector3d(0.30, 0, 0);
    return x;
  };
  for (bool b_first : {false, true}) {
    const DbscanResult got = Dbscan(scene(b_first), 0.25, 4);
    EXPECT_EQ(got.num_clusters, 2);
    EXPECT_FALSE(got.is_core[8]);
    EXPECT_EQ(got.labels[8], 0) << "the border point belongs to the cluster holding point 0";
    EXPECT_EQ(got.labels[0], 0);
    EXPECT_EQ(got.labels[4], 1);
    ExpectSameAsBruteForce(scene(b_first), 0.25, 4);
  }
}

TEST(Dbscan, EmptyAndSinglePoint) {
  EXPECT_TRUE(Dbscan(Points3(0, 3), 0.1, 5).labels.empty());
  const DbscanResult one = Dbscan(Points3::Zero(1, 3), 0.1, 1);
  EXPECT_EQ(one.labels, std::vector<int>{0});
  EXPECT_EQ(Dbscan(Points3::Zero(1, 3), 0.1, 2).labels, std::vector<int>{-1});
}

TEST(Dbscan, FarFromOriginAndNegativeCoordinates) {
  Points3 x = MakeCloud(3, 100, 100, 10, 0.05, 3);
  x.rowwise() += Eigen::RowVector3d(-1.0e4, 2.0e4, -3.5e3);
  ExpectSameAsBruteForce(x, 0.1, 5);
}

TEST(Dbscan, RejectsBadInput) {
  Points3 x = MakeCloud(1, 20, 0, 0, 0.1, 0);
  EXPECT_THROW(Dbscan(x, 0.0, 5), std::invalid_argument);
  EXPECT_THROW(Dbscan(x, -1.0, 5), std::invalid_argument);
  EXPECT_THROW(Dbscan(x, std::numeric_limits<double>::infinity(), 5), std::invalid_argument);
  EXPECT_THROW(Dbscan(x, 0.1, 0), std::invalid_argument);
  x(7, 1) = std::numeric_limits<double>::quiet_NaN();
  try {
    Dbscan(x, 0.1, 5);
    FAIL() << "NaN accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("points[7]"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace m3c::ground
