// VPoser pose prior as Ceres residual blocks (SLAHMR's stage-1 pose prior, the thesis's stage (iv)), on the
// axis-angle body pose the optimizer keeps: z(theta) is the mean of VPoser's encoder for body joints 1..21,
// the first 63 values of the body block (SMPL's hand joints 22 and 23 are outside VPoser; the residual does
// not depend on them). With a stencil c over consecutive frames the residual is sqrt(weight) sum_f c_f z(theta_f):
//   c = {1}      pose prior        weight |z_t|^2 (a standard-normal latent: the VAE's prior)
//   c = {-1, 1}  latent smoothness weight |z_{t+1} - z_t|^2
// Jacobians are exact (nn::VPoser::EncodeMean's reverse pass).
#pragma once

#include <memory>
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

namespace m3c::motion {

// Body poses as VPoser latents (SLAHMR's pose variables): frame f's body joints 1..21 are the decoded latent
// z_f (6D rotations -> axis-angle); the rest of its body block (SMPL's hand joints) keeps the values it had
// when the frame was added. The decoder writes each decoded pose into the frame's body block, so code that reads
// body blocks sees the pose the latents stand for; costs on body poses see it through LatentBodyCost.
class LatentPoseDecoder {
 public:
  static constexpr int kLatentDim = 32;  // the Jets below are sized for VPoser's latent (v1 and v2)

  LatentPoseDecoder(const nn::VPoser* vposer, int body_size, int num_threads);
  // Registers a frame: its latent block (kLatentDim) and the body block that receives the decoded pose.
  // Returns the frame's index.
  int AddFrame(double* latent, double* body);
  int num_frames() const { return static_cast<int>(frames_.size()); }
  double* latent(int i) const { return frames_[i].latent; }
  int body_size() const { return body_size_; }
  int decoded_size() const { return 3 * vposer_->num_joints(); }  // body entries that come from the latent

  // Decodes every frame's latent into its body block, with d body / d z when with_jacobian. A no-op when the
  // latents are those of the last call (and it computed Jacobians if they are wanted).
  void DecodeAll(bool with_jacobian);
  // Frame i's decoded body (body_size) and d body / d z (3 J_vposer x kLatentDim, row-major; the hand rows are
  // zero and left out) for the given latent values: from the last DecodeAll when it was at these values, else
  // computed into `scratch`. jacobian may be null.
  void Get(int i, const double* latent, const double** body, const double** jacobian, std::vector<double>* scratch) const;

 private:
  void Decode(int i, const double* latent, double* body, double* jacobian) const;
  // The last DecodeAll holds frame i at these latent values (with Jacobians, if wanted).
  bool Cached(int i, const double* latent, bool with_jacobian) const;

  const nn::VPoser* vposer_;
  int body_size_, num_threads_;
  struct Frame {
    double* latent;
    double* body;
    std::vector<double> tail;  // body entries after VPoser's joints, fixed
  };
  std::vector<Frame> frames_;
  bool valid_ = false, with_jacobian_ = false;
  std::vector<double> latents_, bodies_, jacobians_;  // the last DecodeAll, per frame
};

// A cost on body poses evaluated on latents: the parameter blocks `slots` of `inner` (owned) are the body poses
// of decoder frames `frames`; this cost takes those frames' latents in their place and chains d body / d z.
class LatentBodyCost : public ceres::CostFunction {
 public:
  LatentBodyCost(ceres::CostFunction* inner, const LatentPoseDecoder* decoder, std::vector<int> slots,
                 std::vector<int> frames);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  const LatentPoseDecoder* decoder_;
  std::vector<int> slots_, frames_;
};

}  // namespace m3c::motion
