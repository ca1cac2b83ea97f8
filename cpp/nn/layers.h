// Network building blocks templated on the scalar, so the same code runs on double and on ceres::Jet.
// Weights are always double; activations are T. Matrices are row-major (out x in) as torch stores them.
#pragma once

#include <cmath>

#include <Eigen/Core>

#include "nn/safetensors.h"

namespace m3c::nn {

namespace internal {
using std::exp;
using std::log;
using std::sqrt;
}  // namespace internal

// y = W x + b, W (out x in).
template <typename T>
void LinearApply(const RowMatrixXd& W, const Eigen::VectorXd& b, const T* x, T* y) {
  const Eigen::Index out = W.rows(), in = W.cols();
  if constexpr (std::is_same_v<T, double>) {
    Eigen::Map<Eigen::VectorXd>(y, out).noalias() = W * Eigen::Map<const Eigen::VectorXd>(x, in) + b;
  } else {
    for (Eigen::Index i = 0; i < out; ++i) {
      T acc(b[i]);
      const double* row = W.row(i).data();
      for (Eigen::Index j = 0; j < in; ++j) acc += row[j] * x[j];
      y[i] = acc;
    }
  }
}

// torch.nn.GroupNorm on one sample of C channels: per group of C/G consecutive channels,
// y = (x - mean) / sqrt(var + eps) * gamma + beta with the biased variance. In-place allowed.
template <typename T>
void GroupNormApply(const Eigen::VectorXd& gamma, const Eigen::VectorXd& beta, int groups, double eps, const T* x,
                    T* y) {
  using namespace internal;
  const int C = static_cast<int>(gamma.size()), size = C / groups;
  for (int g = 0; g < groups; ++g) {
    const T* xg = x + g * size;
    T mean(0);
    for (int i = 0; i < size; ++i) mean += xg[i];
    mean /= double(size);
    T var(0);
    for (int i = 0; i < size; ++i) var += (xg[i] - mean) * (xg[i] - mean);
    var /= double(size);
    const T inv = T(1) / sqrt(var + eps);
    for (int i = 0; i < size; ++i) {
      const int c = g * size + i;
      y[c] = (xg[i] - mean) * inv * gamma[c] + beta[c];
    }
  }
}

template <typename T>
T Relu(const T& x) {
  return x > T(0) ? x : T(0);
}

template <typename T>
T LeakyRelu(const T& x, double slope) {
  return x > T(0) ? x : x * slope;
}

// log(1 + e^x) without overflow.
template <typename T>
T Softplus(const T& x) {
  using namespace internal;
  return x > T(0) ? x + log(T(1) + exp(-x)) : log(T(1) + exp(x));
}

// BatchNorm1d in eval mode, folded into y = x * scale + shift.
struct BatchNormEval {
  Eigen::VectorXd scale, shift;
  BatchNormEval() = default;
  BatchNormEval(const SafetensorsFile& file, const std::string& prefix, int channels, double eps);
  template <typename T>
  void Apply(const T* x, T* y) const {
    for (Eigen::Index i = 0; i < scale.size(); ++i) y[i] = x[i] * scale[i] + shift[i];
  }
};

// VPoser's 6D decoding: x viewed as a row-major 3x2 matrix; its columns a, b give R = [b1 b2 b1xb2] with
// b1 = a/|a|, b2 = (b - (b1.b) b1)/|...| (norms clamped at 1e-12 as torch's F.normalize). R row-major.
template <typename T>
void Rotation6dColumnsToMatrix(const T* x, T* R) {
  using namespace internal;
  const T a[3] = {x[0], x[2], x[4]}, b[3] = {x[1], x[3], x[5]};
  T na = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  if (na < T(1e-12)) na = T(1e-12);
  const T b1[3] = {a[0] / na, a[1] / na, a[2] / na};
  const T dot = b1[0] * b[0] + b1[1] * b[1] + b1[2] * b[2];
  T u[3] = {b[0] - dot * b1[0], b[1] - dot * b1[1], b[2] - dot * b1[2]};
  T nu = sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
  if (nu < T(1e-12)) nu = T(1e-12);
  const T b2[3] = {u[0] / nu, u[1] / nu, u[2] / nu};
  const T b3[3] = {b1[1] * b2[2] - b1[2] * b2[1], b1[2] * b2[0] - b1[0] * b2[2], b1[0] * b2[1] - b1[1] * b2[0]};
  for (int r = 0; r < 3; ++r) {
    R[3 * r + 0] = b1[r];
    R[3 * r + 1] = b2[r];
    R[3 * r + 2] = b3[r];
  }
}

// WHAM's (pytorch3d's) 6D decoding: x[0:3] and x[3:6] orthonormalised into the ROWS of R; third row b1 x b2.
template <typename T>
void Rotation6dRowsToMatrix(const T* x, T* R) {
  T columns_layout[6] = {x[0], x[3], x[1], x[4], x[2], x[5]};
  T Rt[9];
  Rotation6dColumnsToMatrix(columns_layout, Rt);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R[3 * r + c] = Rt[3 * c + r];
}

}  // namespace m3c::nn
