#include "body/body_model.h"

#include <algorithm>
#include <cmath>

#include "util/check.h"

namespace m3c::body {

namespace {
bool AllFinite(const double* data, Eigen::Index size) {
  return std::all_of(data, data + size, [](double x) { return std::isfinite(x); });
}
}  // namespace

BodyModel::BodyModel(const RowMatrixXd& v_template, const Eigen::MatrixXd& shapedirs,
                     const Eigen::MatrixXd& posedirs, const Eigen::SparseMatrix<double, Eigen::RowMajor>& j_regressor,
                     const RowMatrixXd& weights, const std::vector<int>& parents, const RowMatrixXi& faces)
    : num_vertices_(static_cast<int>(v_template.rows())),
      num_joints_(static_cast<int>(parents.size())),
      num_betas_(static_cast<int>(shapedirs.cols())),
      parents_(parents),
      faces_(faces),
      j_regressor_(j_regressor) {
  const int V = num_vertices_, J = num_joints_;
  M3C_CHECK(V > 0 && v_template.cols() == 3) << "v_template must be (V,3) with V > 0, got (" << v_template.rows()
                                             << "," << v_template.cols() << ")";
  M3C_CHECK(J >= 1) << "the model needs at least one joint";
  M3C_CHECK(parents_[0] == -1) << "parents[0] must be -1 (the root), got " << parents_[0];
  for (int j = 1; j < J; ++j) {
    M3C_CHECK(parents_[j] >= 0 && parents_[j] < j)
        << "parents[" << j << "] = " << parents_[j] << ": every parent must come before its child";
  }
  M3C_CHECK(shapedirs.rows() == 3 * V) << "shapedirs must have 3V = " << 3 * V << " rows, got " << shapedirs.rows();
  M3C_CHECK(posedirs.rows() == 3 * V && posedirs.cols() == 9 * (J - 1))
      << "posedirs must be (3V, 9(J-1)) = (" << 3 * V << "," << 9 * (J - 1) << "), got (" << posedirs.rows() << ","
      << posedirs.cols() << ")";
  M3C_CHECK(j_regressor.rows() == J && j_regressor.cols() == V)
      << "J_regressor must be (J,V) = (" << J << "," << V << "), got (" << j_regressor.rows() << ","
      << j_regressor.cols() << ")";
  M3C_CHECK(weights.rows() == V && weights.cols() == J)
      << "weights must be (V,J) = (" << V << "," << J << "), got (" << weights.rows() << "," << weights.cols() << ")";
  M3C_CHECK(faces.size() == 0 || faces.cols() == 3) << "faces must be (F,3)";
  if (faces.size() > 0) {
    M3C_CHECK(faces.minCoeff() >= 0 && faces.maxCoeff() < V) << "faces index vertices outside [0, " << V << ")";
  }
  M3C_CHECK(AllFinite(v_template.data(), v_template.size()) && AllFinite(shapedirs.data(), shapedirs.size()) &&
            AllFinite(posedirs.data(), posedirs.size()) && AllFinite(weights.data(), weights.size()) &&
            AllFinite(j_regressor.valuePtr(), j_regressor.nonZeros()))
      << "the body model contains NaN or Inf";

  ancestors_.resize(J);
  for (int j = 0; j < J; ++j) {
    for (int k = j; k >= 0; k = parents_[k]) ancestors_[j].push_back(k);
  }

  weight_offsets_.assign(1, 0);
  for (int v = 0; v < V; ++v) {
    for (int j = 0; j < J; ++j) {
      if (weights(v, j) != 0.0) {
        weight_joints_.push_back(j);
        arrays_d_.weight_values.push_back(weights(v, j));
      }
    }
    weight_offsets_.push_back(static_cast<int>(weight_joints_.size()));
  }

  arrays_d_.v_template = Eigen::Map<const Eigen::VectorXd>(RowMatrixXd(v_template).data(), 3 * V);
  arrays_d_.shapedirs = shapedirs;
  arrays_d_.posedirs = posedirs;
  // Rest joints are J_regressor applied to the shaped mesh; by linearity that is a template plus (3J,B) directions.
  Eigen::Map<const RowMatrixXd> template_v3(arrays_d_.v_template.data(), V, 3);
  RowMatrixXd joints_template = j_regressor_ * template_v3;
  arrays_d_.joint_template = Eigen::Map<const Eigen::VectorXd>(joints_template.data(), 3 * J);
  arrays_d_.joint_shapedirs.resize(3 * J, num_betas_);
  for (int b = 0; b < num_betas_; ++b) {
    Eigen::Map<const RowMatrixXd> dir_v3(arrays_d_.shapedirs.col(b).data(), V, 3);
    RowMatrixXd dir_j3 = j_regressor_ * dir_v3;
    arrays_d_.joint_shapedirs.col(b) = Eigen::Map<const Eigen::VectorXd>(dir_j3.data(), 3 * J);
  }
}

const ModelArrays<float>& BodyModel::arrays_f() const {
  std::call_once(float_once_, [this] {
    arrays_f_.v_template = arrays_d_.v_template.cast<float>();
    arrays_f_.shapedirs = arrays_d_.shapedirs.cast<float>();
    arrays_f_.posedirs = arrays_d_.posedirs.cast<float>();
    arrays_f_.joint_template = arrays_d_.joint_template.cast<float>();
    arrays_f_.joint_shapedirs = arrays_d_.joint_shapedirs.cast<float>();
    arrays_f_.weight_values.assign(arrays_d_.weight_values.begin(), arrays_d_.weight_values.end());
  });
  return arrays_f_;
}

KeypointRegressor::KeypointRegressor(const Eigen::SparseMatrix<double, Eigen::RowMajor>& vertex_weights,
                                     const Eigen::SparseMatrix<double, Eigen::RowMajor>& joint_weights)
    : vertex_weights_(vertex_weights), joint_weights_(joint_weights) {
  M3C_CHECK(vertex_weights.rows() == joint_weights.rows())
      << "vertex and joint weights must have one row per keypoint, got " << vertex_weights.rows() << " and "
      << joint_weights.rows();
  vertex_weights_.makeCompressed();
  joint_weights_.makeCompressed();
  M3C_CHECK(AllFinite(vertex_weights_.valuePtr(), vertex_weights_.nonZeros()) &&
            AllFinite(joint_weights_.valuePtr(), joint_weights_.nonZeros()))
      << "keypoint regressor contains NaN or Inf";
  std::vector<int> used(vertex_weights_.innerIndexPtr(), vertex_weights_.innerIndexPtr() + vertex_weights_.nonZeros());
  std::sort(used.begin(), used.end());
  used.erase(std::unique(used.begin(), used.end()), used.end());
  used_vertices_ = std::move(used);
}

}  // namespace m3c::body
