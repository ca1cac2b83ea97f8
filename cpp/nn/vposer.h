// VPoser (v1 or v2) evaluated from exported weights (python -m m3c.models.export --vposer ...).
//   Decode: z (32) -> fc1 -> LeakyReLU -> fc2 -> LeakyReLU -> out (126) -> 21 rotations (6D, column layout).
//   Encode: pose_body (63, axis-angle) -> the version's encoder ops -> mean (32), scale = softplus (32).
// BatchNorm runs in eval mode (running statistics); dropout is inactive. Templated on the scalar.
#pragma once

#include <string>
#include <vector>

#include "nn/layers.h"
#include "nn/safetensors.h"

namespace m3c::nn {

class VPoser {
 public:
  explicit VPoser(const SafetensorsFile& file);
  static VPoser FromFile(const std::string& path) { return VPoser(SafetensorsFile::Read(path)); }

  const std::string& version() const { return version_; }
  int latent_dim() const { return latent_dim_; }
  int num_joints() const { return num_joints_; }

  // z (latent_dim) -> the raw 6D output (6 num_joints).
  template <typename T>
  void Decode6d(const T* z, T* out) const;
  // z (latent_dim) -> num_joints row-major 3x3 rotations (9 num_joints).
  template <typename T>
  void Decode(const T* z, T* rotations) const;
  // pose_body (3 num_joints, axis-angle) -> mean (latent_dim), scale (latent_dim).
  template <typename T>
  void Encode(const T* pose_body, T* mean, T* scale) const;
  // The encoder mean alone, in double, with its exact Jacobian d mean / d pose_body (latent_dim x 3 num_joints,
  // row-major) when `jacobian` is not null: a reverse pass over the encoder's ops, about latent_dim / (3
  // num_joints) the cost of forward-mode Jets. For pose priors inside a solver (motion/vposer_term.h).
  void EncodeMean(const double* pose_body, double* mean, double* jacobian) const;

 private:
  struct Dense {
    RowMatrixXd weight;
    Eigen::VectorXd bias;
    template <typename T>
    std::vector<T> operator()(const std::vector<T>& x) const {
      std::vector<T> y(weight.rows());
      LinearApply(weight, bias, x.data(), y.data());
      return y;
    }
  };
  enum class Op { kBatchNorm1, kBatchNorm2, kFc1, kFc2, kFc3, kLeakyRelu };

  std::string version_;
  int latent_dim_ = 0, num_joints_ = 0, hidden_ = 0;
  double slope_ = 0;
  Dense dec_fc1_, dec_fc2_, dec_out_;
  std::vector<Op> encoder_ops_;
  BatchNormEval enc_bn1_, enc_bn2_;
  Dense enc_fc1_, enc_fc2_, enc_fc3_, enc_mu_, enc_logvar_;
};

template <typename T>
void VPoser::Decode6d(const T* z, T* out) const {
  std::vector<T> h(z, z + latent_dim_);
  h = dec_fc1_(h);
  for (T& v : h) v = LeakyRelu(v, slope_);
  h = dec_fc2_(h);
  for (T& v : h) v = LeakyRelu(v, slope_);
  h = dec_out_(h);
  for (size_t i = 0; i < h.size(); ++i) out[i] = h[i];
}

template <typename T>
void VPoser::Decode(const T* z, T* rotations) const {
  std::vector<T> raw(6 * num_joints_);
  Decode6d(z, raw.data());
  for (int j = 0; j < num_joints_; ++j) Rotation6dColumnsToMatrix(raw.data() + 6 * j, rotations + 9 * j);
}

template <typename T>
void VPoser::Encode(const T* pose_body, T* mean, T* scale) const {
  std::vector<T> h(pose_body, pose_body + 3 * num_joints_);
  for (Op op : encoder_ops_) {
    switch (op) {
      case Op::kBatchNorm1:
        enc_bn1_.Apply(h.data(), h.data());
        break;
      case Op::kBatchNorm2:
        enc_bn2_.Apply(h.data(), h.data());
        break;
      case Op::kFc1:
        h = enc_fc1_(h);
        break;
      case Op::kFc2:
        h = enc_fc2_(h);
        break;
      case Op::kFc3:
        h = enc_fc3_(h);
        break;
      case Op::kLeakyRelu:
        for (T& v : h) v = LeakyRelu(v, slope_);
        break;
    }
  }
  const std::vector<T> mu = enc_mu_(h), logvar = enc_logvar_(h);
  for (int i = 0; i < latent_dim_; ++i) {
    mean[i] = mu[i];
    scale[i] = Softplus(logvar[i]);
  }
}

}  // namespace m3c::nn
