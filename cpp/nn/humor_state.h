// HuMoR's 339-d motion state and its canonical frame, templated on the scalar (double, ceres::Jet).
//
// State (ground frame: z up, floor z = 0): trans 3 | trans_vel 3 | root_orient 9 (row-major) |
// root_orient_vel 3 | pose_body 21 x 9 | joints 22 x 3 (SMPL 0..21) | joints_vel 22 x 3.
// Velocities are central differences over frames t-1, t+1; w is read off (dR/dt) R^T.
//
// Canonical frame of a state x (HuMoR scores x_prev -> x_next in the frame of x_prev): with the body's right
// direction r = -(first column of the root rotation), c = r_x/|r_xy|, s = r_y/|r_xy|, the yaw
// A = [[c, s, 0], [-s, c, 0], [0, 0, 1]] takes r to +x. Then
//   trans' = A (trans - (tx, ty, 0)),  joints' = A (joints - (px, py, 0)) + (px - tx, py - ty, 0),
//   rotations R' = A R, velocities v' = A v,
// with (tx, ty) the translation and (px, py) the pelvis joint of x (the frame's source).
#pragma once

#include <cmath>

#include "body/rotation.h"

namespace m3c::nn::humor {

constexpr int kStateDim = 339;
constexpr int kLatentDim = 48;
constexpr int kNumBodyJoints = 21;
constexpr int kNumStateJoints = 22;
constexpr int kTrans = 0;
constexpr int kTransVel = 3;
constexpr int kRootOrient = 6;
constexpr int kRootOrientVel = 15;
constexpr int kPoseBody = 18;
constexpr int kJoints = 207;
constexpr int kJointsVel = 273;

template <typename T>
struct CanonicalFrame {
  T c, s;         // the yaw A
  T trans[2];     // (tx, ty) of the source state
  T pelvis[2];    // (px, py) of the source state
};

template <typename T>
CanonicalFrame<T> ComputeCanonicalFrame(const T* x) {
  using std::sqrt;
  const T rx = -x[kRootOrient + 0], ry = -x[kRootOrient + 3];  // -R[0][0], -R[1][0]
  T norm = sqrt(rx * rx + ry * ry);
  if (norm < T(1e-12)) norm = T(1e-12);  // a body lying on its side has no heading; HuMoR's is arbitrary too
  CanonicalFrame<T> f;
  f.c = rx / norm;
  f.s = ry / norm;
  f.trans[0] = x[kTrans];
  f.trans[1] = x[kTrans + 1];
  f.pelvis[0] = x[kJoints];
  f.pelvis[1] = x[kJoints + 1];
  return f;
}

// out = the state x expressed in frame f (out may not alias x).
template <typename T>
void ToCanonical(const CanonicalFrame<T>& f, const T* x, T* out) {
  const T c = f.c, s = f.s;
  auto rotate = [&](const T v0, const T v1, const T v2, T* o) {
    o[0] = c * v0 + s * v1;
    o[1] = -s * v0 + c * v1;
    o[2] = v2;
  };
  rotate(x[kTrans] - f.trans[0], x[kTrans + 1] - f.trans[1], x[kTrans + 2], out + kTrans);
  rotate(x[kTransVel], x[kTransVel + 1], x[kTransVel + 2], out + kTransVel);
  for (int col = 0; col < 3; ++col) {  // A R, column by column
    T o[3];
    rotate(x[kRootOrient + col], x[kRootOrient + 3 + col], x[kRootOrient + 6 + col], o);
    for (int row = 0; row < 3; ++row) out[kRootOrient + 3 * row + col] = o[row];
  }
  rotate(x[kRootOrientVel], x[kRootOrientVel + 1], x[kRootOrientVel + 2], out + kRootOrientVel);
  for (int i = kPoseBody; i < kJoints; ++i) out[i] = x[i];
  const T offset[2] = {f.pelvis[0] - f.trans[0], f.pelvis[1] - f.trans[1]};
  for (int j = 0; j < kNumStateJoints; ++j) {
    const T* p = x + kJoints + 3 * j;
    T* o = out + kJoints + 3 * j;
    rotate(p[0] - f.pelvis[0], p[1] - f.pelvis[1], p[2], o);
    o[0] += offset[0];
    o[1] += offset[1];
    rotate(x[kJointsVel + 3 * j], x[kJointsVel + 3 * j + 1], x[kJointsVel + 3 * j + 2], out + kJointsVel + 3 * j);
  }
}

// The reverse pass of a canonicalisation. Given x_frame (the frame's source state), states x[k] and
// dL/d(canonical x[k]) g[k] for k < count, adds dL/dx[k] to grad[k] (including, for x[k] == x_frame, the path
// through the frame) and the frame's own contribution to grad_frame. Pointers in grad may equal grad_frame.
void ToCanonicalBackward(const double* x_frame, int count, const double* const* x, const double* const* g,
                         double* const* grad, double* grad_frame);

// A rigid transform p -> R p + t (R row-major) applied to a posed SMPL body: the root rotates about the rest
// pelvis j0 = joints[0] - trans, so trans' = R (trans + j0) + t - j0; joints (count x 3) move rigidly.
template <typename T>
void TransformSmpl(const T* R, const T* t, int count, T* trans, T* root_rotation, T* joints) {
  auto apply = [&](const T* v, T* o) {
    for (int r = 0; r < 3; ++r) o[r] = R[3 * r] * v[0] + R[3 * r + 1] * v[1] + R[3 * r + 2] * v[2];
  };
  T pelvis[3] = {joints[0], joints[1], joints[2]}, moved[3];
  apply(pelvis, moved);
  for (int i = 0; i < 3; ++i) trans[i] = moved[i] + t[i] - (pelvis[i] - trans[i]);
  T rotated[9];
  for (int col = 0; col < 3; ++col) {
    const T v[3] = {root_rotation[col], root_rotation[3 + col], root_rotation[6 + col]};
    T o[3];
    apply(v, o);
    for (int row = 0; row < 3; ++row) rotated[3 * row + col] = o[row];
  }
  for (int i = 0; i < 9; ++i) root_rotation[i] = rotated[i];
  for (int j = 0; j < count; ++j) {
    T o[3];
    apply(joints + 3 * j, o);
    for (int i = 0; i < 3; ++i) joints[3 * j + i] = o[i] + t[i];
  }
}

// The state of the middle frame of three consecutive frames k = 0 (t-1), 1 (t), 2 (t+1):
// trans[k] (3), root_orient[k] (3, axis-angle), joints[k] (66, SMPL joints 0..21), pose_body (63, axis-angle,
// frame t only), fps. ground_R (9, row-major) and ground_t (3), if not null, move all three frames into the
// ground frame first (see TransformSmpl). state: 339.
template <typename T>
void BuildState(const T* const trans[3], const T* const root_orient[3], const T* const joints[3],
                const T* pose_body, double fps, const T* ground_R, const T* ground_t, T* state) {
  const double h = 1.0 / fps;
  T tr[3][3], rot[3][9], jo[3][3 * kNumStateJoints];
  for (int k = 0; k < 3; ++k) {
    for (int i = 0; i < 3; ++i) tr[k][i] = trans[k][i];
    AxisAngleToRotation(root_orient[k], rot[k]);
    for (int i = 0; i < 3 * kNumStateJoints; ++i) jo[k][i] = joints[k][i];
    if (ground_R != nullptr) TransformSmpl(ground_R, ground_t, kNumStateJoints, tr[k], rot[k], jo[k]);
  }
  for (int i = 0; i < 3; ++i) {
    state[kTrans + i] = tr[1][i];
    state[kTransVel + i] = (tr[2][i] - tr[0][i]) / (2 * h);
  }
  for (int i = 0; i < 9; ++i) state[kRootOrient + i] = rot[1][i];
  // W = (dR/dt) R^T; w = antisymmetric part read off W.
  T W[9];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      T acc(0);
      for (int k = 0; k < 3; ++k) acc += (rot[2][3 * r + k] - rot[0][3 * r + k]) / (2 * h) * rot[1][3 * c + k];
      W[3 * r + c] = acc;
    }
  }
  state[kRootOrientVel + 0] = (W[7] - W[5]) / 2.0;
  state[kRootOrientVel + 1] = (W[2] - W[6]) / 2.0;
  state[kRootOrientVel + 2] = (W[3] - W[1]) / 2.0;
  for (int j = 0; j < kNumBodyJoints; ++j) AxisAngleToRotation(pose_body + 3 * j, state + kPoseBody + 9 * j);
  for (int i = 0; i < 3 * kNumStateJoints; ++i) {
    state[kJoints + i] = jo[1][i];
    state[kJointsVel + i] = (jo[2][i] - jo[0][i]) / (2 * h);
  }
}

}  // namespace m3c::nn::humor
