#include "motion/joint_blocks.h"

#include <algorithm>
#include <cmath>

#include "motion/costs.h"
#include "util/check.h"

namespace m3c::motion {

SharedJoints::SharedJoints(const body::BodyModel* model, const body::KeypointRegressor* joints, int num_threads)
    : model_(model), joints_(joints), num_threads_(std::max(1, num_threads)) {
  M3C_CHECK(joints->num_keypoints() == model->num_joints()) << "SharedJoints needs the body's joints as points";
}

int SharedJoints::AddFrame(const double* transl, const double* root, const double* body, const double* betas) {
  frames_.push_back({transl, root, body, betas});
  points_.emplace_back();
  values_.emplace_back();
  return num_frames() - 1;
}

std::vector<int> SharedJoints::Ancestors(int joint) const {
  std::vector<int> chain;
  for (int a = model_->parents()[joint]; a > 0; a = model_->parents()[a]) chain.push_back(a);
  std::reverse(chain.begin(), chain.end());
  return chain;
}

std::vector<std::vector<int>> SharedJoints::Chains() const {
  const std::vector<int>& parents = model_->parents();
  const int J = model_->num_joints();
  std::vector<int> children(J, 0);
  for (int j = 1; j < J; ++j) ++children[parents[j]];
  std::vector<std::vector<int>> chains;
  std::vector<int> chain_of(J, -1);
  for (int j = 0; j < J; ++j) {  // parents come before children
    const int p = j == 0 ? -1 : parents[j];
    if (p >= 0 && children[p] == 1) {
      chain_of[j] = chain_of[p];
    } else {
      chain_of[j] = static_cast<int>(chains.size());
      chains.emplace_back();
    }
    chains[chain_of[j]].push_back(j);
  }
  return chains;
}

void SharedJoints::EvaluateAll(bool with_jacobian) {
  const int J = model_->num_joints(), B = model_->num_betas(), n = num_frames();
  // Allocated on this thread (the solve's) before the parallel loop: storage that Release frees then serves this
  // thread's allocations and the next evaluation takes it back. (Allocated by the loop's threads, it would stay
  // in their heaps while this thread's heap grew.)
  for (int i = 0; i < n; ++i) {
    values_[i].resize(6 + 3 * (J - 1) + B);
    points_[i].Reserve(*model_, *joints_, with_jacobian);
  }
#pragma omp parallel for num_threads(num_threads_) schedule(dynamic, 8)
  for (int i = 0; i < n; ++i) {
    const Frame& fr = frames_[i];
    std::vector<double>& v = values_[i];
    std::copy(fr.transl, fr.transl + 3, v.begin());
    std::copy(fr.root, fr.root + 3, v.begin() + 3);
    std::copy(fr.body, fr.body + 3 * (J - 1), v.begin() + 6);
    std::copy(fr.betas, fr.betas + B, v.begin() + 6 + 3 * (J - 1));
    points_[i].Evaluate(*model_, *joints_, {fr.transl, fr.root, fr.body, fr.betas}, with_jacobian);
  }
  evaluated_ = true;
  with_jacobian_ = with_jacobian;
}

void SharedJoints::Release() {
  std::vector<body::BlockPoints>(points_.size()).swap(points_);
  for (std::vector<double>& v : values_) std::vector<double>().swap(v);  // Get() then computes what it is asked
  evaluated_ = false;
}

const body::BlockPoints& SharedJoints::Get(int i, const std::vector<int>& ancestors, const double* transl,
                                           const double* root, const std::vector<const double*>& ancestor_blocks,
                                           const double* betas, bool with_jacobian, body::BlockPoints* scratch) const {
  const int J = model_->num_joints(), B = model_->num_betas();
  const std::vector<double>& v = values_[i];
  bool cached = !v.empty() && (with_jacobian_ || !with_jacobian) && std::equal(transl, transl + 3, v.begin()) &&
                std::equal(root, root + 3, v.begin() + 3) &&
                std::equal(betas, betas + B, v.begin() + 6 + 3 * (J - 1));
  for (size_t a = 0; cached && a < ancestors.size(); ++a) {
    cached = std::equal(ancestor_blocks[a], ancestor_blocks[a] + 3, v.begin() + 6 + 3 * (ancestors[a] - 1));
  }
  if (cached) return points_[i];
  // Not at the shared point (a check of the cost alone, or a call outside a solve): the other body joints do not
  // move this one, so they are left at zero.
  thread_local std::vector<double> body;
  body.assign(3 * (J - 1), 0.0);
  for (size_t a = 0; a < ancestors.size(); ++a) {
    std::copy(ancestor_blocks[a], ancestor_blocks[a] + 3, body.begin() + 3 * (ancestors[a] - 1));
  }
  scratch->Evaluate(*model_, *joints_, {transl, root, body.data(), betas}, with_jacobian);
  return *scratch;
}

JointStencilCost::JointStencilCost(const SharedJoints* shared, std::vector<int> frames, std::vector<double> stencil,
                                   std::vector<int> joints, std::vector<double> weights, double sigma)
    : shared_(shared), frames_(std::move(frames)), joints_(std::move(joints)), stencil_(std::move(stencil)),
      sigma_(sigma) {
  M3C_CHECK(stencil_.size() >= 2 && stencil_.size() == frames_.size()) << "a stencil needs a frame per coefficient";
  M3C_CHECK(!joints_.empty() && weights.size() == joints_.size()) << "one weight per joint, and at least one joint";
  for (double w : weights) {
    M3C_CHECK(w >= 0) << "weights must be >= 0";
    sqrt_weights_.push_back(std::sqrt(w));
  }
  for (int j : joints_) {
    M3C_CHECK(j >= 0 && j < shared->model().num_joints()) << "joint " << j << " out of range";
    for (int a : shared->Ancestors(j)) ancestors_.push_back(a);
  }
  std::sort(ancestors_.begin(), ancestors_.end());
  ancestors_.erase(std::unique(ancestors_.begin(), ancestors_.end()), ancestors_.end());
  set_num_residuals(3 * static_cast<int>(joints_.size()));
  auto* sizes = mutable_parameter_block_sizes();
  for (size_t f = 0; f < frames_.size(); ++f) {
    sizes->insert(sizes->end(), {3, 3});
    sizes->insert(sizes->end(), ancestors_.size(), 3);
  }
  sizes->push_back(shared->model().num_betas());
}

bool JointStencilCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const int F = static_cast<int>(frames_.size()), A = static_cast<int>(ancestors_.size()), per = 2 + A;
  const int B = shared_->model().num_betas(), betas_slot = F * per, N = static_cast<int>(joints_.size());
  thread_local std::vector<body::BlockPoints> scratch;
  thread_local std::vector<const double*> ancestor_blocks;
  scratch.resize(F);
  ancestor_blocks.resize(A);
  std::fill(residuals, residuals + 3 * N, 0.0);
  if (jacobians && jacobians[betas_slot]) std::fill(jacobians[betas_slot], jacobians[betas_slot] + 3 * N * B, 0.0);
  using Rows3 = Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>, 0, Eigen::OuterStride<>>;
  for (int f = 0; f < F; ++f) {
    const double* const* p = parameters + f * per;
    for (int a = 0; a < A; ++a) ancestor_blocks[a] = p[2 + a];
    const body::BlockPoints& points = shared_->Get(frames_[f], ancestors_, p[0], p[1], ancestor_blocks,
                                                   parameters[betas_slot], jacobians != nullptr, &scratch[f]);
    double* const* jac = jacobians ? jacobians + f * per : nullptr;
    for (int n = 0; n < N; ++n) {
      const int j = joints_[n];
      const double c = sqrt_weights_[n] * stencil_[f];
      Eigen::Map<Eigen::Vector3d>(residuals + 3 * n) += c * points.point(j);
      if (!jacobians) continue;
      // Rows 3n..3n+2 of each 3-column block; a chain joint's Jacobian is zero on the chain's ancestors that
      // are not its own.
      if (jac[0]) Rows3(jac[0] + 9 * n, Eigen::OuterStride<>(3)) = c * points.jacobian(j, 0);
      if (jac[1]) Rows3(jac[1] + 9 * n, Eigen::OuterStride<>(3)) = c * points.jacobian(j, 1);
      for (int a = 0; a < A; ++a) {
        if (jac[2 + a]) {
          Rows3(jac[2 + a] + 9 * n, Eigen::OuterStride<>(3)) = c * points.jacobian(j, 2).middleCols<3>(3 * (ancestors_[a] - 1));
        }
      }
      if (jacobians[betas_slot]) {
        Eigen::Map<body::RowMatrixXd>(jacobians[betas_slot] + 3 * n * B, 3, B) += c * points.jacobian(j, 3);
      }
    }
  }
  for (int n = 0; sigma_ > 0 && n < N; ++n) {
    RobustPointRows(sqrt_weights_[n], sigma_, n, residuals, jacobians, parameter_block_sizes(), num_residuals());
  }
  return true;
}

