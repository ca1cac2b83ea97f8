// Per-frame SMPL posing math, templated on the parameter scalar T (double, float, ceres::Jet) and the
// model's storage scalar M. REFERENCE.md F: v_shaped = v_template + S beta; J = J_regressor v_shaped;
// v_posed = v_shaped + P vec(R[1:] - I); G_j = G_parent [R_j | J_j - J_parent]; A_j = G_j with the rest
// joint removed; v = sum_j w_j A_j [v_posed; 1] + transl.
#pragma once

#include <algorithm>
#include <type_traits>
#include <vector>

#include "body/body_model.h"
#include "body/rotation.h"

namespace m3c::body {

// Kinematic state of one posed frame, all before the root translation is added.
template <typename T>
struct Skeleton {
  std::vector<T> rest_joints;   // 3J, rest-pose joints J(beta)
  std::vector<T> local_rot;     // 9J, R_j = Rodrigues(theta_j), row-major
  std::vector<T> world_rot;     // 9J, rotation part of G_j
  std::vector<T> world_origin;  // 3J, translation part of G_j = posed joint positions
  void Resize(int J) {
    rest_joints.resize(3 * J);
    local_rot.resize(9 * J);
    world_rot.resize(9 * J);
    world_origin.resize(3 * J);
  }
};

// Rest joints J(beta) = J_regressor v_template + (J_regressor S) beta, never touching the mesh.
template <typename T, typename M>
void RestJoints(const ModelArrays<M>& arrays, const T* betas, T* rest_joints) {
  const int rows = static_cast<int>(arrays.joint_template.size());
  const int B = static_cast<int>(arrays.joint_shapedirs.cols());
  for (int r = 0; r < rows; ++r) {
    T value = T(arrays.joint_template[r]);
    for (int b = 0; b < B; ++b) value += T(arrays.joint_shapedirs(r, b)) * betas[b];
    rest_joints[r] = value;
  }
}

// Forward kinematics over the chain, given rest joints already in skeleton->rest_joints.
template <typename T>
void PoseSkeleton(const std::vector<int>& parents, const T* pose, Skeleton<T>* skeleton) {
  const int J = static_cast<int>(parents.size());
  T* Rl = skeleton->local_rot.data();
  T* Rw = skeleton->world_rot.data();
  T* o = skeleton->world_origin.data();
  const T* Jr = skeleton->rest_joints.data();
  for (int j = 0; j < J; ++j) AxisAngleToRotation(pose + 3 * j, Rl + 9 * j);
  for (int c = 0; c < 9; ++c) Rw[c] = Rl[c];
  for (int c = 0; c < 3; ++c) o[c] = Jr[c];
  for (int j = 1; j < J; ++j) {
    const int p = parents[j];
    const T* Rp = Rw + 9 * p;
    const T* Rj = Rl + 9 * j;
    T* Rwj = Rw + 9 * j;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        Rwj[3 * r + c] = Rp[3 * r] * Rj[c] + Rp[3 * r + 1] * Rj[3 + c] + Rp[3 * r + 2] * Rj[6 + c];
      }
    }
    const T d0 = Jr[3 * j] - Jr[3 * p], d1 = Jr[3 * j + 1] - Jr[3 * p + 1], d2 = Jr[3 * j + 2] - Jr[3 * p + 2];
    for (int r = 0; r < 3; ++r) {
      o[3 * j + r] = o[3 * p + r] + Rp[3 * r] * d0 + Rp[3 * r + 1] * d1 + Rp[3 * r + 2] * d2;
    }
  }
}

// Pose feature vec(R_j - I) for j = 1..J-1 (row-major per joint), the input of the pose blend shapes.
template <typename T>
void PoseFeature(int num_joints, const T* local_rot, T* feature) {
  for (int j = 1; j < num_joints; ++j) {
    for (int c = 0; c < 9; ++c) {
      feature[9 * (j - 1) + c] = local_rot[9 * j + c] - ((c % 4 == 0) ? T(1) : T(0));
    }
  }
}

