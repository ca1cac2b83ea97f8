// HuMoR's GroupNorm MLP: Linear(in, h1), then for each further width [GroupNorm(G) -> ReLU -> Linear(h + skip,
// next)], where the last `skip_dim` input features are concatenated after the hidden features before every
// Linear but the first. Forward<T> runs on any scalar (double, ceres::Jet); ForwardBatch / BackwardBatch are
// the fast double path for many samples at once, with a hand-written reverse pass (vector-Jacobian
// products) that costs about one forward pass.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "nn/layers.h"
#include "nn/safetensors.h"

namespace m3c::nn {

class GroupNormMlp {
 public:
  // Tensors "<prefix>.<3k>.weight|bias" (Linear k) and "<prefix>.<3k+1>.weight|bias" (GroupNorm after
  // Linear k), as in HuMoR's checkpoints. widths = [in, h1, ..., out]. Throws if a tensor is missing or its
  // shape differs.
  GroupNormMlp(const SafetensorsFile& file, const std::string& prefix, const std::vector<int>& widths,
               int skip_dim, int groups, double eps);

  int input_dim() const { return widths_.front(); }
  int output_dim() const { return widths_.back(); }
  int skip_dim() const { return skip_dim_; }
  const std::vector<int>& widths() const { return widths_; }

  // One sample: x (input_dim) -> y (output_dim).
  template <typename T>
  void Forward(const T* x, T* y) const;

  // What BackwardBatch needs from ForwardBatch. (Not the ReLU outputs: where the ReLU passed follows from
  // `normalized` again, and they would double the memory held per sample.)
  struct Activations {
    std::vector<Eigen::MatrixXd> normalized;  // per hidden layer: (x - mean) / std, width x N
    std::vector<Eigen::MatrixXd> inv_std;     // per hidden layer: groups x N
    Eigen::MatrixXd skip;                     // skip_dim x N
  };

  // X: input_dim x N (one sample per column) -> Y: output_dim x N.
  void ForwardBatch(const Eigen::Ref<const Eigen::MatrixXd>& X, Eigen::MatrixXd* Y, Activations* acts) const;
  // dY (output_dim x N) = dL/dY -> dX = dL/dX (input_dim x N), for the batch ForwardBatch saw.
  void BackwardBatch(const Activations& acts, const Eigen::Ref<const Eigen::MatrixXd>& dY, Eigen::MatrixXd* dX) const;

 private:
  std::vector<int> widths_;
  int skip_dim_, groups_;
  double eps_;
  std::vector<RowMatrixXd> weight_;  // Linear k: widths[k+1] x (widths[k] + (k ? skip : 0))
  std::vector<Eigen::VectorXd> bias_;
  std::vector<Eigen::VectorXd> gn_weight_, gn_bias_;  // GroupNorm after Linear k, k < last
};

template <typename T>
void GroupNormMlp::Forward(const T* x, T* y) const {
  const int layers = static_cast<int>(weight_.size());
  std::vector<T> h(widths_[1]), input;
  LinearApply(weight_[0], bias_[0], x, h.data());
  for (int k = 1; k < layers; ++k) {
    const int width = widths_[k];
    GroupNormApply(gn_weight_[k - 1], gn_bias_[k - 1], groups_, eps_, h.data(), h.data());
    input.assign(width + skip_dim_, T(0));
    for (int i = 0; i < width; ++i) input[i] = Relu(h[i]);
    for (int i = 0; i < skip_dim_; ++i) input[width + i] = x[widths_[0] - skip_dim_ + i];
    h.assign(widths_[k + 1], T(0));
    LinearApply(weight_[k], bias_[k], input.data(), h.data());
  }
  for (int i = 0; i < widths_.back(); ++i) y[i] = h[i];
}

}  // namespace m3c::nn
