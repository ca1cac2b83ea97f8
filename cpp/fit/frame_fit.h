// Camera-local body fit, one frame at a time (the offline stand-in for HMR 2.0, thesis 4.1.2): the body model's
// pose, shape and camera-frame translation fitted to 2D keypoints with a robust reprojection term and, when a
// monocular 3D pose is available (MediaPipe's metric landmarks), a weak root-relative 3D term, with Gaussian
// pose and shape priors. Frames of one track are warm-started from the previous frame's fit, with temporal
// priors towards it; a warm fit whose torso ends turned far from the 3D torso is solved again turned as the 3D
// torso, and one that ends far from the keypoints is retried from a cold initialisation (see Fit for which one
// is kept).
//
// Cold initialisation: the root orientation from the 3D torso (Kabsch) or, without 3D, from which side of the
// image the person's left shoulder and hip appear on (facing the camera or away from it); the body pose from a
// 3D-only solve when 3D is given; the translation from the linear least-squares solution of the projection
// equations (u - cx)(z_k + t_z) = fx (x_k + t_x) (and likewise for v) of the posed keypoints.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "body/body_model.h"
#include "fit/costs.h"
#include "nn/vposer.h"

namespace m3c::fit {

struct FitOptions {
  double robust_sigma_px = 30.0;       // Geman-McClure scale of the reprojection term, pixels
  double min_confidence = 0.3;         // 2D/3D keypoints below it are ignored
  int min_keypoints = 6;               // fewer confident 2D keypoints: the frame is not fitted
  double keypoints3d_weight = 400.0;   // weak 3D term, per m^2 (5 cm error ~ 1 px of reprojection)
  double keypoints3d_sigma = 0.15;     // its Geman-McClure scale, metres
  double pose_prior_weight = 5.0;      // body pose towards 0, per rad^2
  // With a learned pose prior (BodyFitter's vposer): weight of |z(theta)|^2, z VPoser's encoder mean of the body
  // pose (SMPLify-X's prior: the latent is standard normal over real poses), in the objective's units (pixels^2
  // of reprojection). On synthetic mocap poses seen from the side and the front with the far arm's keypoints
  // noisy (3 px, 12 px on the far elbow and wrist), PA-MPJPE without the prior 54 / 73 mm, at 0.5: 58 / 55, at
  // 2: 46 / 51, at 8: 51 / 65, at 32: 70 / 77; the far elbow and wrist 91 / 122 -> 73 / 79 mm at 2. 0: none.
  double vposer_weight = 2.0;
  double shape_prior_weight = 10.0;    // betas towards 0
  double temporal_pose_weight = 20.0;  // body pose towards the previous frame's, per rad^2
  double temporal_betas_weight = 100.0;  // betas towards the previous frame's
  // Translation towards its constant-velocity prediction from the previous two fits, per m^2: monocular depth
  // is weakly observed (body size against image size, which the shape can trade), so frame-to-frame depth jitter
  // would read as motion. Weak on purpose: at 3000 the prediction carried the depth itself, a velocity read off
  // each small correction feeding the next, and a person standing 9 m away wandered by metres over seconds (the
  // basketball clip's standing man between 6.6 and 12.8 m; a synthetic one with 2 px of keypoint noise: 1.2 m sd).
  // Slow wandering survives every smoothing downstream; jitter does not. At 100: 0.2 m sd, 6 cm frame to frame.
  double temporal_transl_weight = 100.0;
  bool optimize_betas = true;
  double min_depth = 0.1;              // metres in front of the camera
  int max_iterations = 40;
  double reinit_error_px = 20.0;       // a warm start ending above this mean error is retried cold
  // A warm fit whose torso ends turned more than this (degrees) from the monocular 3D torso is solved again
  // turned as the 3D torso (see Fit). In a side view the 2D keypoints cannot tell which way the body faces,
  // and the 3D term, robust, barely pulls a torso that is half a turn off: a warm start on the wrong side
  // stayed there for seconds. Negative: never.
  double max_turn_from_3d_deg = 90.0;
  // A warm fit with a limb end (limbs below) farther than this (metres) from the monocular 3D, root-relative, is
  // solved again with its body pose started from the rest pose posed by the 3D alone (see Fit). Seen from behind
  // or in front, a far foot higher in the image fits a knee bent backwards as well as a step forward, and the
  // robust 3D term barely pulls a limb that far off: the bundled walker's left knee, once bent, stayed bent at
  // 60-90 degrees for 5 s while MediaPipe's 3D had his feet taking turns. Negative: never.
  double max_limb_from_3d_m = 0.25;
  // Keypoint roles, as indices into the regressor's keypoints (COCO-17 defaults).
  std::vector<int> torso = {5, 6, 11, 12};       // orientation from 3D (Kabsch)
  std::vector<int> reference_3d = {11, 12};      // origin of the relative 3D observations (hip centre)
  std::vector<int> left_side = {5, 11};          // person's left shoulder and hip ...
  std::vector<int> right_side = {6, 12};         // ... and right ones: facing direction from 2D
  std::vector<int> limbs = {7, 8, 9, 10, 13, 14, 15, 16};  // elbows, wrists, knees, ankles: checked against 3D
};

struct FrameObservation {
  Observations3 keypoints;    // (K, 3): u, v (pixels), confidence; confidence 0 = missing
  Observations4 keypoints3d;  // (K, 4): x, y, z (metres, camera axes, any origin), confidence; or empty
  Intrinsics intrinsics;
};

struct BodyState {
  Eigen::Vector3d transl = Eigen::Vector3d::Zero();  // camera frame, metres
  Eigen::Vector3d root = Eigen::Vector3d::Zero();    // axis-angle, body to camera
  Eigen::VectorXd body;                              // 3(J-1) axis-angle
  Eigen::VectorXd betas;                             // B
};

struct FrameFitResult {
  BodyState state;
  std::string status;              // "ok", "too_few_keypoints" (state = the warm start or the initialisation)
  double reprojection_error_px = 0.0;  // mean over keypoints with confidence >= min_confidence
  Eigen::VectorXd keypoint_error_px;   // (K) pixel distance per keypoint, -1 where the point is behind the camera
  int num_keypoints = 0;               // keypoints used (confidence >= min_confidence)
  int iterations = 0;
  double cost = 0.0;                   // final objective
  bool warm_started = false;           // the kept solution started from the previous frame
};

class BodyFitter {
 public:
  // vposer (may be nullptr; must outlive the fitter): the learned pose prior weighted by options.vposer_weight.
  BodyFitter(const body::BodyModel* model, const body::KeypointRegressor* regressor, FitOptions options,
             const nn::VPoser* vposer = nullptr);

