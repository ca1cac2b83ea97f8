#include "nn/humor.h"

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>

#include "util/check.h"

namespace m3c::nn {

using humor::kLatentDim;
using humor::kStateDim;

struct HumorPrior::Spec {
  std::vector<int> encoder, prior;
  int groups = 16;
  double eps = 1e-5;
};

HumorPrior::HumorPrior(const SafetensorsFile& file) : HumorPrior(file, ReadSpec(file)) {}

HumorPrior::HumorPrior(const SafetensorsFile& file, const Spec& spec)
    : encoder_(file, "encoder.net", spec.encoder, 0, spec.groups, spec.eps),
      prior_(file, "prior_net.net", spec.prior, 0, spec.groups, spec.eps) {}

HumorPrior::Spec HumorPrior::ReadSpec(const SafetensorsFile& file) {
  const auto it = file.metadata().find("m3c");
  M3C_CHECK(it != file.metadata().end())
      << file.path() << " has no M3C manifest entry (metadata 'm3c'); export HuMoR with "
      << "python -m m3c.models.export --humor CHECKPOINT --out DIR";
  HumorPrior::Spec spec;
  try {
    const nlohmann::json entry = nlohmann::json::parse(it->second);
    M3C_CHECK(entry.at("architecture").get<std::string>() == "humor")
        << file.path() << " holds a '" << entry.at("architecture").get<std::string>() << "' model, not HuMoR";
    M3C_CHECK(entry.at("state_dim").get<int>() == kStateDim && entry.at("latent_dim").get<int>() == kLatentDim)
        << file.path() << ": state/latent dims " << entry.at("state_dim") << "/" << entry.at("latent_dim")
        << ", expected " << kStateDim << "/" << kLatentDim;
    spec.encoder = entry.at("networks").at("encoder").at("layers").get<std::vector<int>>();
    spec.prior = entry.at("networks").at("prior").at("layers").get<std::vector<int>>();
    spec.groups = entry.at("group_norm_groups").get<int>();
    spec.eps = entry.at("group_norm_eps").get<double>();
  } catch (const nlohmann::json::exception& err) {
    M3C_CHECK(false) << file.path() << ": unreadable M3C manifest entry (" << err.what() << ")";
  }
  M3C_CHECK(!spec.encoder.empty() && spec.encoder.front() == 2 * kStateDim &&
            spec.encoder.back() == 2 * kLatentDim)
      << file.path() << ": the encoder must map " << 2 * kStateDim << " -> " << 2 * kLatentDim;
  M3C_CHECK(!spec.prior.empty() && spec.prior.front() == kStateDim && spec.prior.back() == 2 * kLatentDim)
      << file.path() << ": the prior must map " << kStateDim << " -> " << 2 * kLatentDim;
  return spec;
}

namespace {

// dL/d(mean), dL/d(logvar) of the Gaussian NLL at z; returns the NLL.
double NllAndGradient(const double* z, const double* mean, const double* logvar, double* d_z, double* d_mean,
                      double* d_logvar) {
  constexpr double kLog2Pi = 1.8378770664093453;
  double sum = 0;
  for (int d = 0; d < kLatentDim; ++d) {
    const double inv_var = std::exp(-logvar[d]);
    const double diff = z[d] - mean[d];
    sum += 0.5 * (logvar[d] + kLog2Pi + diff * diff * inv_var);
    if (d_z) d_z[d] = diff * inv_var;
    if (d_mean) d_mean[d] = -diff * inv_var;
    if (d_logvar) d_logvar[d] = 0.5 * (1.0 - diff * diff * inv_var);
  }
  return sum;
}

}  // namespace

void HumorPrior::LatentNll(int n, const double* x_prev, const double* z, double* values, double* grad_prev,
                           double* grad_z) const {
  M3C_CHECK(n >= 0) << "negative sample count";
  if (n == 0) return;
  Eigen::MatrixXd X(kStateDim, n);
  for (int i = 0; i < n; ++i) {
    const double* x = x_prev + static_cast<size_t>(i) * kStateDim;
    humor::ToCanonical(humor::ComputeCanonicalFrame(x), x, X.col(i).data());
  }
  Eigen::MatrixXd Y;
  GroupNormMlp::Activations acts;
  prior_.ForwardBatch(X, &Y, &acts);
  const bool want_grad = grad_prev != nullptr;
  Eigen::MatrixXd dY = Eigen::MatrixXd::Zero(2 * kLatentDim, n);
  for (int i = 0; i < n; ++i) {
    const double* zi = z + static_cast<size_t>(i) * kLatentDim;
    const double v = NllAndGradient(zi, Y.col(i).data(), Y.col(i).data() + kLatentDim,
                                    grad_z ? grad_z + static_cast<size_t>(i) * kLatentDim : nullptr,
                                    dY.col(i).data(), dY.col(i).data() + kLatentDim);
    if (values) values[i] = v;
  }
  if (!want_grad) return;
  Eigen::MatrixXd dX;
  prior_.BackwardBatch(acts, dY, &dX);
  for (int i = 0; i < n; ++i) {
    const double* x = x_prev + static_cast<size_t>(i) * kStateDim;
    double* g = grad_prev + static_cast<size_t>(i) * kStateDim;
    std::fill(g, g + kStateDim, 0.0);
    const double* xs[1] = {x};
    const double* gs[1] = {dX.col(i).data()};
    double* out[1] = {g};
    humor::ToCanonicalBackward(x, 1, xs, gs, out, g);
  }
}

void HumorPrior::TransitionNll(int n, const double* x_prev, const double* x_next, double* values,
                               double* grad_prev, double* grad_next) const {
  M3C_CHECK(n >= 0) << "negative sample count";
  if (n > kBatchChunk) {
    for (int first = 0; first < n; first += kBatchChunk) {
      const size_t at = static_cast<size_t>(first);
      TransitionNll(std::min(kBatchChunk, n - first), x_prev + at * kStateDim, x_next + at * kStateDim,
                    values ? values + at : nullptr, grad_prev ? grad_prev + at * kStateDim : nullptr,
                    grad_next ? grad_next + at * kStateDim : nullptr);
    }
    return;
  }
  if (n == 0) return;
  Eigen::MatrixXd X(2 * kStateDim, n);
  for (int i = 0; i < n; ++i) {
    const double* a = x_prev + static_cast<size_t>(i) * kStateDim;
    const double* b = x_next + static_cast<size_t>(i) * kStateDim;
    const humor::CanonicalFrame<double> frame = humor::ComputeCanonicalFrame(a);
    humor::ToCanonical(frame, a, X.col(i).data());
    humor::ToCanonical(frame, b, X.col(i).data() + kStateDim);
  }
  Eigen::MatrixXd Q, P;
  GroupNormMlp::Activations acts_q, acts_p;
  encoder_.ForwardBatch(X, &Q, &acts_q);
  prior_.ForwardBatch(X.topRows(kStateDim), &P, &acts_p);
  Eigen::MatrixXd dQ = Eigen::MatrixXd::Zero(2 * kLatentDim, n), dP(2 * kLatentDim, n);
  for (int i = 0; i < n; ++i) {
    const double v = NllAndGradient(Q.col(i).data(), P.col(i).data(), P.col(i).data() + kLatentDim,
                                    dQ.col(i).data(), dP.col(i).data(), dP.col(i).data() + kLatentDim);
    if (values) values[i] = v;
  }
  if (grad_prev == nullptr && grad_next == nullptr) return;
  Eigen::MatrixXd dXq, dXp;
  encoder_.BackwardBatch(acts_q, dQ, &dXq);
  prior_.BackwardBatch(acts_p, dP, &dXp);
  dXq.topRows(kStateDim) += dXp;
  std::vector<double> scratch_prev(grad_prev ? 0 : kStateDim), scratch_next(grad_next ? 0 : kStateDim);
  for (int i = 0; i < n; ++i) {
    const double* a = x_prev + static_cast<size_t>(i) * kStateDim;
    const double* b = x_next + static_cast<size_t>(i) * kStateDim;
    double* ga = grad_prev ? grad_prev + static_cast<size_t>(i) * kStateDim : scratch_prev.data();
    double* gb = grad_next ? grad_next + static_cast<size_t>(i) * kStateDim : scratch_next.data();
    std::fill(ga, ga + kStateDim, 0.0);
    std::fill(gb, gb + kStateDim, 0.0);
    const double* xs[2] = {a, b};
    const double* gs[2] = {dXq.col(i).data(), dXq.col(i).data() + kStateDim};
    double* out[2] = {ga, gb};
    humor::ToCanonicalBackward(a, 2, xs, gs, out, ga);
  }
}

double HumorPrior::SequenceTransitionNll(int num_states, const double* states, double* grad) const {
  M3C_CHECK(num_states >= 2) << "a sequence needs at least 2 states, got " << num_states;
  const int n = num_states - 1;
  std::vector<double> values(n);
  std::vector<double> grad_prev(grad ? static_cast<size_t>(n) * kStateDim : 0);
  std::vector<double> grad_next(grad ? static_cast<size_t>(n) * kStateDim : 0);
  TransitionNll(n, states, states + kStateDim, values.data(), grad ? grad_prev.data() : nullptr,
                grad ? grad_next.data() : nullptr);
  if (grad) {
    std::fill(grad, grad + static_cast<size_t>(num_states) * kStateDim, 0.0);
    for (size_t i = 0; i < grad_prev.size(); ++i) {
      grad[i] += grad_prev[i];
      grad[i + kStateDim] += grad_next[i];
    }
  }
  double total = 0;
  for (double v : values) total += v;
  return total;
}

}  // namespace m3c::nn
