#include "ground/dbscan.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include "util/check.h"

namespace m3c::ground {

namespace {

using CellKey = std::array<int64_t, 3>;

// Points sorted into cubic cells; a cell's points are contiguous and cells are sorted by (x, y, z) key.
struct Grid {
  std::vector<double> xyz;          // sorted points, 3 per point
  std::vector<int> original;        // sorted position -> input index
  std::vector<int> cell_begin;      // cell c holds sorted positions [cell_begin[c], cell_begin[c + 1])
  std::vector<CellKey> cell_key;
  std::vector<int> neighbor_begin;  // cell c's neighbour cells: neighbors[neighbor_begin[c] .. neighbor_begin[c+1])
  std::vector<int> neighbors;

  int num_cells() const { return static_cast<int>(cell_key.size()); }
  const double* point(int k) const { return &xyz[3 * static_cast<size_t>(k)]; }
};

uint64_t Mix(uint64_t x) {  // splitmix64 finaliser
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ULL;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

struct ColumnHash {
  size_t operator()(const std::pair<int64_t, int64_t>& c) const {
    return Mix(static_cast<uint64_t>(c.first) * 0x9e3779b97f4a7c15ULL ^ static_cast<uint64_t>(c.second));
  }
};

double SquaredDistance(const double* a, const double* b) {
  const double dx = a[0] - b[0], dy = a[1] - b[1], dz = a[2] - b[2];
  return dx * dx + dy * dy + dz * dz;
}

// Cells of side `side` with, for each cell, every other non-empty cell whose points can be within
// `reach_cells` cells along each axis.
Grid BuildGrid(const PointsRef& points, double side, int reach_cells) {
  const int n = static_cast<int>(points.rows());
  struct Entry {
    CellKey key;
    int index;
    bool operator<(const Entry& o) const { return key != o.key ? key < o.key : index < o.index; }
  };
  std::vector<Entry> entries(n);
  for (int i = 0; i < n; ++i) {
    entries[i].index = i;
    for (int a = 0; a < 3; ++a) {
      const double cell = std::floor(points(i, a) / side);
      // Beyond 2^52 cells the floor is no longer exact and keys could collide.
      M3C_CHECK(std::abs(cell) < 4.0e15) << "points[" << i << "] = (" << points(i, 0) << ", " << points(i, 1) << ", "
                                         << points(i, 2) << ") is too far from the origin for a grid of eps = "
                                         << side * std::sqrt(3.0) << "; shift the points or use a larger eps";
      entries[i].key[a] = static_cast<int64_t>(cell);
    }
  }
  std::sort(entries.begin(), entries.end());
  Grid g;
  g.original.resize(n);
  g.xyz.resize(3 * static_cast<size_t>(n));
  for (int k = 0; k < n; ++k) {
    const int i = entries[k].index;
    g.original[k] = i;
    for (int a = 0; a < 3; ++a) g.xyz[3 * static_cast<size_t>(k) + a] = points(i, a);
    if (k == 0 || entries[k].key != entries[k - 1].key) {
      g.cell_begin.push_back(k);
      g.cell_key.push_back(entries[k].key);
    }
  }
  g.cell_begin.push_back(n);

  // Cells sorted by (x, y, z) make each (x, y) column a contiguous run sorted by z.
  std::unordered_map<std::pair<int64_t, int64_t>, std::pair<int, int>, ColumnHash> columns;
  columns.reserve(g.cell_key.size());
  for (int c = 0; c < g.num_cells(); ++c) {
    auto [it, inserted] = columns.try_emplace({g.cell_key[c][0], g.cell_key[c][1]}, c, c + 1);
    if (!inserted) it->second.second = c + 1;
  }
  g.neighbor_begin.reserve(g.cell_key.size() + 1);
  for (int c = 0; c < g.num_cells(); ++c) {
    g.neighbor_begin.push_back(static_cast<int>(g.neighbors.size()));
    const CellKey& key = g.cell_key[c];
    for (int64_t dx = -reach_cells; dx <= reach_cells; ++dx) {
      for (int64_t dy = -reach_cells; dy <= reach_cells; ++dy) {
        auto it = columns.find({key[0] + dx, key[1] + dy});
        if (it == columns.end()) continue;
        const auto [first, last] = it->second;
        // First cell of the column with z >= key.z - reach.
        int lo = first, hi = last;
        while (lo < hi) {
          const int mid = lo + (hi - lo) / 2;
          if (g.cell_key[mid][2] < key[2] - reach_cells) {
            lo = mid + 1;
          } else {
            hi = mid;
          }
        }
        for (int d = lo; d < last && g.cell_key[d][2] <= key[2] + reach_cells; ++d) {
          if (d != c) g.neighbors.push_back(d);
        }
      }
    }
  }
  g.neighbor_begin.push_back(static_cast<int>(g.neighbors.size()));
  return g;
}

struct UnionFind {
  explicit UnionFind(int n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int Find(int a) {
    while (parent[a] != a) a = parent[a] = parent[parent[a]];
    return a;
  }
  void Unite(int a, int b) { parent[Find(a)] = Find(b); }
  std::vector<int> parent;
};

}  // namespace

DbscanResult Dbscan(const PointsRef& points, double eps, int min_samples) {
  M3C_CHECK(std::isfinite(eps) && eps > 0.0) << "eps must be a positive, finite distance (metres), got " << eps;
  M3C_CHECK(min_samples >= 1) << "min_samples must be >= 1 (it counts the point itself), got " << min_samples;
  M3C_CHECK(points.rows() < std::numeric_limits<int>::max()) << "at most 2^31 - 2 points, got " << points.rows();
  const int n = static_cast<int>(points.rows());
  for (int i = 0; i < n; ++i) {
    M3C_CHECK(points.row(i).allFinite()) << "points[" << i << "] = (" << points(i, 0) << ", " << points(i, 1) << ", "
                                         << points(i, 2) << ") is not finite; drop NaN/inf points before clustering";
  }
  DbscanResult result;
  result.labels.assign(n, -1);
  result.is_core.assign(n, 0);
  if (n == 0) return result;

  // Cell side eps/sqrt(3) (shrunk by 1e-9 against rounding) keeps every cell's diameter below eps, so all points in
  // a cell are mutual neighbours; a neighbour can then be at most 2 cells away along each axis.
  const double eps2 = eps * eps;
  const Grid g = BuildGrid(points, eps / std::sqrt(3.0) * (1.0 - 1e-9), 2);
  const int num_cells = g.num_cells();
  auto nbr_begin = [&](int c) { return g.neighbors.begin() + g.neighbor_begin[c]; };
  auto nbr_end = [&](int c) { return g.neighbors.begin() + g.neighbor_begin[c + 1]; };

  // 1. Core points: count neighbours only until min_samples is reached.
  std::vector<int> cell_of(n);
  std::vector<uint8_t> core(n, 0);
  for (int c = 0; c < num_cells; ++c) {
    const int size = g.cell_begin[c + 1] - g.cell_begin[c];
    for (int k = g.cell_begin[c]; k < g.cell_begin[c + 1]; ++k) {
      cell_of[k] = c;
      int count = size;
      for (auto d = nbr_begin(c); d != nbr_end(c) && count < min_samples; ++d) {
        for (int q = g.cell_begin[*d]; q < g.cell_begin[*d + 1]; ++q) {
          if (SquaredDistance(g.point(k), g.point(q)) <= eps2 && ++count >= min_samples) break;
        }
      }
      core[k] = count >= min_samples;
    }
  }
  // Core points of each cell, contiguous: cores[core_begin[c] .. core_begin[c + 1]).
  std::vector<int> core_begin(num_cells + 1, 0), cores;
  for (int c = 0; c < num_cells; ++c) {
    core_begin[c] = static_cast<int>(cores.size());
    for (int k = g.cell_begin[c]; k < g.cell_begin[c + 1]; ++k) {
      if (core[k]) cores.push_back(k);
    }
  }
  core_begin[num_cells] = static_cast<int>(cores.size());
  auto has_core = [&](int c) { return core_begin[c + 1] > core_begin[c]; };
  auto near_core_of = [&](int c, const double* x) {
    for (int j = core_begin[c]; j < core_begin[c + 1]; ++j) {
      if (SquaredDistance(x, g.point(cores[j])) <= eps2) return true;
    }
    return false;
  };

  // 2. Clusters: cores of one cell are linked; two cells are linked when any pair of their cores is within eps.
  UnionFind components(num_cells);
  for (int c = 0; c < num_cells; ++c) {
    if (!has_core(c)) continue;
    for (auto it = nbr_begin(c); it != nbr_end(c); ++it) {
      const int d = *it;
      if (d < c || !has_core(d) || components.Find(c) == components.Find(d)) continue;
      for (int j = core_begin[c]; j < core_begin[c + 1]; ++j) {
        if (near_core_of(d, g.point(cores[j]))) {
          components.Unite(c, d);
          break;
        }
      }
    }
  }

  // 3. Cluster ids in the order of each cluster's lowest-index core point (scikit-learn's seeding order).
  std::vector<int> sorted_pos(n);
  for (int k = 0; k < n; ++k) sorted_pos[g.original[k]] = k;
  std::vector<int> component_label(num_cells, -1);
  for (int i = 0; i < n; ++i) {
    const int k = sorted_pos[i];
    if (!core[k]) continue;
    int& label = component_label[components.Find(cell_of[k])];
    if (label < 0) label = result.num_clusters++;
    result.labels[i] = label;
    result.is_core[i] = 1;
  }
  auto cell_label = [&](int c) { return component_label[components.Find(c)]; };

  // 4. Border points join the smallest-id cluster with a core within eps; the rest stay noise.
  for (int k = 0; k < n; ++k) {
    if (core[k]) continue;
    const int c = cell_of[k];
    int best = has_core(c) ? cell_label(c) : std::numeric_limits<int>::max();
    for (auto it = nbr_begin(c); it != nbr_end(c); ++it) {
      const int d = *it;
      if (has_core(d) && cell_label(d) < best && near_core_of(d, g.point(k))) best = cell_label(d);
    }
    if (best != std::numeric_limits<int>::max()) result.labels[g.original[k]] = best;
  }
  return result;
}

}  // namespace m3c::ground
