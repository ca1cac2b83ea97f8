#include "nn/mlp.h"

#include <algorithm>
#include <cmath>

#include "util/check.h"

extern "C" void dgemm_(const char* transa, const char* transb, const int* m, const int* n, const int* k,
                       const double* alpha, const double* a, const int* lda, const double* b, const int* ldb,
                       const double* beta, double* c, const int* ldc);

namespace m3c::nn {

namespace {
// C = op(W) B + beta C, op(W) = W or W^T, for a row-major block W of the weights and column-major B and C, on the
// system BLAS: the batched networks' products are most of the motion prior's time, and OpenBLAS runs them
// several times faster than Eigen built for the baseline CPU (no -march=native, see CMakeLists.txt).
void WeightProduct(const Eigen::Ref<const RowMatrixXd>& W, bool transpose, const Eigen::Ref<const Eigen::MatrixXd>& B,
                   double beta, Eigen::MatrixXd* C) {
  const int m = static_cast<int>(transpose ? W.cols() : W.rows()), k = static_cast<int>(transpose ? W.rows() : W.cols());
  const int n = static_cast<int>(B.cols());
  M3C_CHECK(B.rows() == k) << "product of " << m << "x" << k << " weights with " << B.rows() << " rows";
  if (beta == 0.0) {
    C->resize(m, n);
  } else {
    M3C_CHECK(C->rows() == m && C->cols() == n) << "accumulating product into a matrix of the wrong size";
  }
  if (m == 0 || n == 0) return;
  if (k == 0) {
    if (beta == 0.0) C->setZero(); else *C *= beta;
    return;
  }
  // Row-major W is column-major W^T: op 'T' gives W, op 'N' gives W^T.
  const char op_w = transpose ? 'N' : 'T', op_b = 'N';
  const int lda = std::max<int>(static_cast<int>(W.outerStride()), transpose ? m : k);
  const int ldb = std::max<int>(static_cast<int>(B.outerStride()), k), ldc = m;
  const double alpha = 1.0;
  dgemm_(&op_w, &op_b, &m, &n, &k, &alpha, W.data(), &lda, B.data(), &ldb, &beta, C->data(), &ldc);
}

// GroupNorm's affine map gamma * xhat + beta per column, as an expression (the same arithmetic in the forward and
// the backward pass).
auto Affine(const Eigen::MatrixXd& xhat, const Eigen::VectorXd& gamma, const Eigen::VectorXd& beta) {
  return (xhat.array().colwise() * gamma.array()).colwise() + beta.array();
}
}  // namespace

BatchNormEval::BatchNormEval(const SafetensorsFile& file, const std::string& prefix, int channels, double eps) {
  const Eigen::VectorXd weight = file.Vector(prefix + ".weight", channels);
  const Eigen::VectorXd bias = file.Vector(prefix + ".bias", channels);
  const Eigen::VectorXd mean = file.Vector(prefix + ".running_mean", channels);
  const Eigen::VectorXd var = file.Vector(prefix + ".running_var", channels);
  scale = weight.array() / (var.array() + eps).sqrt();
  shift = bias.array() - mean.array() * scale.array();
}

GroupNormMlp::GroupNormMlp(const SafetensorsFile& file, const std::string& prefix, const std::vector<int>& widths,
                           int skip_dim, int groups, double eps)
    : widths_(widths), skip_dim_(skip_dim), groups_(groups), eps_(eps) {
  M3C_CHECK(widths.size() >= 2) << prefix << ": an MLP needs at least an input and an output width";
  M3C_CHECK(skip_dim >= 0 && skip_dim <= widths.front()) << prefix << ": skip_dim " << skip_dim << " out of range";
  M3C_CHECK(groups > 0) << prefix << ": groups must be positive";
  const int layers = static_cast<int>(widths.size()) - 1;
  for (int k = 0; k < layers; ++k) {
    const std::string linear = prefix + "." + std::to_string(3 * k);
    const int in = widths[k] + (k > 0 ? skip_dim : 0);
    weight_.push_back(file.Matrix(linear + ".weight", widths[k + 1], in));
    bias_.push_back(file.Vector(linear + ".bias", widths[k + 1]));
    if (k + 1 < layers) {
      M3C_CHECK(widths[k + 1] % groups == 0)
          << prefix << ": width " << widths[k + 1] << " is not divisible into " << groups << " groups";
      const std::string norm = prefix + "." + std::to_string(3 * k + 1);
      gn_weight_.push_back(file.Vector(norm + ".weight", widths[k + 1]));
      gn_bias_.push_back(file.Vector(norm + ".bias", widths[k + 1]));
    }
  }
}

void GroupNormMlp::ForwardBatch(const Eigen::Ref<const Eigen::MatrixXd>& X, Eigen::MatrixXd* Y,
                                Activations* acts) const {
  M3C_CHECK(X.rows() == input_dim()) << "MLP input has " << X.rows() << " rows, expected " << input_dim();
  const Eigen::Index n = X.cols();
  const int layers = static_cast<int>(weight_.size());
  acts->normalized.resize(layers - 1);
  acts->inv_std.resize(layers - 1);
  acts->skip = X.bottomRows(skip_dim_);

  Eigen::MatrixXd h, relu;
  WeightProduct(weight_[0], false, X, 0.0, &h);
  h.colwise() += bias_[0];
  for (int k = 1; k < layers; ++k) {
    const int width = widths_[k], size = width / groups_;
    Eigen::MatrixXd& xhat = acts->normalized[k - 1];
    Eigen::MatrixXd& inv = acts->inv_std[k - 1];
    xhat.resize(width, n);
    inv.resize(groups_, n);
    const Eigen::VectorXd& gamma = gn_weight_[k - 1];
    const Eigen::VectorXd& beta = gn_bias_[k - 1];
    for (Eigen::Index j = 0; j < n; ++j) {
      for (int g = 0; g < groups_; ++g) {
        const auto block = h.col(j).segment(g * size, size);
        const double mean = block.mean();
        const double var = (block.array() - mean).square().mean();
        const double inv_std = 1.0 / std::sqrt(var + eps_);
        inv(g, j) = inv_std;
        xhat.col(j).segment(g * size, size) = (block.array() - mean) * inv_std;
      }
    }
    relu = Affine(xhat, gamma, beta).max(0.0);
    WeightProduct(weight_[k].leftCols(width), false, relu, 0.0, &h);
    if (skip_dim_ > 0) WeightProduct(weight_[k].rightCols(skip_dim_), false, acts->skip, 1.0, &h);
    h.colwise() += bias_[k];
  }
  *Y = std::move(h);
}

void GroupNormMlp::BackwardBatch(const Activations& acts, const Eigen::Ref<const Eigen::MatrixXd>& dY,
                                 Eigen::MatrixXd* dX) const {
  M3C_CHECK(dY.rows() == output_dim()) << "MLP output gradient has " << dY.rows() << " rows, expected "
                                       << output_dim();
  const Eigen::Index n = dY.cols();
  const int layers = static_cast<int>(weight_.size());
  M3C_CHECK(static_cast<int>(acts.normalized.size()) == layers - 1 && (layers == 1 || acts.normalized[0].cols() == n))
      << "BackwardBatch needs the activations of a ForwardBatch over the same " << n << " samples";
  Eigen::MatrixXd dh = dY;
  Eigen::MatrixXd dskip = Eigen::MatrixXd::Zero(skip_dim_, n);
  for (int k = layers - 1; k >= 1; --k) {
    const int width = widths_[k], size = width / groups_;
    if (skip_dim_ > 0) WeightProduct(weight_[k].rightCols(skip_dim_), true, dh, 1.0, &dskip);
    Eigen::MatrixXd da;
    WeightProduct(weight_[k].leftCols(width), true, dh, 0.0, &da);
    // Through ReLU, then GroupNorm's affine: d xhat = dy * gamma where the ReLU passed (the forward pass's values).
    const Eigen::MatrixXd& xhat = acts.normalized[k - 1];
    da = (Affine(xhat, gn_weight_[k - 1], gn_bias_[k - 1]) > 0.0).select(da, 0.0);
    da.array().colwise() *= gn_weight_[k - 1].array();
    // Through the normalisation: dx = inv_std * (g - mean(g) - xhat * mean(g * xhat)) per group.
    const Eigen::MatrixXd& inv = acts.inv_std[k - 1];
    for (Eigen::Index j = 0; j < n; ++j) {
      for (int g = 0; g < groups_; ++g) {
        auto grad = da.col(j).segment(g * size, size);
        const auto xh = xhat.col(j).segment(g * size, size);
        const double mean_grad = grad.mean();
        const double mean_grad_xh = grad.dot(xh) / size;
        grad = inv(g, j) * (grad.array() - mean_grad - xh.array() * mean_grad_xh);
      }
    }
    dh = std::move(da);
  }
  WeightProduct(weight_[0], true, dh, 0.0, dX);
  if (skip_dim_ > 0) dX->bottomRows(skip_dim_) += dskip;
}

}  // namespace m3c::nn
