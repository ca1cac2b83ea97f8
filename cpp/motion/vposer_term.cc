#include "motion/vposer_term.h"

#include <algorithm>
#include <cmath>

#include <ceres/rotation.h>

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

namespace {

// z -> axis-angle of VPoser's joints (3 num_joints), on any scalar.
template <typename T>
void DecodeToAxisAngle(const nn::VPoser& vposer, const T* z, T* pose) {
  std::vector<T> rotations(9 * vposer.num_joints());
  vposer.Decode(z, rotations.data());
  for (int j = 0; j < vposer.num_joints(); ++j) {
    ceres::RotationMatrixToAngleAxis(ceres::RowMajorAdapter3x3(static_cast<const T*>(rotations.data() + 9 * j)),
                                     pose + 3 * j);
  }
}

}  // namespace

LatentPoseDecoder::LatentPoseDecoder(const nn::VPoser* vposer, int body_size, int num_threads)
    : vposer_(vposer), body_size_(body_size), num_threads_(std::max(1, num_threads)) {
  M3C_CHECK(vposer != nullptr) << "latent poses need a VPoser";
  M3C_CHECK(vposer->latent_dim() == kLatentDim)
      << "latent pose variables need a " << kLatentDim << "-d VPoser latent, this VPoser's has "
      << vposer->latent_dim() << "; set latent_pose = false to optimise axis-angle poses under the VPoser prior";
  M3C_CHECK(body_size >= 3 * vposer->num_joints())
      << "the body block (" << body_size << ") is smaller than VPoser's " << vposer->num_joints() << " joints";
}

int LatentPoseDecoder::AddFrame(double* latent, double* body) {
  const int P = 3 * vposer_->num_joints();
  frames_.push_back({latent, body, std::vector<double>(body + P, body + body_size_)});
  valid_ = false;
  return num_frames() - 1;
}

void LatentPoseDecoder::Decode(int i, const double* latent, double* body, double* jacobian) const {
  const int P = 3 * vposer_->num_joints();
  if (jacobian == nullptr) {
    DecodeToAxisAngle(*vposer_, latent, body);
  } else {
    using Jet = ceres::Jet<double, kLatentDim>;
    std::vector<Jet> z(kLatentDim), pose(P);
    for (int k = 0; k < kLatentDim; ++k) z[k] = Jet(latent[k], k);
    DecodeToAxisAngle(*vposer_, z.data(), pose.data());
    for (int r = 0; r < P; ++r) {
      body[r] = pose[r].a;
      Eigen::Map<Eigen::Matrix<double, 1, kLatentDim>>(jacobian + static_cast<size_t>(r) * kLatentDim) = pose[r].v.transpose();
    }
  }
  std::copy(frames_[i].tail.begin(), frames_[i].tail.end(), body + P);
}

bool LatentPoseDecoder::Cached(int i, const double* latent, bool with_jacobian) const {
  return valid_ && (with_jacobian_ || !with_jacobian) &&
         std::equal(latent, latent + kLatentDim, latents_.begin() + static_cast<size_t>(i) * kLatentDim);
}

void LatentPoseDecoder::DecodeAll(bool with_jacobian) {
  const int n = num_frames(), P = 3 * vposer_->num_joints();
  bool unchanged = true;
  for (int i = 0; i < n && unchanged; ++i) unchanged = Cached(i, frames_[i].latent, with_jacobian);
  if (unchanged) return;
  latents_.resize(static_cast<size_t>(n) * kLatentDim);
  bodies_.resize(static_cast<size_t>(n) * body_size_);
  jacobians_.resize(with_jacobian ? static_cast<size_t>(n) * P * kLatentDim : 0);
#pragma omp parallel for num_threads(num_threads_) schedule(dynamic, 4)
  for (int i = 0; i < n; ++i) {
    std::copy(frames_[i].latent, frames_[i].latent + kLatentDim, latents_.begin() + static_cast<size_t>(i) * kLatentDim);
    double* body = bodies_.data() + static_cast<size_t>(i) * body_size_;
    Decode(i, frames_[i].latent, body, with_jacobian ? jacobians_.data() + static_cast<size_t>(i) * P * kLatentDim : nullptr);
    std::copy(body, body + body_size_, frames_[i].body);
  }
  with_jacobian_ = with_jacobian;
  valid_ = true;
}

