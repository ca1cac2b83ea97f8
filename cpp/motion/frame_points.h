// Points of one posed frame (a KeypointRegressor applied to the body) with Jacobians split into the
// optimizer's parameter blocks: translation (3), root orientation (3), body pose (3(J-1)), betas (B).
#pragma once

#include <vector>

#include <Eigen/Core>

#include "body/body_model.h"

namespace m3c::motion {

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct FrameBlocks {
  const double* transl;
  const double* root;
  const double* body;
  const double* betas;
};

class FramePoints {
 public:
  // points (K,3); when with_jacobian, jacobian (3K, 3 + 3J + B) with columns [transl | root | body | betas].
  void Evaluate(const body::BodyModel& model, const body::KeypointRegressor& regressor, const FrameBlocks& blocks,
                bool with_jacobian);
  const double* point(int k) const { return points_.data() + 3 * k; }
  // Row 3k+c of d point / d block, for block 0..3 (transl, root, body, betas).
  const double* jacobian_row(int row) const { return jacobian_.data() + static_cast<size_t>(row) * cols_; }
  int block_offset(int block) const { return offsets_[block]; }
  int block_size(int block) const { return sizes_[block]; }

 private:
  std::vector<double> pose_, points_, jacobian_;
  int cols_ = 0;
  int offsets_[4] = {0, 0, 0, 0}, sizes_[4] = {0, 0, 0, 0};
};

}  // namespace m3c::motion
