// Staged world-frame optimization of every person's motion (thesis 4.1.4 / SLAHMR), all people in one problem
// sharing the camera scale. Stage k is a Levenberg-Marquardt solve of a Ceres problem over the terms active in it
// (Ceres's iteration, motion/lm_solver.h, or ceres::Solve: OptimizerConfig::minimizer); a stage that fails (solver
// failure, non-finite values, a worse objective) is reverted to the last good state and the run stops cleanly.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "body/body_model.h"
#include "motion/costs.h"
#include "nn/humor.h"
#include "nn/vposer.h"

namespace m3c::motion {

// One person, frames [first_frame, first_frame + n). Arrays have n rows.
struct TrackInput {
  int first_frame = 0;
  RowMatrixXd keypoints;  // (n, 3K): u, v, confidence per keypoint of `keypoint_regressor`; confidence 0 = missing
  RowMatrixXd transl;     // (n, 3) initial world-frame root translation
  RowMatrixXd root;       // (n, 3) initial world-frame root orientation, axis-angle
  RowMatrixXd body;       // (n, 3(J-1)) initial body pose
  Eigen::VectorXd betas;  // (B)
  RowMatrixXd ground_normal;      // (n, 3) ground plane normal in each frame's camera coordinates, or empty
  Eigen::VectorXd ground_offset;  // (n) plane offset d_c in metres: n_c . x_cam + d_c = 0
  RowMatrixXd contacts;  // (n, C) contact probabilities of `contact_regressor` points, or empty
  // (n, C) the points surely on the ground (contact_height pulls them onto it), or empty: `contacts`. Planted
  // feet (contact_velocity holds them still) are more than those standing on the ground: a monocular fit's
  // lifting heel may be planted, and pulling it down sinks the body.
  RowMatrixXd ground_contacts;
  // (C) each contact point's height above the ground when it stands on it (a joint's height above the sole in
  // the rest pose: the ankle's about 7 cm, the toes' joint 2.5): contact_height holds planted points there and
  // ground_penetration keeps every point above it; empty: 0.
  Eigen::VectorXd contact_heights;
};

struct CameraInput {
  std::vector<Eigen::Matrix4d> world_from_cam;  // (T) from VO, translation up to scale
  RowMatrixXd intrinsics;                       // (T, 4): fx, fy, cx, cy
  bool static_camera = false;                   // freezes the scale (it is unobservable)
  double initial_scale = 1.0;                   // metric translation = scale * VO translation, at the start
  // Standard deviation of log(initial_scale), the scale estimator's uncertainty (m3c.vo.scale): the
  // "scale_prior" term holds the scale to the estimate within it. <= 0 or non-finite: no prior (the term adds
  // nothing).
  double scale_sigma = 0.0;
  // (T) each frame's time in seconds, increasing, for a video whose frame rate varies; empty: equally spaced.
  // The joint and contact stencils are then the finite differences at these times, in units of the median step
  // (equal to the equally spaced ones when the steps are). The motion prior still takes frames as equally spaced.
  std::vector<double> times;
};

// Which parameter groups a stage frees and which terms it minimises (weight 0 = inactive).
struct StageConfig {
  std::string name;
  bool transl = true, root = false, body = false, betas = false, scale = false, offset = false;
  std::map<std::string, double> weights;  // term name -> weight
  int max_iterations = 20;
};

struct OptimizerConfig {
  double robust_sigma = 100.0;        // Geman-McClure scale, pixels
  double min_confidence = 0.4;        // keypoints below it are ignored (SLAHMR)
  double contact_threshold = 0.5;     // contact probability that activates contact terms
  // Metres above/below its standing height (TrackInput::contact_heights) allowed for a planted contact point.
  double contact_height_tolerance = 0.03;
  // Geman-McClure scale of "contact_velocity", metres per frame step (0: plain squares): a foot labelled planted
  // that moves much faster (a mislabelled swing) pulls with a bounded force.
  double contact_velocity_sigma = 0.02;
  double upright_sigma = 0.2;  // Geman-McClure scale of "upright", metres of the spine across the up direction
  double min_depth = 0.05;            // metres in front of the camera
  // A frame with at least this many keypoints of confidence >= min_confidence is well seen; "end_motion_anchor"
  // holds the steps of a track's frames before its first and after its last well-seen frame.
  int well_seen_keypoints = 12;
  bool optimize_offset = false;       // a shared camera translation offset (off: people's translations cover it)
  // A stage must not make the world worse: after each stage the world check (these terms at these weights,
  // evaluated over every person and frame: the images, jitter, planted feet, the ground) is compared with its
  // value before the stage, and a stage that raised it by more than max_world_increase (relative) is reverted
  // and the next stage goes on from the state before it.
  std::map<std::string, double> world_check;
  double max_world_increase = 0.05;
  // With a VPoser (SetPosePrior), the body pose of joints 1..21 is optimised as VPoser latents, SLAHMR's pose
  // variables (initialised by encoding the initial pose; SMPL's hand joints stay fixed); otherwise as axis-angle
  // under the VPoser prior on the encoded pose.
  bool latent_pose = true;
  int num_threads = 2;
  // Which minimizer solves a stage: "m3c", Ceres's Levenberg-Marquardt iteration with M3C's assembly of the
  // normal equations (motion/lm_solver.h, the same steps and costs, faster), or "ceres", ceres::Solve itself
  // (the reference; a stage with a bounded parameter, a freed camera scale, always takes it).
  std::string minimizer = "m3c";
  std::vector<StageConfig> stages;
};

// The thesis's recipe as Ceres stages, with SLAHMR's weights (REFERENCE.md B) and the departures its
// definition lists (acceleration instead of velocity smoothing, pose_anchor instead of an L2 pose prior).
OptimizerConfig DefaultOptimizerConfig();

struct TermCost {
  std::string term;
  double before = 0.0, after = 0.0;
};

struct StageReport {
  std::string name;
  std::string status;  // "ok", "reverted", "skipped"
  double world_before = 0.0, world_after = 0.0;  // the world check (OptimizerConfig::world_check)
  std::string message;
  int iterations = 0;  // with several parts, the most any part took
  int parts = 1;       // problems the stage was solved as: one per person where they share no free parameter
                       // (1 for a skipped stage)
  double seconds = 0.0;
  double objective_before = 0.0, objective_after = 0.0;
  double scale = 1.0;  // camera scale after the stage
  std::vector<TermCost> terms;
};

struct TrackResult {
  RowMatrixXd transl, root, body;
  Eigen::VectorXd betas;
  RowMatrixXd latent;  // (n, 32) VPoser latents of the body pose when it was optimised as latents, else empty
};

struct OptimizerResult {
  std::vector<TrackResult> tracks;
  double scale = 1.0;
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  std::vector<StageReport> stages;
  bool stopped_early = false;
};

class WorldOptimizer {
 public:
  // The problem's parameter memory, for extra terms: per track and frame pointers into the blocks.
  struct Variables {
    std::vector<std::vector<double*>> transl, root, body;  // [track][frame]
    // [track][frame] VPoser latents when the pose is latent (then body blocks hold the decoded pose and stay
    // constant in the solves: an extra term on body poses must use the latents); else empty.
    std::vector<std::vector<double*>> latent;
    std::vector<double*> betas;                            // [track]
    double* scale;
    double* offset;
    // Adds a residual block whose cost takes whole body blocks (body[track][frame]): the problem holds the body
    // pose as per-joint blocks (or as latents), and this wraps the cost to take those. A term on body poses must
    // add its blocks through it; blocks of other groups may be given to problem->AddResidualBlock directly.
    std::function<ceres::ResidualBlockId(ceres::Problem*, ceres::CostFunction*, std::vector<double*>)> add_block;
  };
  // Adds residual blocks of an extra term (e.g. a learned motion prior) to `problem` with `weight`, without Ceres
  // loss functions (a stage reports each term's cost as half its squared residuals; a robust term puts its
  // robustness into the residual, as ReprojectionCost does).
  using TermBuilder = std::function<void(ceres::Problem* problem, const Variables& variables, double weight)>;