std::vector<int> SelectedJoints(const body::KeypointRegressor& regressor) {
  if (regressor.vertex_weights().nonZeros() != 0) return {};
  std::vector<int> joints;
  const auto& w = regressor.joint_weights();
  for (int k = 0; k < w.outerSize(); ++k) {
    int count = 0;
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(w, k); it; ++it) {
      if (it.value() == 0.0) continue;
      if (it.value() != 1.0 || ++count > 1) return {};
      joints.push_back(static_cast<int>(it.col()));
    }
    if (count != 1) return {};
  }
  return joints;
}

std::vector<int> MovingJoints(const body::BodyModel& model, const body::KeypointRegressor& regressor) {
  const int J = model.num_joints();
  std::vector<bool> moves(J, false);
  // A joint is where its strict ancestors put it (rest joints do not depend on the pose).
  const auto& jw = regressor.joint_weights();
  for (int k = 0; k < jw.outerSize(); ++k) {
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(jw, k); it; ++it) {
      if (it.value() == 0.0) continue;
      for (int a = model.parents()[it.col()]; a > 0; a = model.parents()[a]) moves[a] = true;
    }
  }
  // A vertex moves with its skinning joints and their ancestors, and with every joint whose pose blend shapes
  // move it.
  const auto& vw = regressor.vertex_weights();
  const auto& posedirs = model.arrays_d().posedirs;
  for (int k = 0; k < vw.outerSize(); ++k) {
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(vw, k); it; ++it) {
      if (it.value() == 0.0) continue;
      const int v = static_cast<int>(it.col());
      for (int i = model.weight_offsets()[v]; i < model.weight_offsets()[v + 1]; ++i) {
        for (int a : model.ancestors(model.weight_joints()[i])) {
          if (a > 0) moves[a] = true;
        }
      }
      for (int a = 1; a < J; ++a) {
        moves[a] = moves[a] || posedirs.block(3 * v, 9 * (a - 1), 3, 9).cwiseAbs().maxCoeff() > 0.0;
      }
    }
  }
  std::vector<int> joints;
  for (int j = 1; j < J; ++j) {
    if (moves[j]) joints.push_back(j);
  }
  return joints;
}

