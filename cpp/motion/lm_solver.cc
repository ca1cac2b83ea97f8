#include "motion/lm_solver.h"

#include <algorithm>
#include <chrono>
#include <climits>
#include <cstdint>
#include <cmath>
#include <limits>
#include <numeric>
#include <unordered_map>

#include <amd.h>
#include <cholmod.h>

#include "util/check.h"
#include "util/openmp_levels.h"

namespace m3c::motion {

namespace {

double Seconds() {
  return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

// A residual block that reads at least one free parameter block. Its Jacobian is evaluated as one dense
// row-major rows x width matrix over its free blocks, in the order of their columns in the normal matrix.
struct Row {
  const ceres::CostFunction* cost = nullptr;
  std::vector<double*> params;  // every parameter block, in the cost function's order
  std::vector<int> param;       // per free block (column order): its index in params
  std::vector<int> col;         // per free block: its first column in the normal matrix
  std::vector<int> local;       // per free block: its first column in the row's dense Jacobian
  std::vector<int> size;        // per free block: its size
  int rows = 0, width = 0;
  size_t residual = 0;  // its first residual in the stacked residuals
  size_t jacobian = 0;  // its first value in its chunk's Jacobian buffer
  size_t runs = 0;      // its first entry in run_ptr_: n + 1 of them for n free blocks
};

// The upper triangle (b >= a) of J^T J of one dense row-major rows x width Jacobian, added into g (width x width,
// row-major: row a holds the entries b >= a, which are column a's on and below the diagonal in the normal
// matrix's lower triangle). Exact zeros (a keypoint below the confidence threshold) are skipped. Built twice where
// the compiler can: for AVX2 with FMA, chosen at load, and for the baseline the rest of the build has.
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && defined(__linux__)
__attribute__((target_clones("arch=x86-64-v3", "default")))
#endif
void AddRowGram(const double* __restrict jacobian, int rows, int width, double* __restrict g) {
  int i = 0;
  // Four rows at a time: one pass over g instead of four, each entry summed in the same order as row by row.
  for (; i + 3 < rows; i += 4) {
    const double* r0 = jacobian + static_cast<size_t>(i) * width;
    const double *r1 = r0 + width, *r2 = r1 + width, *r3 = r2 + width;
    for (int a = 0; a < width; ++a) {
      const double v0 = r0[a], v1 = r1[a], v2 = r2[a], v3 = r3[a];
      if (v0 == 0.0 && v1 == 0.0 && v2 == 0.0 && v3 == 0.0) continue;
      double* ga = g + static_cast<size_t>(a) * width;
      for (int b = a; b < width; ++b) {
        double t = ga[b];
        t += v0 * r0[b];
        t += v1 * r1[b];
        t += v2 * r2[b];
        t += v3 * r3[b];
        ga[b] = t;
      }
    }
  }
  for (; i < rows; ++i) {
    const double* row = jacobian + static_cast<size_t>(i) * width;
    for (int a = 0; a < width; ++a) {
      const double v = row[a];
      if (v == 0.0) continue;
      double* ga = g + static_cast<size_t>(a) * width;
      for (int b = a; b < width; ++b) ga[b] += v * row[b];
    }
  }
}

class LmSolver {
 public:
  LmSolver(const LmOptions& options, ceres::Problem* problem) : options_(options), problem_(problem) {}
  ~LmSolver() {
    if (factor_) cholmod_free_factor(&factor_, &cc_);
    if (normal_) cholmod_free_sparse(&normal_, &cc_);
    if (rhs_) cholmod_free_dense(&rhs_, &cc_);
    if (started_) cholmod_finish(&cc_);
  }
  LmSolver(const LmSolver&) = delete;
  LmSolver& operator=(const LmSolver&) = delete;

  void Solve(ceres::Solver::Summary* summary);

 private:
  bool Setup(std::string* why);
  bool EvaluateCost(double* cost);
  bool Linearize(double* cost);
  bool ComputeStep(std::vector<double>* step);
  double ModelCostChange(const std::vector<double>& step) const;
  void Gather(std::vector<double>* x) const;
  void Scatter(const std::vector<double>& x) const;
  void Prepare(bool jacobians, bool new_point) const {
    if (options_.evaluation_callback) options_.evaluation_callback->PrepareForEvaluation(jacobians, new_point);
  }

  const LmOptions& options_;
  ceres::Problem* problem_;
  std::vector<double*> blocks_;  // free parameter blocks, in column order
  std::vector<int> block_size_;  // their sizes
  std::vector<int> block_col_;   // their first columns
  int n_ = 0;                    // columns
  std::vector<Row> rows_;
  std::vector<std::pair<const ceres::CostFunction*, std::vector<double*>>> fixed_;  // blocks of constants only
  size_t num_residuals_ = 0;
  // The rows are linearized a chunk at a time (evaluated in parallel, then added into J^T J in order), so that
  // no more than a chunk's Jacobian is held: chunk c is rows [chunks_[c], chunks_[c + 1]).
  std::vector<size_t> chunks_;
  std::vector<double> chunk_jacobian_;
  // Where a row's J^T J goes in block k's columns below the diagonal block: runs of the later blocks l > k that
  // lie next to each other both in the row and in the column, each copied as one span. Row r's runs for block k
  // are runs_[run_ptr_[r.runs + k] .. run_ptr_[r.runs + k + 1]).
  struct Run {
    int offset;             // rows into the column, after the diagonal block's part
    std::uint16_t local;    // first column in the row's dense Jacobian
    std::uint16_t length;
  };
  std::vector<Run> runs_;
  std::vector<size_t> run_ptr_;
  std::vector<int> diagonal_at_;     // per column, the position of its diagonal in the normal matrix
  std::vector<double> residuals_;    // at x
  std::vector<double> scratch_residuals_;  // at a candidate
  std::vector<double> scale_;        // Jacobi scaling per column (Ceres's: from the first Jacobian)
  std::vector<double> rhs_values_;   // J^T r of the scaled Jacobian
  std::vector<double> gram_diagonal_;  // diag(J^T J) of the scaled Jacobian
  std::vector<double> lm_diagonal_;    // clamped diag(J^T J), kept over rejected steps as Ceres keeps it
  double radius_ = 0.0, decrease_factor_ = 2.0;
  bool reuse_diagonal_ = false;
  std::string failure_;  // why the last step could not be computed

  cholmod_common cc_;
  bool started_ = false;
  // J^T J of the scaled Jacobian, lower triangle (CHOLMOD's own layout: no transpose per factorization), columns
  // in the fill-reducing order. Between steps it holds J^T J itself; a step adds D^2 to its diagonal.
  cholmod_sparse* normal_ = nullptr;
  cholmod_factor* factor_ = nullptr;
  cholmod_dense* rhs_ = nullptr;
};

bool LmSolver::Setup(std::string* why) {
  // The rows and the free blocks they read, each block numbered by the first row that reads it: the residual
  // blocks come in the order they were added, while Problem::GetParameterBlocks orders blocks by their address,
  // which would make AMD's ties, and so the round-off, differ from run to run. A free block that no row reads
  // stays as it is (Ceres drops it from the problem it solves).
  std::vector<ceres::ResidualBlockId> ids;
  problem_->GetResidualBlocks(&ids);
  std::unordered_map<const double*, int> id;  // free block -> its number
  std::vector<double*> free;
  std::vector<size_t> row_block_ptr = {0};
  // Per row, from row_block_ptr[r]: the numbers of its free blocks and their indices among its parameters.
  std::vector<int> row_block, row_param;
  for (const ceres::ResidualBlockId rid : ids) {
    Row row;
    row.cost = problem_->GetCostFunctionForResidualBlock(rid);
    problem_->GetParameterBlocksForResidualBlock(rid, &row.params);
    const size_t first = row_block.size();
    for (size_t q = 0; q < row.params.size(); ++q) {
      if (problem_->IsParameterBlockConstant(row.params[q])) continue;
      const auto [it, added] = id.emplace(row.params[q], static_cast<int>(free.size()));
      if (added) free.push_back(row.params[q]);
      row_block.push_back(it->second);
      row_param.push_back(static_cast<int>(q));
    }
    if (row_block.size() == first) {
      fixed_.emplace_back(row.cost, row.params);
      continue;
    }
    rows_.push_back(std::move(row));
    row_block_ptr.push_back(row_block.size());
  }
  const int nb = static_cast<int>(free.size());
  std::vector<int> size(nb);
  long long columns = 0;
  for (int b = 0; b < nb; ++b) {
    size[b] = problem_->ParameterBlockSize(free[b]);
    columns += size[b];
  }
  if (nb == 0) return true;

  // The blocks' graph (b ~ c when a row reads both), each edge once, as the strictly lower pattern of its
  // adjacency matrix: a marker per block, over the rows that read it.
  std::vector<size_t> block_row_ptr(nb + 1, 0);
  for (int b : row_block) ++block_row_ptr[b + 1];
  for (int b = 0; b < nb; ++b) block_row_ptr[b + 1] += block_row_ptr[b];
  std::vector<int> block_row(row_block.size());
  {
    std::vector<size_t> at(block_row_ptr.begin(), block_row_ptr.end() - 1);
    for (size_t r = 0; r + 1 < row_block_ptr.size(); ++r) {
      for (size_t e = row_block_ptr[r]; e < row_block_ptr[r + 1]; ++e) block_row[at[row_block[e]]++] = static_cast<int>(r);
    }
  }
  std::vector<int> marker(nb, -1);
  std::vector<int> graph_ptr(nb + 1, 0), graph;  // column b: the blocks c > b adjacent to b
  for (int b = 0; b < nb; ++b) {
    marker[b] = b;
    for (size_t e = block_row_ptr[b]; e < block_row_ptr[b + 1]; ++e) {
      const int r = block_row[e];
      for (size_t f = row_block_ptr[r]; f < row_block_ptr[r + 1]; ++f) {
        const int c = row_block[f];
        if (c > b && marker[c] != b) {
          marker[c] = b;
          graph.push_back(c);
        }
      }
    }
    if (graph.size() > static_cast<size_t>(INT_MAX)) {
      *why = "the problem couples too many parameter blocks for CHOLMOD's 32-bit indices";
      return false;
    }
    graph_ptr[b + 1] = static_cast<int>(graph.size());
  }
  std::vector<int>().swap(block_row);
  std::vector<size_t>().swap(block_row_ptr);

  // A fill-reducing order of the blocks: AMD on their graph, as Ceres orders its blocks for CHOLMOD.
  std::vector<int> order(nb);
  double control[AMD_CONTROL], info[AMD_INFO];
  amd_defaults(control);
  const int amd_status = amd_order(nb, graph_ptr.data(), graph.data(), order.data(), control, info);
  if (amd_status != AMD_OK && amd_status != AMD_OK_BUT_JUMBLED) {
    for (int b = 0; b < nb; ++b) order[b] = b;  // the natural order: slower, the same steps
  }
  std::vector<int> position(nb);
  for (int k = 0; k < nb; ++k) position[order[k]] = k;
  if (columns > INT_MAX) {
    *why = "the problem has too many parameters for CHOLMOD's 32-bit indices";
    return false;
  }
  blocks_.resize(nb);
  block_size_.resize(nb);
  block_col_.resize(nb);
  n_ = 0;
  for (int k = 0; k < nb; ++k) {
    blocks_[k] = free[order[k]];
    block_size_[k] = size[order[k]];
    block_col_[k] = n_;
    n_ += block_size_[k];
  }

  // The normal matrix's lower triangle: column block k holds its own diagonal block's rows on and below the
  // diagonal, then the row blocks j > k adjacent to it, in order (lower_ptr / lower); `below` counts the rows
  // of those before each.
  std::vector<int> lower_ptr(nb + 1, 0);
  for (int b = 0; b < nb; ++b) {
    for (int e = graph_ptr[b]; e < graph_ptr[b + 1]; ++e) ++lower_ptr[std::min(position[b], position[graph[e]]) + 1];
  }
  for (int k = 0; k < nb; ++k) lower_ptr[k + 1] += lower_ptr[k];
  std::vector<int> lower(graph.size());
  {
    std::vector<int> at(lower_ptr.begin(), lower_ptr.end() - 1);
    for (int b = 0; b < nb; ++b) {
      for (int e = graph_ptr[b]; e < graph_ptr[b + 1]; ++e) {
        const int u = position[b], v = position[graph[e]];
        lower[at[std::min(u, v)]++] = std::max(u, v);
      }
    }
  }
  std::vector<int>().swap(graph);
  std::vector<int>().swap(graph_ptr);
  std::vector<int> below(lower.size());
  long long nnz = 0;
  for (int k = 0; k < nb; ++k) {
    std::sort(lower.begin() + lower_ptr[k], lower.begin() + lower_ptr[k + 1]);
    int rows = 0;
    for (int e = lower_ptr[k]; e < lower_ptr[k + 1]; ++e) {
      below[e] = rows;
      rows += block_size_[lower[e]];
    }
    for (int q = 0; q < block_size_[k]; ++q) nnz += (block_size_[k] - q) + rows;
  }
  if (nnz > INT_MAX) {
    *why = "J^T J has too many entries for CHOLMOD's 32-bit indices";
    return false;
  }

  cholmod_start(&cc_);
  started_ = true;
  cc_.print = 0;
  cc_.nmethods = 1;
  cc_.method[0].ordering = CHOLMOD_NATURAL;  // the blocks are in AMD's order already
  cc_.postorder = 0;
  cc_.supernodal = CHOLMOD_AUTO;
  cc_.quick_return_if_not_posdef = 1;
  normal_ = cholmod_allocate_sparse(n_, n_, nnz, /*sorted=*/1, /*packed=*/1, /*stype=*/-1, CHOLMOD_REAL, &cc_);
  rhs_ = cholmod_allocate_dense(n_, 1, n_, CHOLMOD_REAL, &cc_);
  if (normal_ == nullptr || rhs_ == nullptr) {
    *why = "CHOLMOD could not allocate J^T J (" + std::to_string(nnz) + " entries)";
    return false;
  }
  auto* colptr = static_cast<int*>(normal_->p);
  auto* rowind = static_cast<int*>(normal_->i);
  diagonal_at_.resize(n_);
  int at = 0;
  for (int k = 0; k < nb; ++k) {
    for (int q = 0; q < block_size_[k]; ++q) {
      colptr[block_col_[k] + q] = at;
      diagonal_at_[block_col_[k] + q] = at;
      for (int r = q; r < block_size_[k]; ++r) rowind[at++] = block_col_[k] + r;
      for (int e = lower_ptr[k]; e < lower_ptr[k + 1]; ++e) {
        for (int r = 0; r < block_size_[lower[e]]; ++r) rowind[at++] = block_col_[lower[e]] + r;
      }
    }
  }
  colptr[n_] = at;

  // The rows: free blocks in column order, chunks, runs.
  constexpr size_t kChunkValues = size_t{1} << 19;  // 4 MiB of Jacobian per chunk
  size_t residual = 0, chunk_values = 0, largest_chunk = 0;
  chunks_.assign(1, 0);
  for (size_t r = 0; r < rows_.size(); ++r) {
    Row& row = rows_[r];
    std::vector<std::pair<int, int>> mine;  // (position, parameter index)
    for (size_t e = row_block_ptr[r]; e < row_block_ptr[r + 1]; ++e) {
      mine.emplace_back(position[row_block[e]], row_param[e]);
    }
    std::sort(mine.begin(), mine.end());
    row.rows = row.cost->num_residuals();
    row.width = 0;
    for (const auto& [k, q] : mine) {
      row.param.push_back(q);
      row.col.push_back(block_col_[k]);
      row.local.push_back(row.width);
      row.size.push_back(block_size_[k]);
      row.width += block_size_[k];
    }
    const size_t values = static_cast<size_t>(row.rows) * row.width;
    if (chunk_values > 0 && chunk_values + values > kChunkValues) {
      chunks_.push_back(r);
      chunk_values = 0;
    }
    row.jacobian = chunk_values;
    chunk_values += values;
    largest_chunk = std::max(largest_chunk, chunk_values);
    row.residual = residual;
    residual += row.rows;
    row.runs = run_ptr_.size();
    for (size_t k = 0; k < mine.size(); ++k) {
      run_ptr_.push_back(runs_.size());
      const int column = mine[k].first;
      for (size_t l = k + 1; l < mine.size(); ++l) {
        const auto e = std::lower_bound(lower.begin() + lower_ptr[column], lower.begin() + lower_ptr[column + 1],
                                        mine[l].first) - lower.begin();
        Run* last = runs_.size() > run_ptr_.back() ? &runs_.back() : nullptr;
        if (last && last->offset + last->length == below[e] && last->local + last->length == row.local[l] &&
            last->length + row.size[l] <= UINT16_MAX) {
          last->length = static_cast<std::uint16_t>(last->length + row.size[l]);
        } else {
          runs_.push_back({below[e], static_cast<std::uint16_t>(row.local[l]), static_cast<std::uint16_t>(row.size[l])});
        }
      }
    }
    run_ptr_.push_back(runs_.size());
  }
  chunks_.push_back(rows_.size());
  chunk_jacobian_.assign(largest_chunk, 0.0);
  num_residuals_ = residual;
  residuals_.assign(num_residuals_, 0.0);
  scratch_residuals_.assign(num_residuals_, 0.0);
  return true;
}

void LmSolver::Gather(std::vector<double>* x) const {
  x->resize(n_);
  for (size_t k = 0; k < blocks_.size(); ++k) {
    std::copy(blocks_[k], blocks_[k] + block_size_[k], x->data() + block_col_[k]);
  }
}

void LmSolver::Scatter(const std::vector<double>& x) const {
  for (size_t k = 0; k < blocks_.size(); ++k) {
    std::copy(x.data() + block_col_[k], x.data() + block_col_[k] + block_size_[k], blocks_[k]);
  }
}

// Half the squared residuals of rows [first, last) into cost[r - first]; with jacobians, their Jacobians into the
// chunk buffer. False when a cost function fails or returns a non-finite value (Ceres's evaluation fails then).
bool EvaluateRows(const std::vector<Row>& rows, size_t first, size_t last, int threads, double* residuals,
                  double* jacobian_buffer, std::vector<double>* cost) {
  const long count = static_cast<long>(last - first);
  cost->assign(count, 0.0);
  std::vector<char> ok(count, 1);
  const util::ScopedOpenMpLevels levels(threads > 1 ? 1 : 0);
#pragma omp parallel num_threads(threads)
  {
    std::vector<double> scratch;
    std::vector<double*> pointers;
#pragma omp for schedule(dynamic, 16)
    for (long e = 0; e < count; ++e) {
      const Row& row = rows[first + e];
      double* res = residuals + row.residual;
      if (!jacobian_buffer) {
        ok[e] = row.cost->Evaluate(row.params.data(), res, nullptr);
      } else {
        scratch.resize(static_cast<size_t>(row.rows) * row.width);
        pointers.assign(row.params.size(), nullptr);
        for (size_t k = 0; k < row.param.size(); ++k) pointers[row.param[k]] = scratch.data() + row.rows * row.local[k];
        ok[e] = row.cost->Evaluate(row.params.data(), res, pointers.data());
        double* out = jacobian_buffer + row.jacobian;
        for (size_t k = 0; ok[e] && k < row.param.size(); ++k) {  // per block r x s -> the row's r x width
          const double* in = scratch.data() + row.rows * row.local[k];
          const int s = row.size[k];
          for (int i = 0; i < row.rows; ++i) {
            std::copy(in + i * s, in + (i + 1) * s, out + static_cast<size_t>(i) * row.width + row.local[k]);
          }
        }
        for (size_t v = 0; ok[e] && v < scratch.size(); ++v) ok[e] = std::isfinite(scratch[v]);
      }
      double sum = 0.0;
      for (int i = 0; i < row.rows; ++i) sum += res[i] * res[i];
      if (!std::isfinite(sum)) ok[e] = 0;
      (*cost)[e] = 0.5 * sum;
    }
  }
  return std::all_of(ok.begin(), ok.end(), [](char c) { return c != 0; });
}

// The reduced cost (rows with a free block) at the parameters in the problem's memory.
bool LmSolver::EvaluateCost(double* cost) {
  std::vector<double> row_cost;
  if (!EvaluateRows(rows_, 0, rows_.size(), std::max(1, options_.num_threads), scratch_residuals_.data(), nullptr,
                    &row_cost)) {
    return false;
  }
  *cost = 0.0;
  for (double c : row_cost) *cost += c;
  return true;
}

// The cost, the residuals and the normal equations of the scaled Jacobian at the parameters in the problem's
// memory: J^T J into the normal matrix, J^T r, diag(J^T J). The Jacobi scaling is set from the first Jacobian's
// column norms (the unscaled diagonal), as Ceres sets it.
bool LmSolver::Linearize(double* cost) {
  auto* h = static_cast<double*>(normal_->x);
  const auto* colptr = static_cast<const int*>(normal_->p);
  std::fill(h, h + colptr[n_], 0.0);
  rhs_values_.assign(n_, 0.0);
  *cost = 0.0;
  std::vector<double> row_cost, g;
  for (size_t c = 0; c + 1 < chunks_.size(); ++c) {
    if (!EvaluateRows(rows_, chunks_[c], chunks_[c + 1], std::max(1, options_.num_threads), residuals_.data(),
                      chunk_jacobian_.data(), &row_cost)) {
      return false;
    }
    for (double v : row_cost) *cost += v;
    for (size_t r = chunks_[c]; r < chunks_[c + 1]; ++r) {
      const Row& row = rows_[r];
      const double* jac = chunk_jacobian_.data() + row.jacobian;
      const double* res = residuals_.data() + row.residual;
      const int w = row.width;
      g.assign(static_cast<size_t>(w) * (w + 1), 0.0);  // J^T J, then J^T r in the last row
      double* jtr = g.data() + static_cast<size_t>(w) * w;
      for (int i = 0; i < row.rows; ++i) {
        const double ri = res[i];
        const double* ji = jac + static_cast<size_t>(i) * w;
        for (int a = 0; a < w; ++a) jtr[a] += ji[a] * ri;
      }
      for (size_t k = 0; k < row.col.size(); ++k) {
        double* out = rhs_values_.data() + row.col[k];
        for (int t = 0; t < row.size[k]; ++t) out[t] += jtr[row.local[k] + t];
      }
      AddRowGram(jac, row.rows, w, g.data());
      // Column q of block k, on and below the diagonal: its own block's rows q.. first, then each later block's.
      const size_t blocks = row.col.size();
      for (size_t k = 0; k < blocks; ++k) {
        const int sk = row.size[k];
        for (int q = 0; q < sk; ++q) {
          double* column = h + colptr[row.col[k] + q];
          const double* from = g.data() + static_cast<size_t>(row.local[k] + q) * w;
          for (int t = q; t < sk; ++t) column[t - q] += from[row.local[k] + t];
          column += sk - q;
          for (size_t u = run_ptr_[row.runs + k]; u < run_ptr_[row.runs + k + 1]; ++u) {
            const Run& run = runs_[u];
            double* to = column + run.offset;
            const double* src = from + run.local;
            for (int t = 0; t < run.length; ++t) to[t] += src[t];
          }
        }
      }
    }
  }
  if (scale_.empty()) {
    scale_.resize(n_);
    for (int c = 0; c < n_; ++c) scale_[c] = 1.0 / (1.0 + std::sqrt(h[diagonal_at_[c]]));
  }
  const auto* rowind = static_cast<const int*>(normal_->i);
  for (int c = 0; c < n_; ++c) {
    for (int e = colptr[c]; e < colptr[c + 1]; ++e) h[e] *= scale_[rowind[e]] * scale_[c];
    rhs_values_[c] *= scale_[c];
  }
  gram_diagonal_.resize(n_);
  for (int c = 0; c < n_; ++c) gram_diagonal_[c] = h[diagonal_at_[c]];
  return true;
}

// The LM step of the scaled problem, Ceres's: (J^T J + D^2) y = J^T r, step = -y, D^2 = clamp(diag J^T J) / radius.
bool LmSolver::ComputeStep(std::vector<double>* step) {
  if (!reuse_diagonal_) {
    lm_diagonal_.resize(n_);
    for (int c = 0; c < n_; ++c) {
      lm_diagonal_[c] = std::min(std::max(gram_diagonal_[c], options_.min_lm_diagonal), options_.max_lm_diagonal);
    }
  }
  reuse_diagonal_ = true;
  auto* h = static_cast<double*>(normal_->x);
  for (int c = 0; c < n_; ++c) h[diagonal_at_[c]] = gram_diagonal_[c] + lm_diagonal_[c] / radius_;
  bool ok = true;
  {
    const util::ScopedOpenMpLevels serial(0);  // CHOLMOD's OpenMP teams: see util/openmp_levels.h
    if (!factor_) {
      factor_ = cholmod_analyze(normal_, &cc_);
      if (!factor_ || cc_.status != CHOLMOD_OK) {
        failure_ = "CHOLMOD's analysis failed (status " + std::to_string(cc_.status) + ")";
        ok = false;
      }
    }
    if (ok) {
      cholmod_factorize(normal_, factor_, &cc_);
      if (cc_.status != CHOLMOD_OK) {
        failure_ = "CHOLMOD's factorization failed (status " + std::to_string(cc_.status) +
                   (cc_.status == CHOLMOD_NOT_POSDEF ? ", not positive definite)" : ")");
        ok = false;
      }
    }
    if (ok) {
      std::copy(rhs_values_.begin(), rhs_values_.end(), static_cast<double*>(rhs_->x));
      cholmod_dense* y = cholmod_solve(CHOLMOD_A, factor_, rhs_, &cc_);
      if (!y || cc_.status != CHOLMOD_OK) {
        failure_ = "CHOLMOD's solve failed (status " + std::to_string(cc_.status) + ")";
        ok = false;
      } else {
        const auto* yv = static_cast<const double*>(y->x);
        step->resize(n_);
        for (int c = 0; c < n_; ++c) {
          (*step)[c] = -yv[c];
          ok = ok && std::isfinite(yv[c]);
        }
        if (!ok) failure_ = "the step is not finite";
      }
      if (y) cholmod_free_dense(&y, &cc_);
    }
  }
  for (int c = 0; c < n_; ++c) h[diagonal_at_[c]] = gram_diagonal_[c];
  return ok;
}

// Ceres's model cost change -(J step).(r + J step / 2) of the scaled problem, from the normal equations:
// -(step.J^T r + step^T J^T J step / 2).
double LmSolver::ModelCostChange(const std::vector<double>& step) const {
  const auto* h = static_cast<const double*>(normal_->x);
  const auto* colptr = static_cast<const int*>(normal_->p);
  const auto* rowind = static_cast<const int*>(normal_->i);
  double linear = 0.0, quadratic = 0.0;
  for (int c = 0; c < n_; ++c) {
    linear += step[c] * rhs_values_[c];
    double off = 0.0;
    for (int e = colptr[c] + 1; e < colptr[c + 1]; ++e) off += h[e] * step[rowind[e]];
    quadratic += step[c] * (h[colptr[c]] * step[c] + 2.0 * off);
  }
  return -(linear + 0.5 * quadratic);
}

void LmSolver::Solve(ceres::Solver::Summary* summary) {
  const double start = Seconds();
  *summary = ceres::Solver::Summary();
  summary->minimizer_type = ceres::TRUST_REGION;
  summary->trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  summary->linear_solver_type_given = summary->linear_solver_type_used = ceres::SPARSE_NORMAL_CHOLESKY;
  summary->fixed_cost = 0.0;  // Ceres's Summary starts its counts at -1 ("not run")
  summary->num_successful_steps = summary->num_unsuccessful_steps = 0;
  std::string why;
  if (!Setup(&why)) {
    summary->termination_type = ceres::FAILURE;
    summary->message = why + "; solve this problem with minimizer \"ceres\" or in shorter windows";
    return;
  }
  summary->num_parameter_blocks = problem_->NumParameterBlocks();
  summary->num_parameters = problem_->NumParameters();
  summary->num_residual_blocks = problem_->NumResidualBlocks();
  summary->num_residuals = problem_->NumResiduals();
  summary->num_parameter_blocks_reduced = static_cast<int>(blocks_.size());
  summary->num_parameters_reduced = summary->num_effective_parameters_reduced = n_;
  summary->num_residual_blocks_reduced = static_cast<int>(rows_.size());
  summary->num_residuals_reduced = static_cast<int>(num_residuals_);

  // The cost of the blocks that read constants only (Ceres's fixed cost).
  Prepare(false, true);
  for (const auto& [cost, params] : fixed_) {
    std::vector<double> res(cost->num_residuals());
    if (!cost->Evaluate(params.data(), res.data(), nullptr)) {
      summary->termination_type = ceres::FAILURE;
      summary->message = "Residual evaluation of a constant residual block failed.";
      return;
    }
    for (double v : res) summary->fixed_cost += 0.5 * v * v;
  }
  if (blocks_.empty()) {
    summary->termination_type = ceres::CONVERGENCE;
    summary->message = "Function tolerance reached. No non-constant parameter blocks found.";
    summary->initial_cost = summary->final_cost = summary->fixed_cost;
    return;
  }

  std::vector<double> x, original, candidate, step;
  Gather(&x);
  original = x;
  double x_norm = -1.0;  // as Ceres's: unset until the first accepted step
  double x_cost = 0.0, candidate_cost = 0.0;
  radius_ = options_.initial_trust_region_radius;
  decrease_factor_ = 2.0;
  reuse_diagonal_ = false;
  int invalid_steps = 0;

  // Ceres reports and tests the gradient J^T r of the unscaled problem.
  auto gradient_norms = [&](ceres::IterationSummary* it) {
    double max_norm = 0.0, squared = 0.0;
    for (int c = 0; c < n_; ++c) {
      const double g = rhs_values_[c] / scale_[c];
      max_norm = std::max(max_norm, std::abs(g));
      squared += g * g;
    }
    it->gradient_max_norm = max_norm;
    it->gradient_norm = std::sqrt(squared);
  };
  auto finish = [&]() {
    summary->final_cost = summary->initial_cost;  // as Ceres's: the least cost of any iteration
    for (const ceres::IterationSummary& i : summary->iterations) summary->final_cost = std::min(summary->final_cost, i.cost);
    const bool usable = summary->termination_type == ceres::CONVERGENCE ||
                        summary->termination_type == ceres::NO_CONVERGENCE ||
                        summary->termination_type == ceres::USER_SUCCESS;
    Scatter(usable ? x : original);
    summary->total_time_in_seconds = Seconds() - start;
  };

  ceres::IterationSummary it;
  it.iteration = 0;
  it.eta = 0.1;
  Prepare(true, true);
  if (!Linearize(&x_cost)) {
    summary->termination_type = ceres::FAILURE;
    summary->message = "Residual and Jacobian evaluation failed.";
    Scatter(original);
    return;
  }
  summary->initial_cost = x_cost + summary->fixed_cost;
  it.cost = summary->initial_cost;
  it.step_is_valid = it.step_is_successful = true;
  gradient_norms(&it);
  double iteration_start = start;

  while (true) {
    // The iteration's end: record it, run the callbacks, test the tolerances (Ceres's order).
    if (it.step_is_successful) {
      ++summary->num_successful_steps;
    } else {
      ++summary->num_unsuccessful_steps;
    }
    it.trust_region_radius = radius_;
    it.iteration_time_in_seconds = Seconds() - iteration_start;
    it.cumulative_time_in_seconds = Seconds() - start;
    summary->iterations.push_back(it);
    bool go_on = true;
    for (ceres::IterationCallback* callback : options_.callbacks) {
      const ceres::CallbackReturnType answer = (*callback)(it);
      if (answer == ceres::SOLVER_TERMINATE_SUCCESSFULLY) {
        summary->termination_type = ceres::USER_SUCCESS;
        summary->message = "User callback returned SOLVER_TERMINATE_SUCCESSFULLY.";
        go_on = false;
        break;
      }
      if (answer == ceres::SOLVER_ABORT) {
        summary->termination_type = ceres::USER_FAILURE;
        summary->message = "User callback returned SOLVER_ABORT.";
        go_on = false;
        break;
      }
    }
    if (go_on && it.iteration >= options_.max_iterations) {
      summary->termination_type = ceres::NO_CONVERGENCE;
      summary->message = "Maximum number of iterations reached. Number of iterations: " + std::to_string(it.iteration) + ".";
      go_on = false;
    }
    if (go_on && it.step_is_successful && it.gradient_max_norm <= options_.gradient_tolerance) {
      summary->termination_type = ceres::CONVERGENCE;
      summary->message = "Gradient tolerance reached.";
      go_on = false;
    }
    if (go_on && radius_ <= options_.min_trust_region_radius) {
      summary->termination_type = ceres::CONVERGENCE;
      summary->message = "Minimum trust region radius reached.";
      go_on = false;
    }
    if (!go_on) break;

    iteration_start = Seconds();
    const ceres::IterationSummary previous = it;
    it = ceres::IterationSummary();
    it.iteration = previous.iteration + 1;
    it.eta = 0.1;

    // The step; an invalid one (no factorization, no model decrease) shrinks the region like a rejected one.
    const double solve_start = Seconds();
    double model_cost_change = 0.0;
    if (ComputeStep(&step)) {
      model_cost_change = ModelCostChange(step);
      it.step_is_valid = model_cost_change > 0.0;
      if (!it.step_is_valid) failure_ = "the model cost does not decrease";
    }
    it.step_solver_time_in_seconds = Seconds() - solve_start;
    it.linear_solver_iterations = 1;
    if (!it.step_is_valid) {
      if (++invalid_steps >= options_.max_num_consecutive_invalid_steps) {
        summary->termination_type = ceres::FAILURE;
        summary->message = "Number of consecutive invalid steps more than max_num_consecutive_invalid_steps: " +
                           std::to_string(options_.max_num_consecutive_invalid_steps) + " (" + failure_ + ")";
        finish();
        return;
      }
      radius_ /= decrease_factor_;
      decrease_factor_ *= 2.0;
      it.cost = x_cost + summary->fixed_cost;
      it.gradient_max_norm = previous.gradient_max_norm;
      it.gradient_norm = previous.gradient_norm;
      continue;
    }
    invalid_steps = 0;

    // The candidate x + S step and its cost.
    candidate.resize(n_);
    for (int c = 0; c < n_; ++c) candidate[c] = x[c] + step[c] * scale_[c];
    Scatter(candidate);
    Prepare(false, true);
    if (!EvaluateCost(&candidate_cost)) candidate_cost = std::numeric_limits<double>::max();

    double step_norm = 0.0;
    for (int c = 0; c < n_; ++c) step_norm += (x[c] - candidate[c]) * (x[c] - candidate[c]);
    it.step_norm = std::sqrt(step_norm);
    if (it.step_norm <= options_.parameter_tolerance * (x_norm + options_.parameter_tolerance)) {
      summary->termination_type = ceres::CONVERGENCE;
      summary->message = "Parameter tolerance reached.";
      finish();
      return;
    }
    it.cost_change = x_cost - candidate_cost;
    if (std::abs(it.cost_change) <= options_.function_tolerance * x_cost) {
      summary->termination_type = ceres::CONVERGENCE;
      summary->message = "Function tolerance reached.";
      finish();
      return;
    }
    it.relative_decrease = candidate_cost >= std::numeric_limits<double>::max()
                               ? std::numeric_limits<double>::lowest()
                               : (x_cost - candidate_cost) / model_cost_change;
    if (it.relative_decrease > options_.min_relative_decrease) {
      x.swap(candidate);
      x_norm = 0.0;
      for (double v : x) x_norm += v * v;
      x_norm = std::sqrt(x_norm);
      Prepare(true, false);  // the point the cost was just evaluated at
      if (!Linearize(&x_cost)) {
        summary->termination_type = ceres::FAILURE;
        summary->message = "Residual and Jacobian evaluation failed.";
        finish();
        return;
      }
      it.cost = x_cost + summary->fixed_cost;
      it.step_is_successful = true;
      gradient_norms(&it);
      radius_ = std::min(options_.max_trust_region_radius,
                         radius_ / std::max(1.0 / 3.0, 1.0 - std::pow(2.0 * it.relative_decrease - 1.0, 3)));
      decrease_factor_ = 2.0;
      reuse_diagonal_ = false;
    } else {
      it.step_is_successful = false;
      it.cost = candidate_cost + summary->fixed_cost;
      it.gradient_max_norm = previous.gradient_max_norm;
      it.gradient_norm = previous.gradient_norm;
      radius_ /= decrease_factor_;
      decrease_factor_ *= 2.0;
      Scatter(x);
    }
  }
  finish();
}

}  // namespace

std::string LmUnsupported(const ceres::Problem& problem) {
  std::vector<double*> blocks;
  problem.GetParameterBlocks(&blocks);
  for (double* block : blocks) {
    if (problem.GetManifold(block) != nullptr) return "a parameter block has a manifold";
    const int size = problem.ParameterBlockSize(block);
    for (int i = 0; i < size; ++i) {
      if (problem.GetParameterLowerBound(block, i) > -std::numeric_limits<double>::max() ||
          problem.GetParameterUpperBound(block, i) < std::numeric_limits<double>::max()) {
        return "a parameter has a bound";
      }
    }
  }
  std::vector<ceres::ResidualBlockId> ids;
  problem.GetResidualBlocks(&ids);
  for (const ceres::ResidualBlockId id : ids) {
    if (problem.GetLossFunctionForResidualBlock(id) != nullptr) return "a residual block has a loss function";
    const std::vector<int32_t>& sizes = problem.GetCostFunctionForResidualBlock(id)->parameter_block_sizes();
    if (std::accumulate(sizes.begin(), sizes.end(), 0LL) > UINT16_MAX) {
      return "a residual block reads more than 65535 parameters";  // the runs' 16-bit columns
    }
  }
  return "";
}

void SolveLm(const LmOptions& options, ceres::Problem* problem, ceres::Solver::Summary* summary) {
  LmSolver solver(options, problem);
  solver.Solve(summary);
}

}  // namespace m3c::motion