  // One frame; previous (may be nullptr) is the same person's fit in the previous frame, predicted_transl
  // (may be nullptr) where its translation is expected now.
  FrameFitResult Fit(const FrameObservation& observation, const BodyState* previous,
                     const Eigen::Vector3d* predicted_transl = nullptr) const;

  // A track's frames in order: frame i is warm-started from the last good fit unless restart[i] (restart may
  // be empty: only frame 0 starts cold), and its translation predicted at constant velocity from the last two
  // good fits when both were warm-started (never across a cold fit). times (seconds or frame numbers,
  // increasing; may be empty = 0, 1, 2, ...) space the frames.
  // Frames that cannot be fitted pass the last good state on.
  std::vector<FrameFitResult> FitSequence(const std::vector<FrameObservation>& observations,
                                          const std::vector<char>& restart,
                                          const std::vector<double>& times = {}) const;

  // The cold initialisation alone (exposed for tests and diagnostics).
  BodyState Initialize(const FrameObservation& observation) const;

  const FitOptions& options() const { return options_; }

 private:
  struct Masked {
    Observations3 keypoints;
    Observations4 keypoints3d;  // empty when unusable
    int num_keypoints = 0;
  };
  Masked Mask(const FrameObservation& observation) const;
  BodyState ColdState(const FrameObservation& observation, const Masked& masked) const;
  // Adds the active terms over `state`'s memory to `problem` (the temporal ones with previous / predicted_transl).
  void AddTerms(const FrameObservation& observation, const Masked& masked, const BodyState* previous,
                const Eigen::Vector3d* predicted_transl, bool use_reprojection, BodyState* state,
                ceres::Problem* problem) const;
  // The frame's own objective at `state`: keypoints, 3D and priors, without the temporal terms.
  double FrameCost(const FrameObservation& observation, const Masked& masked, BodyState state) const;
  // Solves AddTerms' problem over `state` (pose and betas held unless free_pose). Returns the final cost.
  double Solve(const FrameObservation& observation, const Masked& masked, const BodyState* previous,
               const Eigen::Vector3d* predicted_transl, bool free_pose, bool use_reprojection, BodyState* state,
               int* iterations) const;
  void Measure(const FrameObservation& observation, const Masked& masked, FrameFitResult* result) const;
  // The largest root-relative distance (metres) of a `limbs` keypoint from its 3D observation; -1 without 3D.
  double LimbErrorFrom3d(const Masked& masked, const BodyState& state) const;
  // The state's keypoints (K, 3) in the camera frame, or root-relative (no translation) when !translated.
  Observations3 Posed(const BodyState& state, bool translated) const;
  // R rotating `points`' torso keypoints onto the 3D torso (Kabsch); false when fewer than 3 have 3D.
  bool TorsoTo3d(const Masked& masked, const Observations3& points, Eigen::Matrix3d* R) const;
  // Degrees between the state's torso keypoints and the 3D torso (the Kabsch rotation's angle); -1 when fewer
  // than 3 torso keypoints have 3D.
  double TorsoTurnFrom3d(const Masked& masked, const BodyState& state) const;
  void Validate(const FrameObservation& observation) const;

  const body::BodyModel* model_;
  const body::KeypointRegressor* regressor_;
  FitOptions options_;
  const nn::VPoser* vposer_;
};

}  // namespace m3c::fit