SplitBodyCost::SplitBodyCost(ceres::CostFunction* inner, const std::vector<int>& slots, std::vector<int> joints)
    : inner_(inner), joints_(std::move(joints)) {
  set_num_residuals(inner_->num_residuals());
  const std::vector<int32_t>& inner_sizes = inner_->parameter_block_sizes();
  split_.assign(inner_sizes.size(), false);
  for (int slot : slots) {
    M3C_CHECK(slot >= 0 && slot < static_cast<int>(inner_sizes.size())) << "no parameter block " << slot;
    M3C_CHECK(inner_sizes[slot] % 3 == 0) << "a body block has 3 values per joint";
    split_[slot] = true;
  }
  const int body_joints = slots.empty() ? 0 : inner_sizes[slots[0]] / 3;
  if (joints_.empty()) {
    for (int j = 1; j <= body_joints; ++j) joints_.push_back(j);
  }
  for (size_t k = 0; k < joints_.size(); ++k) {
    M3C_CHECK(joints_[k] >= 1 && joints_[k] <= body_joints && (k == 0 || joints_[k] > joints_[k - 1]))
        << "joints must be increasing body joints 1.." << body_joints;
  }
  auto* sizes = mutable_parameter_block_sizes();
  for (size_t b = 0; b < inner_sizes.size(); ++b) {
    first_.push_back(static_cast<int>(sizes->size()));
    if (!split_[b]) {
      sizes->push_back(inner_sizes[b]);
      continue;
    }
    M3C_CHECK(inner_sizes[b] / 3 == body_joints) << "every split block must be a whole body pose";
    sizes->insert(sizes->end(), joints_.size(), 3);
  }
}

bool SplitBodyCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  const std::vector<int32_t>& inner_sizes = inner_->parameter_block_sizes();
  const int n = static_cast<int>(inner_sizes.size()), rows = num_residuals(), m = static_cast<int>(joints_.size());
  thread_local std::vector<std::vector<double>> bodies, body_jacobians;
  thread_local std::vector<const double*> params;
  thread_local std::vector<double*> jacs;
  bodies.resize(n), body_jacobians.resize(n), params.assign(n, nullptr), jacs.assign(n, nullptr);
  for (int b = 0; b < n; ++b) {
    const int first = first_[b];
    if (!split_[b]) {
      params[b] = parameters[first];
      if (jacobians) jacs[b] = jacobians[first];
      continue;
    }
    bodies[b].assign(inner_sizes[b], 0.0);  // joints without a block: zero (they do not move the cost)
    bool wanted = false;
    for (int k = 0; k < m; ++k) {
      std::copy(parameters[first + k], parameters[first + k] + 3, bodies[b].begin() + 3 * (joints_[k] - 1));
      wanted = wanted || (jacobians && jacobians[first + k]);
    }
    params[b] = bodies[b].data();
    if (wanted) {
      body_jacobians[b].resize(static_cast<size_t>(rows) * inner_sizes[b]);
      jacs[b] = body_jacobians[b].data();
    }
  }
  // The inner cost may use thread_local storage of its own, but not these vectors: copy what is needed after.
  if (!inner_->Evaluate(params.data(), residuals, jacobians ? jacs.data() : nullptr)) return false;
  if (!jacobians) return true;
  for (int b = 0; b < n; ++b) {
    if (!split_[b] || jacs[b] == nullptr) continue;
    const int first = first_[b], size = inner_sizes[b];
    for (int k = 0; k < m; ++k) {
      double* out = jacobians[first + k];
      if (!out) continue;
      const int column = 3 * (joints_[k] - 1);
      for (int r = 0; r < rows; ++r) std::copy(jacs[b] + r * size + column, jacs[b] + r * size + column + 3, out + 3 * r);
    }
  }
  return true;
}

}  // namespace m3c::motion
