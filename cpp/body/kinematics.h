// Joints and keypoints without the full mesh, and their analytic Jacobians for Ceres cost functions.
#pragma once

#include "body/body_model.h"

namespace m3c::body {

// Posed joints (N, 3J) for N frames; same argument conventions as Forward() in lbs.h. Touches no vertex.
template <typename T>
void ForwardKinematics(const BodyModel& model, int num_frames, const T* pose, const T* betas, bool betas_shared,
                       const T* transl, T* joints);

// Keypoints (N, 3K) from a KeypointRegressor; only the vertices the regressor uses are posed.
template <typename T>
void Keypoints(const BodyModel& model, const KeypointRegressor& regressor, int num_frames, const T* pose,
               const T* betas, bool betas_shared, const T* transl, T* keypoints);

// Number of parameters one frame's Jacobian is taken with respect to: transl 3 | pose 3J | betas B.
inline int NumJacobianColumns(const BodyModel& model) { return 3 + 3 * model.num_joints() + model.num_betas(); }

// One frame's keypoints (3K) and, when jacobian != nullptr, d keypoints / d [transl | pose | betas] as a
// row-major (3K, 3 + 3J + B) matrix, the layout Ceres uses for a parameter block's Jacobian rows.
// Rotations use the right Jacobian of SO(3): d theta_k moves the subtree below joint k by
// (Rw_k Jr(theta_k) d theta_k) x (p - o_k); pose blend shapes add M_v P_v d vec(R_k).
// body_columns / betas_columns false: those columns (the body joints' 3(J-1), the B betas') are left zero and
// not computed (the pose blend shapes' and shape directions' products are most of the work), for a caller that
// holds them constant; the translation and root columns are always computed.
void KeypointsWithJacobian(const BodyModel& model, const KeypointRegressor& regressor, const double* pose,
                           const double* betas, const double* transl, double* keypoints, double* jacobian,
                           bool body_columns = true, bool betas_columns = true);

// The same for the model's own J posed joints (identity joint regressor).
void JointsWithJacobian(const BodyModel& model, const double* pose, const double* betas, const double* transl,
                        double* joints, double* jacobian);

// Regressor that selects the model's joints one by one.
KeypointRegressor IdentityJointRegressor(const BodyModel& model);

}  // namespace m3c::body
