#include "motion/vposer_term.h"

#include <cmath>

#include "util/check.h"

namespace m3c::motion {

VPoserLatentCost::VPoserLatentCost(const nn::VPoser* vposer, int body_size, std::vector<double> stencil,
                                   double weight)
    : vposer_(vposer), stencil_(std::move(stencil)), sqrt_weight_(std::sqrt(weight)) {
  M3C_CHECK(vposer != nullptr) << "VPoser term without a VPoser";
  M3C_CHECK(body_size >= 3 * vposer->num_joints())
      << "the VPoser prior needs at least " << vposer->num_joints() << " body joints, the body model has "
      << body_size / 3;
  M3C_CHECK(!stencil_.empty() && weight >= 0) << "the VPoser term needs a stencil and a weight >= 0";
  set_num_residuals(vposer->latent_dim());
  mutable_parameter_block_sizes()->assign(stencil_.size(), body_size);
}

bool VPoserLatentCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int L = vposer_->latent_dim(), P = 3 * vposer_->num_joints(), size = parameter_block_sizes()[0];
  thread_local std::vector<double> z, dz;
  z.resize(L);
  dz.resize(static_cast<size_t>(L) * P);
  std::fill(residuals, residuals + L, 0.0);
  for (size_t f = 0; f < stencil_.size(); ++f) {
    double* jac = jacobians ? jacobians[f] : nullptr;
    vposer_->EncodeMean(parameters[f], z.data(), jac ? dz.data() : nullptr);
    const double c = sqrt_weight_ * stencil_[f];
    for (int i = 0; i < L; ++i) residuals[i] += c * z[i];
    if (!jac) continue;
    for (int i = 0; i < L; ++i) {
      double* row = jac + static_cast<size_t>(i) * size;
      for (int k = 0; k < P; ++k) row[k] = c * dz[static_cast<size_t>(i) * P + k];
      std::fill(row + P, row + size, 0.0);  // hand joints: outside VPoser
    }
  }
  for (int i = 0; i < L; ++i) {
    if (!std::isfinite(residuals[i])) return false;
  }
  return true;
}

}  // namespace m3c::motion
