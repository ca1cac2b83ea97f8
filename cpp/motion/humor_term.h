// HuMoR motion prior as Ceres residual blocks: the thesis's pairwise transition likelihood. For frames
// t-1..t+2 of a person, states x_t (frames t-1, t, t+1) and x_{t+1} (frames t, t+1, t+2) are built in the
// person's ground frame (z up, floor z = 0) and scored by NLL(x_{t+1} | x_t) = -log N(mu_enc(x_t, x_{t+1});
// mu_prior(x_t), sigma_prior(x_t)) (REFERENCE.md A). The NLL is not a sum of squares, so the residual is
// r = sqrt(weight (NLL - c)) with c a fixed level below the block's starting NLL: the objective is
// weight * NLL + const with the exact gradient; the Gauss-Newton model of the term is rank one.
//
// A block alone builds its four frames and two states and runs the networks on one transition. Inside a solve,
// HumorTransitionBatch (a Ceres EvaluationCallback) does that work once per evaluation point for all blocks, a
// chunk of consecutive transitions at a time: each frame's joints once (not four times; twice at a chunk's edge),
// each state once (not twice), the networks on one batch per chunk; the blocks then read their value and gradient
// from it.
#pragma once

#include <memory>
#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "body/body_model.h"
#include "nn/humor.h"

namespace m3c::motion {

class HumorTransitionBatch;
struct HumorContext;  // a person's model, networks, frame rate and ground frame (humor_term.cc)

class HumorTransitionCost : public ceres::CostFunction {
 public:
  // ground_R (3x3) and ground_t take world points into the ground frame: p_ground = R p + t.
  // Blocks: for k = 0..3: transl_k, root_k, body_k; then betas. Residuals: 1.
  HumorTransitionCost(const body::BodyModel* model, const nn::HumorPrior* prior, double fps,
                      const Eigen::Matrix3d& ground_R, const Eigen::Vector3d& ground_t, double weight, double level);
  // Transition `index` of `batch` (which must outlive the cost): values come from the batch when it was last
  // evaluated at these parameters, else the block computes them itself.
  HumorTransitionCost(const HumorTransitionBatch* batch, int index, double weight, double level);
  ~HumorTransitionCost() override;
  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  // NLL of the transition at the given parameter blocks (for choosing `level`).
  double Nll(double const* const* parameters) const;

 private:
  std::shared_ptr<const HumorContext> context_;
  const HumorTransitionBatch* batch_ = nullptr;
  int index_ = -1;
  double weight_, level_;
};

class HumorTransitionBatch : public ceres::EvaluationCallback {
 public:
  // num_threads: threads for the frames, states and network batches; chunk: transitions evaluated together (their
  // frames' and states' Jacobians are held for one chunk at a time; by default the networks' own chunk, so each
  // network batch is the same as over all transitions at once).
  HumorTransitionBatch(const body::BodyModel* model, const nn::HumorPrior* prior, double fps, int num_threads,
                       int chunk = nn::HumorPrior::kBatchChunk);
  ~HumorTransitionBatch() override;

  // A person's parameter blocks per frame (n >= 4 frames) and its ground frame; its transitions are frames
  // f-1..f+2 for f = 1..n-3.
  void AddTrack(const std::vector<double*>& transl, const std::vector<double*>& root, const std::vector<double*>& body,
                double* betas, const Eigen::Matrix3d& ground_R, const Eigen::Vector3d& ground_t);
  int num_transitions() const { return static_cast<int>(transitions_.size()); }
  // Parameter blocks of transition i, in HumorTransitionCost's order, and the context of its person.
  std::vector<double*> Parameters(int i) const;
  std::shared_ptr<const HumorContext> Context(int i) const;
  // NLL of every transition at the blocks' current values.
  std::vector<double> Nll();

  void PrepareForEvaluation(bool evaluate_jacobians, bool new_evaluation_point) override;

  // Transition i's NLL (and, if grad is not null, its gradient packed block after block) from the last
  // evaluation, if that was at `parameters` (and computed gradients when asked for). False otherwise.
  bool Lookup(int i, double const* const* parameters, double* nll, double* grad) const;

 private:
  struct TrackBlocks;
  struct Transition {
    int track, frame;  // frames frame-1..frame+2 of the track
  };
  void Evaluate(bool with_gradient);
  bool InputsUnchanged() const;  // the blocks hold the values of the last evaluation

  const body::BodyModel* model_;
  const nn::HumorPrior* prior_;
  std::shared_ptr<const body::KeypointRegressor> joints_;
  double fps_;
  int num_threads_, chunk_;
  std::vector<TrackBlocks> tracks_;
  std::vector<Transition> transitions_;
  // The last evaluation: its inputs, per transition NLL and packed gradient.
  struct Cache;
  std::unique_ptr<Cache> cache_;
};

// The transform into HuMoR's ground frame for a world plane n.x + d = 0 (n the unit up normal): rows e1, e2, n
// with e1, e2 spanning the plane; t = (0, 0, d), so z = height above the floor.
void GroundFrame(const Eigen::Vector3d& normal, double offset, Eigen::Matrix3d* R, Eigen::Vector3d* t);

}  // namespace m3c::motion
