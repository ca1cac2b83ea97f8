// Patch visual odometry: DPVO's patch graph and sliding-window bundle adjustment on a replaceable front-end.
//
// Per frame:
//  1. every live patch (host within `patch_lifetime` keyframes of the new frame) is measured in the new frame by
//     the front-end (forward edges); the initial guess is the patch's reprojection under the predicted pose;
//  2. before initialisation a frame whose median patch motion since the last keyframe is below `init_min_flow_px`
//     is not added (DPVO's motion probe); after it the frame's pose is fitted motion-only to the map and the frame
//     enters the graph as a keyframe when its flow from the last keyframe reaches `new_keyframe_flow_px`
//     (0: every frame enters, as in DPVO);
//  3. a new keyframe gets `patches_per_frame` patches (gradient-biased, human masks zero the gradient), with
//     inverse depth from the depth map when one is given (scale-aligned to the map), else the median of recent
//     patches (DPVO); they are measured back in the previous `backward_frames` keyframes (backward edges);
//  4. once `init_frames` keyframes exist, `init_iterations` of bundle adjustment initialise the map; afterwards
//     each keyframe triggers a window BA: poses of the last `optimization_window` keyframes free, earlier ones
//     fixed, edges of patches hosted in the last `removal_window` keyframes;
//  5. keyframe removal: keyframe K-keyframe_index is dropped when the mean flow between its neighbours,
//     beta * |full flow| + (1 - beta) * |translation-only flow| (DPVO's flow_mag), is below keyframe_threshold_px;
//     its pose is kept relative to the previous keyframe.
// Finish(): a final bundle adjustment over all keyframes; non-keyframe poses are composed from their stored
// relative pose (DPVO's interpolation of removed frames), or interpolated between the surrounding keyframes for
// frames skipped before initialisation, and then refined motion-only against the final map.
// A camera whose patches never move init_min_flow_px (median) away from the first keyframe is reported static:
// translation zero, rotation fitted to the patches taken at infinity.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "util/pinhole.h"
#include "vo/front_end.h"
#include "vo/lk_front_end.h"
#include "vo/patch_ba.h"
#include "vo/rigid3.h"