void LatentPoseDecoder::Get(int i, const double* latent, const double** body, const double** jacobian,
                            std::vector<double>* scratch) const {
  const int P = 3 * vposer_->num_joints();
  if (Cached(i, latent, jacobian != nullptr)) {
    *body = bodies_.data() + static_cast<size_t>(i) * body_size_;
    if (jacobian) *jacobian = jacobians_.data() + static_cast<size_t>(i) * P * kLatentDim;
    return;
  }
  scratch->resize(body_size_ + static_cast<size_t>(P) * kLatentDim);
  Decode(i, latent, scratch->data(), jacobian ? scratch->data() + body_size_ : nullptr);
  *body = scratch->data();
  if (jacobian) *jacobian = scratch->data() + body_size_;
}

LatentBodyCost::LatentBodyCost(ceres::CostFunction* inner, const LatentPoseDecoder* decoder, std::vector<int> slots,
                               std::vector<int> frames)
    : inner_(inner), decoder_(decoder), slots_(std::move(slots)), frames_(std::move(frames)) {
  M3C_CHECK(inner != nullptr && decoder != nullptr && slots_.size() == frames_.size() && !slots_.empty())
      << "LatentBodyCost needs a cost, a decoder and one frame per body slot";
  set_num_residuals(inner->num_residuals());
  *mutable_parameter_block_sizes() = inner->parameter_block_sizes();
  for (size_t k = 0; k < slots_.size(); ++k) {
    M3C_CHECK(slots_[k] >= 0 && slots_[k] < static_cast<int>(inner->parameter_block_sizes().size()) &&
              inner->parameter_block_sizes()[slots_[k]] == decoder->body_size())
        << "slot " << slots_[k] << " is not a body block of the wrapped cost";
    (*mutable_parameter_block_sizes())[slots_[k]] = LatentPoseDecoder::kLatentDim;
  }
}

bool LatentBodyCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  constexpr int L = LatentPoseDecoder::kLatentDim;
  const int R = num_residuals(), S = decoder_->body_size(), blocks = static_cast<int>(parameter_block_sizes().size());
  std::vector<const double*> params(parameters, parameters + blocks);
  std::vector<double*> inner_jac(jacobians ? blocks : 0);
  if (jacobians) std::copy(jacobians, jacobians + blocks, inner_jac.begin());
  std::vector<std::vector<double>> scratch(slots_.size()), body_jac(slots_.size());
  std::vector<const double*> decode_jac(slots_.size(), nullptr);
  for (size_t k = 0; k < slots_.size(); ++k) {
    const int slot = slots_[k];
    const bool want = jacobians && jacobians[slot];
    decoder_->Get(frames_[k], parameters[slot], &params[slot], want ? &decode_jac[k] : nullptr, &scratch[k]);
    if (want) {
      body_jac[k].resize(static_cast<size_t>(R) * S);
      inner_jac[slot] = body_jac[k].data();
    }
  }
  if (!inner_->Evaluate(params.data(), residuals, jacobians ? inner_jac.data() : nullptr)) return false;
  if (!jacobians) return true;
  for (size_t k = 0; k < slots_.size(); ++k) {
    if (!decode_jac[k]) continue;
    const int slot = slots_[k];
    const Eigen::Map<const nn::RowMatrixXd> d_body(body_jac[k].data(), R, S);
    const int P = decoder_->decoded_size();
    const Eigen::Map<const nn::RowMatrixXd> d_decode(decode_jac[k], P, L);
    Eigen::Map<nn::RowMatrixXd>(jacobians[slot], R, L) = d_body.leftCols(P) * d_decode;
  }
  return true;
}

}  // namespace m3c::motion
