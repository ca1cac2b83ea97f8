// HuMoR motion prior as Ceres residual blocks: the thesis's pairwise transition likelihood. For frames
// t-1..t+2 of a person, states x_t (frames t-1, t, t+1) and x_{t+1} (frames t, t+1, t+2) are built in the
// person's ground frame (z up, floor z = 0) and scored by NLL(x_{t+1} | x_t) = -log N(mu_enc(x_t, x_{t+1});
// mu_prior(x_t), sigma_prior(x_t)) (REFERENCE.md A). The NLL is not a sum of squares, so the residual is
// r = sqrt(weight (NLL - c)) with c a fixed level below the block's starting NLL: the objective is
// weight * NLL + const with the exact gradient; the Gauss-Newton model of the term is rank one.
#pragma once

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "body/body_model.h"
#include "nn/humor.h"

namespace m3c::motion {

class HumorTransitionCost : public ceres::CostFunction {
 public:
  // ground_R (row-major 3x3) and ground_t take world points into the ground frame: p_ground = R p + t.
  // Blocks: for k = 0..3: transl_k, root_k, body_k; then betas. Residuals: 1.
  HumorTransitionCost(const body::BodyModel* model, const nn::HumorPrior* prior, double fps,
                      const Eigen::Matrix3d& ground_R, const Eigen::Vector3d& ground_t, double weight, double level);
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // NLL of the transition at the given parameter blocks (for choosing `level`).
  double Nll(double const* const* parameters) const;

 private:
  // Builds both states and, when wanted, d state / d (inputs of the state builder).
  void States(double const* const* parameters, double* x0, double* x1, Eigen::MatrixXd* dx0,
              Eigen::MatrixXd* dx1, std::vector<Eigen::MatrixXd>* joint_jacobians) const;

  const body::BodyModel* model_;
  const nn::HumorPrior* prior_;
  std::unique_ptr<body::KeypointRegressor> joints_;
  double fps_;
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> ground_R_;
  Eigen::Vector3d ground_t_;
  double weight_, level_;
};

// The transform into HuMoR's ground frame for a world plane n.x + d = 0 (n the unit up normal): rows e1, e2, n
// with e1, e2 spanning the plane; t = (0, 0, d), so z = height above the floor.
void GroundFrame(const Eigen::Vector3d& normal, double offset, Eigen::Matrix3d* R, Eigen::Vector3d* t);

}  // namespace m3c::motion