// Posed positions of the listed vertices (before translation), computing only their rows of the blend shapes.
template <typename T, typename M>
void PoseVertices(const BodyModel& model, const ModelArrays<M>& arrays, const Skeleton<T>& skeleton,
                  const T* betas, const T* pose_feature, const int* vertex_ids, int count, T* out) {
  const int B = model.num_betas();
  const int P = static_cast<int>(arrays.posedirs.cols());
  const auto& offsets = model.weight_offsets();
  const auto& joints = model.weight_joints();
  for (int i = 0; i < count; ++i) {
    const int v = vertex_ids[i];
    T y[3];
    for (int c = 0; c < 3; ++c) {
      const int row = 3 * v + c;
      T value = T(arrays.v_template[row]);
      for (int b = 0; b < B; ++b) value += T(arrays.shapedirs(row, b)) * betas[b];
      for (int k = 0; k < P; ++k) value += T(arrays.posedirs(row, k)) * pose_feature[k];
      y[c] = value;
    }
    T acc[3] = {T(0), T(0), T(0)};
    for (int e = offsets[v]; e < offsets[v + 1]; ++e) {
      const int j = joints[e];
      const T w = T(arrays.weight_values[e]);
      const T* R = skeleton.world_rot.data() + 9 * j;
      const T* o = skeleton.world_origin.data() + 3 * j;
      const T* Jj = skeleton.rest_joints.data() + 3 * j;
      const T d0 = y[0] - Jj[0], d1 = y[1] - Jj[1], d2 = y[2] - Jj[2];
      for (int r = 0; r < 3; ++r) acc[r] += w * (R[3 * r] * d0 + R[3 * r + 1] * d1 + R[3 * r + 2] * d2 + o[r]);
    }
    for (int r = 0; r < 3; ++r) out[3 * i + r] = acc[r];
  }
}

// One frame's keypoints: regressor applied to posed vertices and joints, plus translation. Works on Jets,
// so Ceres autodiff cost functions can be built on it.
template <typename T>
void PoseKeypoints(const BodyModel& model, const KeypointRegressor& regressor, const T* pose, const T* betas,
                   const T* transl, T* keypoints) {
  const int J = model.num_joints();
  const auto& arrays = model.arrays_d();
  Skeleton<T> skeleton;
  skeleton.Resize(J);
  RestJoints(arrays, betas, skeleton.rest_joints.data());
  PoseSkeleton(model.parents(), pose, &skeleton);
  const auto& used = regressor.used_vertices();
  std::vector<T> feature(9 * (J - 1)), used_pos(3 * used.size());
  if (!used.empty()) {
    PoseFeature(J, skeleton.local_rot.data(), feature.data());
    PoseVertices(model, arrays, skeleton, betas, feature.data(), used.data(), static_cast<int>(used.size()),
                 used_pos.data());
  }
  const auto& A = regressor.vertex_weights();
  const auto& Bj = regressor.joint_weights();
  for (int k = 0; k < regressor.num_keypoints(); ++k) {
    T acc[3] = {T(0), T(0), T(0)};
    double weight_sum = 0.0;
    for (typename std::decay_t<decltype(A)>::InnerIterator it(A, k); it; ++it) {
      const int slot = static_cast<int>(std::lower_bound(used.begin(), used.end(), it.col()) - used.begin());
      for (int c = 0; c < 3; ++c) acc[c] += T(it.value()) * used_pos[3 * slot + c];
      weight_sum += it.value();
    }
    for (typename std::decay_t<decltype(Bj)>::InnerIterator it(Bj, k); it; ++it) {
      for (int c = 0; c < 3; ++c) acc[c] += T(it.value()) * skeleton.world_origin[3 * it.col() + c];
      weight_sum += it.value();
    }
    for (int c = 0; c < 3; ++c) keypoints[3 * k + c] = acc[c] + T(weight_sum) * transl[c];
  }
}

}  // namespace m3c::body
