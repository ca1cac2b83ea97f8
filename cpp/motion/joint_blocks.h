// The body pose as one parameter block per joint, and the world joints shared between the residual blocks that
// read them. Why: the joint acceleration term reads every joint of three frames; as one residual block over three
// whole pose blocks (3 x 75 values + betas for 72 residuals) Ceres spent half of each iteration forming its part
// of J^T J. A joint's position depends only on its ancestors' rotations, so with a block per joint and a residual
// block per chain of the skeleton (a leg, an arm, the spine: SharedJoints::Chains) the term touches about a
// quarter of the values. (A residual block per joint touches fewer still, but Ceres's cost per pair of blocks
// in a residual block then dominates.) The joints of each frame, with their Jacobians, are evaluated once per
// evaluation point by SharedJoints (the problem's evaluation callback), not once per residual block that reads
// them.
#pragma once

#include <memory>
#include <vector>

#include <ceres/ceres.h>

#include "body/block_points.h"
#include "body/body_model.h"

namespace m3c::motion {

// The joints (a KeypointRegressor of joints only: IdentityJointRegressor) of registered frames, with Jacobians.
class SharedJoints {
 public:
  SharedJoints(const body::BodyModel* model, const body::KeypointRegressor* joints, int num_threads);
  // Registers a frame by its parameter memory (transl 3, root 3, body 3(J-1), betas B). Returns its index.
  int AddFrame(const double* transl, const double* root, const double* body, const double* betas);
  int num_frames() const { return static_cast<int>(frames_.size()); }
  const body::BodyModel& model() const { return *model_; }
  // Evaluates every frame from its parameter memory (Ceres writes the evaluation point there before it calls the
  // problem's evaluation callback).
  void EvaluateAll(bool with_jacobian);
  // For the problem's evaluation callback: EvaluateAll when the point is new or Jacobians are wanted that the
  // last evaluation did not compute.
  void PrepareForEvaluation(bool evaluate_jacobians, bool new_evaluation_point) {
    if (new_evaluation_point || !evaluated_ || (evaluate_jacobians && !with_jacobian_)) EvaluateAll(evaluate_jacobians);
  }
  // Frees the evaluation (its Jacobians, ~50 KB a frame); the next PrepareForEvaluation evaluates again.
  void Release();
  // Frame i's joints at these values of the blocks that move the joints of interest (transl, root, the body
  // blocks of `ancestors`, a union of Ancestors(), betas; other body values do not move them): the cached
  // evaluation when it was at these values, else computed into `scratch` (valid for those joints only).
  const body::BlockPoints& Get(int i, const std::vector<int>& ancestors, const double* transl, const double* root,
                               const std::vector<const double*>& ancestor_blocks, const double* betas,
                               bool with_jacobian, body::BlockPoints* scratch) const;
  // Body joints (1..J-1) whose rotation moves joint `joint`: its strict ancestors below the root, root first.
  std::vector<int> Ancestors(int joint) const;
  // The skeleton's chains, every joint in one: a chain starts at the root or at a child of a joint with several
  // children and runs on through joints with one child (SMPL: the pelvis, each leg, the spine, neck and head,
  // each arm from the collar). A chain's joints are moved by its last joint's strict ancestors.
  std::vector<std::vector<int>> Chains() const;

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* joints_;
  int num_threads_;
  struct Frame {
    const double *transl, *root, *body, *betas;
  };
  std::vector<Frame> frames_;
  std::vector<body::BlockPoints> points_;
  std::vector<std::vector<double>> values_;  // per frame, the parameter values of the last evaluation
  bool evaluated_ = false, with_jacobian_ = false;
};

// sqrt(w_j) sum_f c_f p_j(frame f) for joints j (a chain, or one joint): a finite-difference stencil over
// consecutive frames (the acceleration c = 1, -2, 1 of "joint_acceleration", the velocity c = -1, 1 of
// "joint_smoothness" and "contact_velocity"); over every chain it equals PointStencilCost on all joints (with
// sigma > 0 robust as it: RobustPointRows). Blocks: per stencil frame transl, root, then the joint blocks of
// `ancestors()` (the joints' strict ancestors, in joint order); last betas. Residuals: 3 per joint.
class JointStencilCost : public ceres::CostFunction {
 public:
  JointStencilCost(const SharedJoints* shared, std::vector<int> frames, std::vector<double> stencil,
                   std::vector<int> joints, std::vector<double> weights, double sigma = 0.0);
  const std::vector<int>& ancestors() const { return ancestors_; }
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

 private:
  const SharedJoints* shared_;
  std::vector<int> frames_, joints_, ancestors_;
  std::vector<double> stencil_, sqrt_weights_;
  double sigma_;
};

// The joints a regressor selects when each of its points is one body joint with weight 1 (the contact points),
// else empty.
std::vector<int> SelectedJoints(const body::KeypointRegressor& regressor);

// The body joints (1..J-1) whose rotation moves a point of `regressor`, in joint order: for its joints their strict
// ancestors; for its vertices their skinning joints with those joints' ancestors, and the joints whose pose blend
// shapes move them (SMPL's move every vertex a little; a model without them, none).
std::vector<int> MovingJoints(const body::BodyModel& model, const body::KeypointRegressor& regressor);

// A cost written for whole body-pose blocks (3(J-1) values) on per-joint blocks: each of the `slots` of `inner`
// (owned) becomes a block of 3 per body joint of `joints` (1..J-1, increasing; empty: all J-1) in its place, in
// joint order. The joints left out must not move the cost (MovingJoints): the inner cost reads them as zero, and
// Ceres forms J^T J over every pair of a residual block's parameter blocks, zero ones included.
class SplitBodyCost : public ceres::CostFunction {
 public:
  SplitBodyCost(ceres::CostFunction* inner, const std::vector<int>& slots, std::vector<int> joints = {});
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;
  // The body joints given a block, in joint order (all J-1 when constructed with none).
  const std::vector<int>& joints() const { return joints_; }

 private:
  std::unique_ptr<ceres::CostFunction> inner_;
  std::vector<bool> split_;  // per inner block, whether it is a body block split per joint
  std::vector<int> first_;   // per inner block, its first block here
  std::vector<int> joints_;
};

}  // namespace m3c::motion
