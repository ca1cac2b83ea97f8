#include "motion/humor_term.h"

#include <cmath>

#include "body/kinematics.h"
#include "body/block_points.h"
#include "nn/humor_state.h"
#include "util/check.h"

namespace m3c::motion {

namespace {
using nn::humor::kNumBodyJoints;
using nn::humor::kNumStateJoints;
using nn::humor::kStateDim;
// Inputs of one state: trans (3 frames x 3) | root (3 x 3) | joints (3 x 66) | body pose of the middle frame (63).
constexpr int kTransIn = 0, kRootIn = 9, kJointsIn = 18, kPoseIn = 18 + 3 * 3 * kNumStateJoints;
constexpr int kInputs = kPoseIn + 3 * kNumBodyJoints;  // 279
using StateJet = ceres::Jet<double, kInputs>;
}  // namespace

void GroundFrame(const Eigen::Vector3d& normal, double offset, Eigen::Matrix3d* R, Eigen::Vector3d* t) {
  const Eigen::Vector3d n = normal.normalized();
  const Eigen::Vector3d seed = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d e1 = (seed - seed.dot(n) * n).normalized();
  const Eigen::Vector3d e2 = n.cross(e1);
  R->row(0) = e1.transpose();
  R->row(1) = e2.transpose();
  R->row(2) = n.transpose();
  *t = Eigen::Vector3d(0.0, 0.0, offset / normal.norm());
}

HumorTransitionCost::HumorTransitionCost(const body::BodyModel* model, const nn::HumorPrior* prior, double fps,
                                         const Eigen::Matrix3d& ground_R, const Eigen::Vector3d& ground_t,
                                         double weight, double level)
    : model_(model),
      prior_(prior),
      joints_(std::make_unique<body::KeypointRegressor>(body::IdentityJointRegressor(*model))),
      fps_(fps),
      ground_R_(ground_R),
      ground_t_(ground_t),
      weight_(weight),
      level_(level) {
  M3C_CHECK(model->num_joints() == 24) << "the HuMoR term needs SMPL's 24-joint layout";
  M3C_CHECK(fps > 0 && weight >= 0) << "fps must be > 0 and weight >= 0";
  set_num_residuals(1);
  auto* sizes = mutable_parameter_block_sizes();
  for (int k = 0; k < 4; ++k) sizes->insert(sizes->end(), {3, 3, 3 * (model->num_joints() - 1)});
  sizes->push_back(model->num_betas());
}

void HumorTransitionCost::States(double const* const* parameters, double* x0, double* x1, Eigen::MatrixXd* dx0,
                                 Eigen::MatrixXd* dx1, std::vector<Eigen::MatrixXd>* joint_jacobians) const {
  const bool with_jacobian = dx0 != nullptr;
  const double* betas = parameters[12];
  std::vector<std::vector<double>> joints(4, std::vector<double>(3 * kNumStateJoints));
  body::BlockPoints points;
  if (joint_jacobians) joint_jacobians->resize(4);
  for (int f = 0; f < 4; ++f) {
    points.Evaluate(*model_, *joints_, {parameters[3 * f], parameters[3 * f + 1], parameters[3 * f + 2], betas},
                    with_jacobian);
    std::copy(points.data(), points.data() + 3 * kNumStateJoints, joints[f].begin());
    if (with_jacobian) {
      const int cols = body::NumJacobianColumns(*model_);
      Eigen::MatrixXd& J = (*joint_jacobians)[f];
      J.resize(3 * kNumStateJoints, cols);
      for (int r = 0; r < 3 * kNumStateJoints; ++r) J.row(r) = Eigen::Map<const Eigen::RowVectorXd>(points.jacobian_row(r), cols);
    }
  }
  const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>& R = ground_R_;
  for (int s = 0; s < 2; ++s) {
    double* x = s == 0 ? x0 : x1;
    if (!with_jacobian) {
      const double* trans[3] = {parameters[3 * s], parameters[3 * (s + 1)], parameters[3 * (s + 2)]};
      const double* root[3] = {parameters[3 * s + 1], parameters[3 * (s + 1) + 1], parameters[3 * (s + 2) + 1]};
      const double* jo[3] = {joints[s].data(), joints[s + 1].data(), joints[s + 2].data()};
      nn::humor::BuildState(trans, root, jo, parameters[3 * (s + 1) + 2], fps_, R.data(), ground_t_.data(), x);
      continue;
    }
    // Jets seeded on the state builder's 279 inputs.
    std::vector<StateJet> in(kInputs), out(kStateDim);
    for (int k = 0; k < 3; ++k) {
      const int f = s + k;
      for (int i = 0; i < 3; ++i) {
        in[kTransIn + 3 * k + i] = StateJet(parameters[3 * f][i], kTransIn + 3 * k + i);
        in[kRootIn + 3 * k + i] = StateJet(parameters[3 * f + 1][i], kRootIn + 3 * k + i);
      }
      for (int i = 0; i < 3 * kNumStateJoints; ++i) {
        const int idx = kJointsIn + 3 * kNumStateJoints * k + i;
        in[idx] = StateJet(joints[f][i], idx);
      }
    }
    for (int i = 0; i < 3 * kNumBodyJoints; ++i) in[kPoseIn + i] = StateJet(parameters[3 * (s + 1) + 2][i], kPoseIn + i);
    std::vector<StateJet> Rj(9), tj(3);
    for (int i = 0; i < 9; ++i) Rj[i] = StateJet(R.data()[i]);
    for (int i = 0; i < 3; ++i) tj[i] = StateJet(ground_t_[i]);
    const StateJet* trans[3] = {&in[kTransIn], &in[kTransIn + 3], &in[kTransIn + 6]};
    const StateJet* root[3] = {&in[kRootIn], &in[kRootIn + 3], &in[kRootIn + 6]};
    const StateJet* jo[3] = {&in[kJointsIn], &in[kJointsIn + 3 * kNumStateJoints], &in[kJointsIn + 6 * kNumStateJoints]};
    nn::humor::BuildState(trans, root, jo, &in[kPoseIn], fps_, Rj.data(), tj.data(), out.data());
    Eigen::MatrixXd& dx = s == 0 ? *dx0 : *dx1;
    dx.resize(kStateDim, kInputs);
    for (int i = 0; i < kStateDim; ++i) {
      x[i] = out[i].a;
      dx.row(i) = out[i].v.transpose();
    }
  }
}

double HumorTransitionCost::Nll(double const* const* parameters) const {
  std::vector<double> x0(kStateDim), x1(kStateDim);
  States(parameters, x0.data(), x1.data(), nullptr, nullptr, nullptr);
  double value = 0.0;
  prior_->TransitionNll(1, x0.data(), x1.data(), &value, nullptr, nullptr);
  return value;
}

bool HumorTransitionCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  std::vector<double> x0(kStateDim), x1(kStateDim), g0(kStateDim), g1(kStateDim);
  Eigen::MatrixXd dx0, dx1;
  std::vector<Eigen::MatrixXd> joint_jac;
  States(parameters, x0.data(), x1.data(), jacobians ? &dx0 : nullptr, jacobians ? &dx1 : nullptr,
         jacobians ? &joint_jac : nullptr);
  double nll = 0.0;
  prior_->TransitionNll(1, x0.data(), x1.data(), &nll, jacobians ? g0.data() : nullptr, jacobians ? g1.data() : nullptr);
  if (!std::isfinite(nll)) return false;
  const double excess = weight_ * (nll - level_);
  const double r = std::sqrt(std::max(excess, 0.0));
  residuals[0] = r;
  if (!jacobians) return true;
  const int J = model_->num_joints(), B = model_->num_betas();
  for (int blk = 0; blk < 13; ++blk) {
    if (jacobians[blk]) std::fill(jacobians[blk], jacobians[blk] + parameter_block_sizes()[blk], 0.0);
  }
  if (r < 1e-9) return true;  // below the level the term is flat
  const double scale = weight_ / (2.0 * r);  // d sqrt(w (nll - c)) = w / (2 r) d nll
  for (int s = 0; s < 2; ++s) {
    const Eigen::VectorXd h = (s == 0 ? dx0 : dx1).transpose() *
                              Eigen::Map<const Eigen::VectorXd>((s == 0 ? g0 : g1).data(), kStateDim);  // 279
    for (int k = 0; k < 3; ++k) {
      const int f = s + k;
      const Eigen::MatrixXd& Jf = joint_jac[f];  // 66 x (3 + 3J + B): [transl | root | body | betas]
      const Eigen::RowVectorXd via_joints = h.segment(kJointsIn + 3 * kNumStateJoints * k, 3 * kNumStateJoints).transpose() * Jf;
      if (double* jt = jacobians[3 * f]) {
        for (int i = 0; i < 3; ++i) jt[i] += scale * (h[kTransIn + 3 * k + i] + via_joints[i]);
      }
      if (double* jr = jacobians[3 * f + 1]) {
        for (int i = 0; i < 3; ++i) jr[i] += scale * (h[kRootIn + 3 * k + i] + via_joints[3 + i]);
      }
      if (double* jb = jacobians[3 * f + 2]) {
        for (int i = 0; i < 3 * (J - 1); ++i) jb[i] += scale * via_joints[6 + i];
        if (k == 1) {
          for (int i = 0; i < 3 * kNumBodyJoints; ++i) jb[i] += scale * h[kPoseIn + i];
        }
      }
      if (double* jbeta = jacobians[12]) {
        for (int i = 0; i < B; ++i) jbeta[i] += scale * via_joints[3 + 3 * J + i];
      }
    }
  }
  return true;
}

}  // namespace m3c::motion
