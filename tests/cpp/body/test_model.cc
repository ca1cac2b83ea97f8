#include "test_model.h"

#include <Eigen/Geometry>

namespace m3c::body::testing {

namespace {
const int kParents[24] = {-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21};
}

std::vector<double> RandomVector(int n, double scale, unsigned seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<double> normal(0.0, scale);
  std::vector<double> out(n);
  for (double& x : out) x = normal(gen);
  return out;
}

BodyModel MakeTestModel(int vertices_per_bone, int num_betas, unsigned seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const int J = 24;
  // Rest joints: a chain that spreads out like a body (exact values do not matter for the math).
  std::vector<Eigen::Vector3d> rest(J);
  rest[0].setZero();
  for (int j = 1; j < J; ++j) {
    rest[j] = rest[kParents[j]] + Eigen::Vector3d(0.15 * normal(gen), 0.2 * normal(gen), 0.1 * normal(gen));
  }
  const int V = (J - 1) * vertices_per_bone;
  RowMatrixXd v_template(V, 3), weights = RowMatrixXd::Zero(V, J);
  int v = 0;
  for (int j = 1; j < J; ++j) {
    const int p = kParents[j];
    for (int i = 0; i < vertices_per_bone; ++i, ++v) {
      const double t = uniform(gen);
      v_template.row(v) = (rest[p] + t * (rest[j] - rest[p])).transpose() +
                          0.04 * Eigen::RowVector3d(normal(gen), normal(gen), normal(gen));
      const double wp = std::clamp(1.5 - 2.0 * t, 0.0, 1.0);
      weights(v, p) = wp;
      weights(v, j) += 1.0 - wp;
      if (i % 5 == 0 && p > 0) {  // some vertices with three influences
        weights(v, kParents[p]) = 0.2;
        weights.row(v) /= weights.row(v).sum();
      }
    }
  }
  Eigen::SparseMatrix<double, Eigen::RowMajor> regressor(J, V);
  std::vector<Eigen::Triplet<double>> triplets;
  for (int j = 0; j < J; ++j) {
    std::vector<std::pair<double, int>> dist;
    for (int u = 0; u < V; ++u) dist.push_back({(v_template.row(u).transpose() - rest[j]).norm(), u});
    std::partial_sort(dist.begin(), dist.begin() + 6, dist.end());
    for (int k = 0; k < 6; ++k) triplets.emplace_back(j, dist[k].second, 1.0 / 6.0);
  }
  regressor.setFromTriplets(triplets.begin(), triplets.end());
  Eigen::MatrixXd shapedirs(3 * V, num_betas), posedirs(3 * V, 9 * (J - 1));
  for (int i = 0; i < shapedirs.size(); ++i) shapedirs.data()[i] = 0.02 * normal(gen);
  for (int i = 0; i < posedirs.size(); ++i) posedirs.data()[i] = 0.01 * normal(gen);
  std::vector<int> parents(kParents, kParents + J);
  return BodyModel(v_template, shapedirs, posedirs, regressor, weights, parents, RowMatrixXi(0, 3));
}

void NaiveLbs(const BodyModel& model, const double* pose, const double* betas, const double* transl,
              RowMatrixXd* vertices, RowMatrixXd* joints) {
  const auto& a = model.arrays_d();
  const int V = model.num_vertices(), J = model.num_joints(), B = model.num_betas();
  Eigen::VectorXd beta = Eigen::Map<const Eigen::VectorXd>(betas, B);
  Eigen::VectorXd v_shaped = a.v_template + a.shapedirs * beta;
  RowMatrixXd shaped = Eigen::Map<const RowMatrixXd>(v_shaped.data(), V, 3);
  RowMatrixXd rest = model.j_regressor() * shaped;  // J = J_regressor v_shaped, straight from the definition
  std::vector<Eigen::Matrix3d> R(J);
  Eigen::VectorXd feature(9 * (J - 1));
  for (int j = 0; j < J; ++j) {
    Eigen::Vector3d w(pose[3 * j], pose[3 * j + 1], pose[3 * j + 2]);
    R[j] = w.norm() > 0 ? Eigen::AngleAxisd(w.norm(), w.normalized()).toRotationMatrix() : Eigen::Matrix3d::Identity();
    if (j > 0) {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) feature(9 * (j - 1) + 3 * r + c) = R[j](r, c) - (r == c ? 1.0 : 0.0);
    }
  }
  Eigen::VectorXd v_posed = v_shaped + a.posedirs * feature;
  std::vector<Eigen::Matrix4d> G(J), A(J);
  for (int j = 0; j < J; ++j) {
    Eigen::Matrix4d local = Eigen::Matrix4d::Identity();
    local.topLeftCorner<3, 3>() = R[j];
    const int p = model.parents()[j];
    const Eigen::Vector3d parent_rest = p >= 0 ? Eigen::Vector3d(rest.row(p).transpose()) : Eigen::Vector3d::Zero();
    local.topRightCorner<3, 1>() = rest.row(j).transpose() - parent_rest;
    G[j] = p >= 0 ? G[p] * local : local;
    Eigen::Matrix4d unrest = Eigen::Matrix4d::Identity();
    unrest.topRightCorner<3, 1>() = -rest.row(j).transpose();
    A[j] = G[j] * unrest;
  }
  // Dense weights, recovered from the sparse storage only to run the plain (V x J) blend.
  RowMatrixXd W = RowMatrixXd::Zero(V, J);
  for (int u = 0; u < V; ++u)
    for (int e = model.weight_offsets()[u]; e < model.weight_offsets()[u + 1]; ++e)
      W(u, model.weight_joints()[e]) = a.weight_values[e];
  const Eigen::Vector3d t(transl[0], transl[1], transl[2]);
  vertices->resize(V, 3);
  for (int u = 0; u < V; ++u) {
    Eigen::Matrix4d M = Eigen::Matrix4d::Zero();
    for (int j = 0; j < J; ++j) M += W(u, j) * A[j];
    vertices->row(u) = ((M * v_posed.segment<3>(3 * u).homogeneous()).head<3>() + t).transpose();
  }
  joints->resize(J, 3);
  for (int j = 0; j < J; ++j) joints->row(j) = (G[j].topRightCorner<3, 1>() + t).transpose();
}

}  // namespace m3c::body::testing
