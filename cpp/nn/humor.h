// HuMoR's motion-prior terms evaluated from exported weights (python -m m3c.models.export): the posterior
// encoder q(z | x_prev, x_next) and the conditional prior p(z | x_prev), GroupNorm MLPs over 339-d states.
//
//   LatentNll(x_prev, z)          = -log N(z; mu_p, sigma_p^2)     (p from the prior network on x_prev)
//                                 = sum_d 0.5 (log sigma_d^2 + log 2 pi + (z_d - mu_d)^2 / sigma_d^2)
//   TransitionNll(x_prev, x_next) = LatentNll(x_prev, mu_q(x_prev, x_next))
//
// States are in the ground frame (z up, floor z = 0); both terms canonicalise them in the frame of x_prev
// first (humor_state.h), so gradients are with respect to the ground-frame states. The templated versions
// run on any scalar (ceres::Jet); the batched double versions use a hand-written reverse pass.
#pragma once

#include <string>
#include <vector>

#include "nn/humor_state.h"
#include "nn/mlp.h"
#include "nn/safetensors.h"

namespace m3c::nn {

class HumorPrior {
 public:
  // From an exported humor.safetensors (its "m3c" metadata gives the architecture). Throws naming the file.
  explicit HumorPrior(const SafetensorsFile& file);
  static HumorPrior FromFile(const std::string& path) { return HumorPrior(SafetensorsFile::Read(path)); }

  const GroupNormMlp& encoder() const { return encoder_; }
  const GroupNormMlp& prior() const { return prior_; }

  template <typename T>
  T LatentNll(const T* x_prev, const T* z) const;
  template <typename T>
  T TransitionNll(const T* x_prev, const T* x_next) const;

  // n samples at once; arrays row-major (n x 339), (n x 48); values (n). Gradient pointers may be null.
  // TransitionNll runs the networks on chunks of kBatchChunk samples: the activations kept for the backward pass
  // grow with the batch (a 600-frame, two-person problem held ~300 MB of them at once), and a few hundred columns
  // already keep the BLAS products efficient.
  static constexpr int kBatchChunk = 256;
  void LatentNll(int n, const double* x_prev, const double* z, double* values, double* grad_prev,
                 double* grad_z) const;
  void TransitionNll(int n, const double* x_prev, const double* x_next, double* values, double* grad_prev,
                     double* grad_next) const;
  // Sum of TransitionNll over the consecutive pairs of num_states states (row-major num_states x 339);
  // grad (num_states x 339) if not null.
  double SequenceTransitionNll(int num_states, const double* states, double* grad) const;

 private:
  struct Spec;
  static Spec ReadSpec(const SafetensorsFile& file);
  HumorPrior(const SafetensorsFile& file, const Spec& spec);

  GroupNormMlp encoder_, prior_;
};

namespace internal {
template <typename T>
T GaussianNll(const T* z, const T* mean, const T* logvar, int dim) {
  using std::exp;
  constexpr double kLog2Pi = 1.8378770664093453;
  T sum(0);
  for (int d = 0; d < dim; ++d) {
    const T diff = z[d] - mean[d];
    sum += 0.5 * (logvar[d] + kLog2Pi + diff * diff * exp(-logvar[d]));
  }
  return sum;
}
}  // namespace internal

template <typename T>
T HumorPrior::LatentNll(const T* x_prev, const T* z) const {
  const humor::CanonicalFrame<T> frame = humor::ComputeCanonicalFrame(x_prev);
  // Heap storage: a large Jet times 339 would not fit the stack.
  std::vector<T> canonical(humor::kStateDim), out(2 * humor::kLatentDim);
  humor::ToCanonical(frame, x_prev, canonical.data());
  prior_.Forward(canonical.data(), out.data());
  return internal::GaussianNll(z, out.data(), out.data() + humor::kLatentDim, humor::kLatentDim);
}

template <typename T>
T HumorPrior::TransitionNll(const T* x_prev, const T* x_next) const {
  const humor::CanonicalFrame<T> frame = humor::ComputeCanonicalFrame(x_prev);
  std::vector<T> pair(2 * humor::kStateDim), posterior(2 * humor::kLatentDim), prior(2 * humor::kLatentDim);
  humor::ToCanonical(frame, x_prev, pair.data());
  humor::ToCanonical(frame, x_next, pair.data() + humor::kStateDim);
  encoder_.Forward(pair.data(), posterior.data());
  prior_.Forward(pair.data(), prior.data());  // the prior reads the first 339 entries: canonical x_prev
  return internal::GaussianNll(posterior.data(), prior.data(), prior.data() + humor::kLatentDim,
                               humor::kLatentDim);
}

}  // namespace m3c::nn