  WorldOptimizer(const body::BodyModel* model, const body::KeypointRegressor* keypoint_regressor,
                 const body::KeypointRegressor* contact_regressor, OptimizerConfig config);

  // Registers a term by name; stages activate it through their weights map.
  void AddTerm(const std::string& name, TermBuilder builder);

  // Enables the "pose_prior" (|z_t|^2) and "latent_smoothness" (|z_{t+1} - z_t|^2) terms, z_t the VPoser
  // encoder mean of frame t's body pose (vposer_term.h). Without it they are reported unavailable.
  void SetPosePrior(const nn::VPoser* vposer);

  // Enables the "motion_prior" term: HuMoR's transition likelihood of consecutive states (humor_term.h) for
  // every person with a ground plane. fps is the video's frame rate (HuMoR was trained at 30).
  void SetMotionPrior(const nn::HumorPrior* prior, double fps);

  OptimizerResult Optimize(const std::vector<TrackInput>& tracks, const CameraInput& cameras);

  // Names of the built-in terms (always available).
  static const std::vector<std::string>& BuiltinTerms();
  // Names of the terms that need learned weights: pose_prior, latent_smoothness (VPoser), motion_prior (HuMoR).
  static const std::vector<std::string>& LearnedTerms();

 private:
  const body::BodyModel* model_;
  const body::KeypointRegressor* keypoint_regressor_;
  const body::KeypointRegressor* contact_regressor_;
  std::unique_ptr<body::KeypointRegressor> joint_regressor_;
  OptimizerConfig config_;
  std::vector<std::pair<std::string, TermBuilder>> terms_;
  const nn::HumorPrior* motion_prior_ = nullptr;
  const nn::VPoser* pose_prior_ = nullptr;
  double fps_ = 30.0;
};

}  // namespace m3c::motion
