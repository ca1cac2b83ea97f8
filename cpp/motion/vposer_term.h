// VPoser pose prior as Ceres residual blocks (SLAHMR's stage-1 pose prior, the thesis's stage (iv)), on the
// axis-angle body pose the optimizer keeps: z(theta) is the mean of VPoser's encoder for body joints 1..21,
// the first 63 values of the body block (SMPL's hand joints 22 and 23 are outside VPoser; the residual does
// not depend on them). With a stencil c over consecutive frames the residual is sqrt(weight) sum_f c_f z(theta_f):
//   c = {1}      pose prior        weight |z_t|^2 (a standard-normal latent: the VAE's prior)
//   c = {-1, 1}  latent smoothness weight |z_{t+1} - z_t|^2
// Jacobians are exact (nn::VPoser::EncodeMean's reverse pass).
#pragma once

#include <vector>

#include <ceres/ceres.h>

#include "nn/vposer.h"

namespace m3c::motion {

class VPoserLatentCost : public ceres::CostFunction {
 public:
  // body_size: the size of a body-pose block, 3(J-1) >= 3 vposer->num_joints().
  // Blocks: one body pose per stencil entry. Residuals: vposer->latent_dim().
  VPoserLatentCost(const nn::VPoser* vposer, int body_size, std::vector<double> stencil, double weight);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const nn::VPoser* vposer_;
  std::vector<double> stencil_;
  double sqrt_weight_;
};

}  // namespace m3c::motion