namespace m3c::vo {

struct PatchVOOptions {
  // Processing resolution: images larger than this (longer side, pixels) are downscaled; 0 keeps the input size.
  int max_image_side = 640;
  // Patch graph. DPVO uses 96 patches, lifetime 13, window 10, removal 22, keyframe index 4 on a GPU; these CPU
  // defaults are smaller (measured: same accuracy on the synthetic tests, ~2x faster).
  int patches_per_frame = 64;
  int patch_lifetime = 10;
  int backward_frames = 3;
  int optimization_window = 8;
  int removal_window = 16;
  int keyframe_index = 4;
  double keyframe_threshold_px = 12.0;  // DPVO removal test, at processing resolution
  // After initialisation a frame enters the graph only if its flow from the last keyframe (same measure) is at
  // least this; 0 adds every frame as DPVO does and leaves thinning to the removal test.
  double new_keyframe_flow_px = 6.0;
  double flow_beta = 0.5;
  // Initialisation.
  int init_frames = 8;
  double init_min_flow_px = 3.0;  // median of forward-backward-checked measurements
  int init_iterations = 12;
  bool init_multi_start = true;  // also start the first BA from straight motions along the camera axes
  double motion_damping = 0.5;  // DPVO's DAMPED_LINEAR motion model
  // Bundle adjustment.
  int window_iterations = 4;
  int final_iterations = 25;
  double loss_scale_px = 1.5;
  double outlier_threshold_px = 3.0;
  int num_threads = 1;
  bool refine_non_keyframes = true;
  int min_refine_observations = 12;
  // Depth maps (when given): used to initialise patch inverse depth.
  bool use_depth = true;
  int depth_window_px = 1;  // median over a (2r+1)^2 window around the patch centre
  // Texture: frames with fewer textured patches than this cannot start the map.
  int min_texture_patches = 12;
  LucasKanadeOptions lucas_kanade;
};

struct FrameQuality {
  int attempted = 0;        // patches the front-end tried to measure in this frame
  int tracked = 0;          // measurements that passed the front-end's checks
  int inliers = 0;          // measurements used by the final estimate with reprojection error < outlier threshold
  double reprojection_rms_px = 0.0;  // over the inliers, processing resolution; 0 if none
  bool keyframe = false;
  bool interpolated = false;  // skipped before initialisation: pose interpolated between the keyframes around it
  bool refined = false;       // a non-keyframe pose refined motion-only against the final map
};

struct PatchVOStats {
  int num_frames = 0;
  int num_keyframes = 0;
  int num_patches = 0;
  int num_observations = 0;
  int window_ba_count = 0;
  double window_ba_seconds = 0.0;
  int init_ba_starts = 0;
  int init_ba_iterations = 0;  // of the start that was kept
  double init_ba_initial_cost = 0.0;  // of the identity start
  double init_ba_final_cost = 0.0;
  double init_ba_seconds = 0.0;
  int final_ba_iterations = 0;
  double final_ba_seconds = 0.0;
  double front_end_seconds = 0.0;
  double total_seconds = 0.0;
  double keyframe_fit_rms_px = 0.0;  // PatchVO::FitRms() at the final estimate
};

// A patch of the final map: a 3D point with an inverse depth along its host pixel's ray.
struct MapPoint {
  Eigen::Vector3d world = Eigen::Vector3d::Zero();  // world = the first camera, VO units
  int host_frame = 0;                               // input frame index
  Eigen::Vector2d host_uv = Eigen::Vector2d::Zero();  // pixel in the host frame, input resolution
  int inlier_observations = 0;  // keyframe measurements with reprojection error < outlier threshold
};

struct PatchVOResult {
  std::vector<Rigid3> world_from_cam;  // one per input frame; world = the first camera
  // The final map: every patch hosted by a final keyframe that went through bundle adjustment, has positive
  // inverse depth and at least one inlier measurement. Empty for a static camera (no depth is observable).
  std::vector<MapPoint> points;
  Intrinsics intrinsics;               // at input resolution
  double processing_scale = 1.0;       // processing resolution / input resolution
  std::vector<FrameQuality> quality;
  bool static_camera = false;
  PatchVOStats stats;
  std::string message;
};

class PatchVO {
 public:
  // `intrinsics` at input resolution; invalid (all zero) means Intrinsics::Default of the first frame.
  explicit PatchVO(const PatchVOOptions& options = {}, const Intrinsics& intrinsics = {},
                   std::unique_ptr<FrontEnd> front_end = nullptr);
  ~PatchVO();

  // gray: CV_8UC1 (or CV_8UC3 BGR), all frames one size. mask: CV_8UC1, non-zero = person, or empty.
  // depth: CV_32FC1 depth along z (any consistent unit; <= 0 or non-finite = unknown), or empty.
  void AddFrame(const cv::Mat& image, const cv::Mat& mask = cv::Mat(), const cv::Mat& depth = cv::Mat());
  // Final optimisation and the trajectory of every frame added. Throws if fewer than 2 frames were added or no
  // frame had texture. Can be called once.
  PatchVOResult Finish();

  // The reprojection rms (pixels, processing resolution) over the inlier measurements into the keyframes (of
  // patches still in the map) at the current estimate: how well the run explains its own measurements so far
  // (a run that started on a wrong motion fits them several times worse). Infinity before the map exists.
  // Finish() reports it at the final estimate (stats.keyframe_fit_rms_px).
  double FitRms() const;

  int num_frames() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Runs PatchVO over a frame sequence (masks / depths empty or one per frame).
PatchVOResult RunPatchVO(const std::vector<cv::Mat>& frames, const std::vector<cv::Mat>& masks,
                         const std::vector<cv::Mat>& depths, const Intrinsics& intrinsics,
                         const PatchVOOptions& options);

}  // namespace m3c::vo
