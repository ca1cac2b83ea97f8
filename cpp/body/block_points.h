// Points of one posed body (a KeypointRegressor applied to the model) with their Jacobians split into the
// parameter blocks the fits and the world optimizer use: translation (3), root orientation (3), body pose
// (3(J-1)), betas (B).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "body/body_model.h"

namespace m3c::body {

struct PoseBlocks {
  const double* transl;  // may be nullptr: zero translation
  const double* root;
  const double* body;
  const double* betas;
};

class BlockPoints {
 public:
  // points (K,3); when with_jacobian, jacobian (3K, 3 + 3J + B) with columns [transl | root | body | betas];
  // body_columns / betas_columns false leave those columns zero, not computed (KeypointsWithJacobian): for a cost
  // whose body or betas block the stage holds constant (Ceres asks for no Jacobian of it).
  void Evaluate(const BodyModel& model, const KeypointRegressor& regressor, const PoseBlocks& blocks,
                bool with_jacobian, bool body_columns = true, bool betas_columns = true);
  // Allocates the storage Evaluate() needs, so that it allocates nothing.
  void Reserve(const BodyModel& model, const KeypointRegressor& regressor, bool with_jacobian);
  int num_points() const { return static_cast<int>(points_.size() / 3); }
  Eigen::Map<const Eigen::Vector3d> point(int k) const { return Eigen::Map<const Eigen::Vector3d>(points_.data() + 3 * k); }
  const double* data() const { return points_.data(); }  // (K, 3) row-major
  // Row 3k+c of d points / d blocks (all four blocks, 3 + 3J + B columns).
  const double* jacobian_row(int row) const { return jacobian_.data() + static_cast<size_t>(row) * cols_; }
  // Rows 3k..3k+2 of d point_k / d block, block 0..3 (transl, root, body, betas), as a 3 x size matrix.
  Eigen::Map<const RowMatrixXd, 0, Eigen::OuterStride<>> jacobian(int k, int block) const {
    return {jacobian_.data() + static_cast<size_t>(3 * k) * cols_ + offsets_[block], 3, sizes_[block],
            Eigen::OuterStride<>(cols_)};
  }
  int block_offset(int block) const { return offsets_[block]; }
  int block_size(int block) const { return sizes_[block]; }

 private:
  std::vector<double> pose_, points_, jacobian_;
  int cols_ = 0;
  int offsets_[4] = {0, 0, 0, 0}, sizes_[4] = {0, 0, 0, 0};
};

}  // namespace m3c::body
