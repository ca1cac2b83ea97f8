#include "body/block_points.h"

#include <algorithm>

#include "body/kinematics.h"

namespace m3c::body {

void BlockPoints::Evaluate(const BodyModel& model, const KeypointRegressor& regressor, const PoseBlocks& blocks,
                           bool with_jacobian, bool body_columns, bool betas_columns) {
  const int J = model.num_joints(), K = regressor.num_keypoints();
  pose_.resize(3 * J);
  std::copy(blocks.root, blocks.root + 3, pose_.begin());
  std::copy(blocks.body, blocks.body + 3 * (J - 1), pose_.begin() + 3);
  points_.resize(3 * K);
  cols_ = NumJacobianColumns(model);
  // KeypointsWithJacobian's column order [transl | pose | betas] already is [transl | root | body | betas].
  offsets_[0] = 0, sizes_[0] = 3;
  offsets_[1] = 3, sizes_[1] = 3;
  offsets_[2] = 6, sizes_[2] = 3 * (J - 1);
  offsets_[3] = 3 + 3 * J, sizes_[3] = model.num_betas();
  if (with_jacobian) jacobian_.resize(static_cast<size_t>(3 * K) * cols_);
  const double zero[3] = {0.0, 0.0, 0.0};
  KeypointsWithJacobian(model, regressor, pose_.data(), blocks.betas, blocks.transl ? blocks.transl : zero,
                        points_.data(), with_jacobian ? jacobian_.data() : nullptr, body_columns, betas_columns);
}

void BlockPoints::Reserve(const BodyModel& model, const KeypointRegressor& regressor, bool with_jacobian) {
  pose_.resize(3 * model.num_joints());
  points_.resize(3 * regressor.num_keypoints());
  if (with_jacobian) jacobian_.resize(static_cast<size_t>(3 * regressor.num_keypoints()) * NumJacobianColumns(model));
}

}  // namespace m3c::body
