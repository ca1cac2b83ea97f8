// SMPL-layout body model (SMPL, SMPL-H, SMPL-X bodies, or M3C's open model): any vertex count V,
// any joint count J whose parents come before their children, any number of shape components B.
#pragma once

#include <memory>
#include <mutex>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

namespace m3c::body {

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
using RowMatrixXi = Eigen::Matrix<int, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// The model's arrays in one scalar type (the float copy exists so float32 batches stream half the bytes).
// Vertex-major layouts: row 3*v + c of shapedirs/posedirs is coordinate c of vertex v.
template <typename T>
struct ModelArrays {
  using Matrix = Eigen::Matrix<T, Eigen::Dynamic, Eigen::Dynamic>;
  using Vector = Eigen::Matrix<T, Eigen::Dynamic, 1>;
  Vector v_template;       // 3V
  Matrix shapedirs;        // 3V x B
  Matrix posedirs;         // 3V x 9(J-1); column 9(j-1) + 3r + c multiplies (R_j - I)[r][c]
  Vector joint_template;   // 3J: J_regressor * v_template
  Matrix joint_shapedirs;  // 3J x B: J_regressor * shapedirs (rest joints are linear in betas)
  std::vector<T> weight_values;  // CSR values of the skinning weights
};

class BodyModel {
 public:
  // v_template (V,3); shapedirs (3V,B); posedirs (3V,9(J-1)); j_regressor (J,V); weights (V,J);
  // parents (J) with parents[0] = -1 and parents[j] < j; faces (F,3), may be empty.
  BodyModel(const RowMatrixXd& v_template, const Eigen::MatrixXd& shapedirs, const Eigen::MatrixXd& posedirs,
            const Eigen::SparseMatrix<double, Eigen::RowMajor>& j_regressor, const RowMatrixXd& weights,
            const std::vector<int>& parents, const RowMatrixXi& faces);

  int num_vertices() const { return num_vertices_; }
  int num_joints() const { return num_joints_; }
  int num_betas() const { return num_betas_; }
  int num_pose_params() const { return 3 * num_joints_; }
  const std::vector<int>& parents() const { return parents_; }
  const RowMatrixXi& faces() const { return faces_; }
  const Eigen::SparseMatrix<double, Eigen::RowMajor>& j_regressor() const { return j_regressor_; }
  // Ancestors of joint j from j itself up to the root.
  const std::vector<int>& ancestors(int j) const { return ancestors_[j]; }

  // Sparse skinning weights: vertex v uses joints weight_joints[k], k in [weight_offsets[v], weight_offsets[v+1]).
  const std::vector<int>& weight_offsets() const { return weight_offsets_; }
  const std::vector<int>& weight_joints() const { return weight_joints_; }

  const ModelArrays<double>& arrays_d() const { return arrays_d_; }
  const ModelArrays<float>& arrays_f() const;  // converted on first use, thread-safe

  template <typename T>
  const ModelArrays<T>& arrays() const;

 private:
  int num_vertices_, num_joints_, num_betas_;
  std::vector<int> parents_;
  std::vector<std::vector<int>> ancestors_;
  RowMatrixXi faces_;
  Eigen::SparseMatrix<double, Eigen::RowMajor> j_regressor_;
  std::vector<int> weight_offsets_, weight_joints_;
  ModelArrays<double> arrays_d_;
  mutable std::once_flag float_once_;
  mutable ModelArrays<float> arrays_f_;
};

template <>
inline const ModelArrays<double>& BodyModel::arrays<double>() const {
  return arrays_d();
}
template <>
inline const ModelArrays<float>& BodyModel::arrays<float>() const {
  return arrays_f();
}

// Keypoints as fixed linear combinations of posed vertices and posed joints:
// k_i = sum_v A[i,v] vertex_v + sum_j B[i,j] joint_j. Covers vertex picks (COCO face points), joint picks,
// and dense regressors (H36M-17) alike.
class KeypointRegressor {
 public:
  KeypointRegressor(const Eigen::SparseMatrix<double, Eigen::RowMajor>& vertex_weights,  // (K,V)
                    const Eigen::SparseMatrix<double, Eigen::RowMajor>& joint_weights);  // (K,J)
  int num_keypoints() const { return static_cast<int>(vertex_weights_.rows()); }
  int num_vertices() const { return static_cast<int>(vertex_weights_.cols()); }
  int num_joints() const { return static_cast<int>(joint_weights_.cols()); }
  const Eigen::SparseMatrix<double, Eigen::RowMajor>& vertex_weights() const { return vertex_weights_; }
  const Eigen::SparseMatrix<double, Eigen::RowMajor>& joint_weights() const { return joint_weights_; }
  // Vertices with a nonzero weight in any keypoint, sorted.
  const std::vector<int>& used_vertices() const { return used_vertices_; }

 private:
  Eigen::SparseMatrix<double, Eigen::RowMajor> vertex_weights_, joint_weights_;
  std::vector<int> used_vertices_;
};

}  // namespace m3c::body
