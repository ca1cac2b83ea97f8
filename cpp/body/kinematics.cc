#include "body/kinematics.h"

#include <algorithm>
#include <vector>

#include "body/posing.h"
#include "body/rotation.h"
#include "util/check.h"

namespace m3c::body {

template <typename T>
void ForwardKinematics(const BodyModel& model, int num_frames, const T* pose, const T* betas, bool betas_shared,
                       const T* transl, T* joints) {
  M3C_CHECK(num_frames >= 0) << "num_frames must be >= 0";
  const int J = model.num_joints(), B = model.num_betas();
  const auto& arrays = model.arrays<T>();
  std::vector<T> rest_shared(3 * J);
  if (betas_shared) RestJoints(arrays, betas, rest_shared.data());
#pragma omp parallel if (num_frames > 256)
  {
    Skeleton<T> skeleton;
    skeleton.Resize(J);
#pragma omp for schedule(static)
    for (int f = 0; f < num_frames; ++f) {
      if (betas_shared) {
        std::copy(rest_shared.begin(), rest_shared.end(), skeleton.rest_joints.begin());
      } else {
        RestJoints(arrays, betas + static_cast<size_t>(f) * B, skeleton.rest_joints.data());
      }
      PoseSkeleton(model.parents(), pose + static_cast<size_t>(f) * 3 * J, &skeleton);
      T* out = joints + static_cast<size_t>(f) * 3 * J;
      const T* t = transl ? transl + 3 * static_cast<size_t>(f) : nullptr;
      for (int k = 0; k < 3 * J; ++k) out[k] = skeleton.world_origin[k] + (t ? t[k % 3] : T(0));
    }
  }
}

template <typename T>
void Keypoints(const BodyModel& model, const KeypointRegressor& regressor, int num_frames, const T* pose,
               const T* betas, bool betas_shared, const T* transl, T* keypoints) {
  M3C_CHECK(num_frames >= 0) << "num_frames must be >= 0";
  M3C_CHECK(regressor.num_vertices() == model.num_vertices() && regressor.num_joints() == model.num_joints())
      << "keypoint regressor is for a model with " << regressor.num_vertices() << " vertices and "
      << regressor.num_joints() << " joints, this model has " << model.num_vertices() << " and "
      << model.num_joints();
  const int J = model.num_joints(), B = model.num_betas(), K = regressor.num_keypoints();
  const T zero[3] = {T(0), T(0), T(0)};
#pragma omp parallel for schedule(static) if (num_frames > 64)
  for (int f = 0; f < num_frames; ++f) {
    PoseKeypoints(model, regressor, pose + static_cast<size_t>(f) * 3 * J,
                  betas + (betas_shared ? 0 : static_cast<size_t>(f) * B),
                  transl ? transl + 3 * static_cast<size_t>(f) : zero, keypoints + static_cast<size_t>(f) * 3 * K);
  }
}

void KeypointsWithJacobian(const BodyModel& model, const KeypointRegressor& regressor, const double* pose,
                           const double* betas, const double* transl, double* keypoints, double* jacobian,
                           bool body_columns, bool betas_columns) {
  M3C_CHECK(regressor.num_vertices() == model.num_vertices() && regressor.num_joints() == model.num_joints())
      << "keypoint regressor does not match the body model";
  if (jacobian == nullptr) {
    PoseKeypoints(model, regressor, pose, betas, transl, keypoints);
    return;
  }
  using Eigen::Matrix3d;
  using Eigen::Vector3d;
  using RowMat3X = Eigen::Matrix<double, 3, Eigen::Dynamic, Eigen::RowMajor>;
  const auto& arrays = model.arrays_d();
  const int J = model.num_joints(), B = model.num_betas(), K = regressor.num_keypoints();
  const int D = NumJacobianColumns(model);
  const int kPose = 3, kBetas = 3 + 3 * J;

  Skeleton<double> sk;
  sk.Resize(J);
  RestJoints(arrays, betas, sk.rest_joints.data());
  PoseSkeleton(model.parents(), pose, &sk);
  auto Rw = [&](int j) { return Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(&sk.world_rot[9 * j]); };
  auto o = [&](int j) { return Eigen::Map<const Vector3d>(&sk.world_origin[3 * j]); };

  // G_k = Rw_k Jr(theta_k): world-frame rotation of joint k per unit change of its axis-angle.
  std::vector<Matrix3d> G(J);
  for (int k = 0; k < J; ++k) G[k] = Rw(k) * RightJacobianSO3(pose + 3 * k);

  // d o_j / d beta (3 x B): o_0 = J_0, o_j = o_p + Rw_p (J_j - J_p), rest joints linear in beta.
  std::vector<RowMat3X> dO(betas_columns ? J : 0, RowMat3X::Zero(3, B));
  auto dJ = [&](int j) { return arrays.joint_shapedirs.middleRows(3 * j, 3); };
  for (int j = 0; betas_columns && j < J; ++j) {
    const int p = model.parents()[j];
    dO[j] = p < 0 ? RowMat3X(dJ(j)) : RowMat3X(dO[p] + Rw(p) * (dJ(j) - dJ(p)));
  }
  // The pose columns a caller reads: the root's always, the body joints' with body_columns.
  const int posed_joints = body_columns ? J : 1;

  Eigen::Map<Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>> jac(jacobian, 3 * K, D);
  jac.setZero();

  // Posed used vertices and their 3 x D Jacobians.
  const auto& used = regressor.used_vertices();
  const int U = static_cast<int>(used.size());
  std::vector<Vector3d> vpos(U);
  std::vector<RowMat3X> vjac(U);
  if (U > 0) {
    std::vector<double> feature(9 * (J - 1));
    PoseFeature(J, sk.local_rot.data(), feature.data());
    // d vec(R_k) / d theta_k (9 x 3): column a is vec(R_k [Jr_k e_a]x).
    std::vector<Eigen::Matrix<double, 9, 3>> dvecR(J);
    for (int k = 1; k < posed_joints; ++k) {
      const Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>> Rk(&sk.local_rot[9 * k]);
      const Matrix3d Jr = RightJacobianSO3(pose + 3 * k);
      for (int a = 0; a < 3; ++a) {
        const Eigen::Matrix<double, 3, 3, Eigen::RowMajor> dR = Rk * Skew(Jr.col(a));
        dvecR[k].col(a) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(dR.data());
      }
    }
    const auto& offsets = model.weight_offsets();
    const auto& wj = model.weight_joints();
    const auto& wval = arrays.weight_values;
    std::vector<Vector3d> c(J);
    std::vector<char> touched(J);
    const Eigen::Map<const Eigen::VectorXd> beta(betas, B);
    const Eigen::Map<const Eigen::VectorXd> f(feature.data(), feature.size());
    for (int i = 0; i < U; ++i) {
      const int v = used[i];
      const Vector3d y = arrays.v_template.segment<3>(3 * v) + arrays.shapedirs.middleRows(3 * v, 3) * beta +
                         arrays.posedirs.middleRows(3 * v, 3) * f;
      RowMat3X& Jv = vjac[i];
      Jv.setZero(3, D);
      Vector3d value = Vector3d::Zero();
      Matrix3d M = Matrix3d::Zero();
      std::fill(touched.begin(), touched.end(), 0);
      for (int e = offsets[v]; e < offsets[v + 1]; ++e) {
        const int j = wj[e];
        const double w = wval[e];
        const Vector3d Jrest(&sk.rest_joints[3 * j]);
        const Vector3d p = Rw(j) * (y - Jrest) + o(j);
        value += w * p;
        M += w * Rw(j);
        if (betas_columns) {
          Jv.middleCols(kBetas, B) += w * (Rw(j) * (arrays.shapedirs.middleRows(3 * v, 3) - dJ(j)) + dO[j]);
        }
        for (int k : model.ancestors(j)) {
          if (!touched[k]) {
            c[k].setZero();
            touched[k] = 1;
          }
          c[k] += w * (p - o(k));
        }
      }
      for (int k = 0; k < posed_joints; ++k) {
        if (touched[k]) Jv.middleCols<3>(kPose + 3 * k) -= Skew(c[k]) * G[k];
        if (k >= 1) {
          Jv.middleCols<3>(kPose + 3 * k) +=
              M * (arrays.posedirs.block(3 * v, 9 * (k - 1), 3, 9) * dvecR[k]);
        }
      }
      vpos[i] = value;
    }
  }

  const auto& A = regressor.vertex_weights();
  const auto& Bj = regressor.joint_weights();
  const Vector3d t(transl[0], transl[1], transl[2]);
  for (int kp = 0; kp < K; ++kp) {
    Vector3d value = Vector3d::Zero();
    double weight_sum = 0.0;
    auto rows = jac.middleRows<3>(3 * kp);
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(A, kp); it; ++it) {
      const int slot = static_cast<int>(std::lower_bound(used.begin(), used.end(), it.col()) - used.begin());
      value += it.value() * vpos[slot];
      rows += it.value() * vjac[slot];
      weight_sum += it.value();
    }
    for (Eigen::SparseMatrix<double, Eigen::RowMajor>::InnerIterator it(Bj, kp); it; ++it) {
      const int j = static_cast<int>(it.col());
      const double w = it.value();
      value += w * o(j);
      weight_sum += w;
      if (betas_columns) rows.middleCols(kBetas, B) += w * dO[j];
      for (int k : model.ancestors(j)) {
        if (k != j && k < posed_joints) rows.middleCols<3>(kPose + 3 * k) -= w * Skew(o(j) - o(k)) * G[k];
      }
    }
    rows.leftCols<3>() += weight_sum * Matrix3d::Identity();
    Eigen::Map<Vector3d>(keypoints + 3 * kp) = value + weight_sum * t;
  }
}

KeypointRegressor IdentityJointRegressor(const BodyModel& model) {
  const int J = model.num_joints();
  Eigen::SparseMatrix<double, Eigen::RowMajor> joint_weights(J, J), vertex_weights(J, model.num_vertices());
  joint_weights.setIdentity();
  return KeypointRegressor(vertex_weights, joint_weights);
}

void JointsWithJacobian(const BodyModel& model, const double* pose, const double* betas, const double* transl,
                        double* joints, double* jacobian) {
  KeypointsWithJacobian(model, IdentityJointRegressor(model), pose, betas, transl, joints, jacobian);
}

template void ForwardKinematics<float>(const BodyModel&, int, const float*, const float*, bool, const float*, float*);
template void ForwardKinematics<double>(const BodyModel&, int, const double*, const double*, bool, const double*,
                                        double*);
template void Keypoints<float>(const BodyModel&, const KeypointRegressor&, int, const float*, const float*, bool,
                               const float*, float*);
template void Keypoints<double>(const BodyModel&, const KeypointRegressor&, int, const double*, const double*, bool,
                                const double*, double*);

}  // namespace m3c::body
