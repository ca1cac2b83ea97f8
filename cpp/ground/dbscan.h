// DBSCAN (Ester et al. 1996) on 3D points with a uniform-grid index.
//
// Semantics (identical to scikit-learn's DBSCAN with the Euclidean metric):
//  - the eps-neighbourhood of a point holds every point at distance <= eps, the point itself included;
//  - a point is core when its neighbourhood holds >= min_samples points;
//  - clusters are the connected components of core points (two cores are linked when within eps);
//  - a non-core point within eps of at least one core point is a border point, otherwise noise (label -1).
// Border rule: a border point reachable from several clusters joins the one with the smallest id, and cluster ids
// are numbered 0, 1, ... in the order of each cluster's lowest-index core point. This is exactly what
// scikit-learn's depth-first expansion produces (it seeds clusters from core points in index order and never
// relabels a point), so the labels equal scikit-learn's, not merely up to a permutation.
//
// Cost: sorting points into cells of side eps/sqrt(3) is O(n log n); a cell's points are all mutual neighbours,
// core tests stop as soon as min_samples neighbours are found, and clusters are unions of cells, so dense clouds
// cost about O(n log n + n * min_samples) rather than O(sum of neighbourhood sizes).
#pragma once

#include <cstdint>
#include <vector>

#include "ground/types.h"

namespace m3c::ground {

struct DbscanResult {
  std::vector<int> labels;       // per point: cluster id in [0, num_clusters) or -1 for noise
  std::vector<uint8_t> is_core;  // per point: 1 for core points
  int num_clusters = 0;
};

// eps in the points' unit (metres), > 0; min_samples >= 1 counts the point itself. Throws std::invalid_argument
// on non-finite points or parameters.
DbscanResult Dbscan(const PointsRef& points, double eps, int min_samples);

}  // namespace m3c::ground
