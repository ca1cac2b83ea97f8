// Classical front-end: gradient-biased sampling (patch_sampling.h) and pyramidal Lucas-Kanade tracking of each
// patch from its host frame (the template never drifts) into the target, with a forward-backward check and
// rejection of measurements that land inside a (dilated) person mask of the target.
#pragma once

#include <map>
#include <random>
#include <vector>

#include "vo/front_end.h"
#include "vo/patch_sampling.h"

namespace m3c::vo {

struct LucasKanadeOptions {
  GradientSamplingOptions sampling;
  int window_px = 15;          // LK window side at processing resolution
  int pyramid_levels = 3;      // levels above the base image
  int max_iterations = 20;
  double epsilon = 0.02;       // LK stop criterion, pixels
  double min_eigen = 1e-3;     // OpenCV's minEigThreshold: rejects textureless windows
  double forward_backward_px = 0.75;  // max |host - track_back(track(host))|
  bool forward_backward_in_track = false;  // true: check inside Track; false: only when Verify is called
  bool reject_masked = true;   // drop measurements inside the target's dilated mask
  unsigned seed = 0;
};

class LucasKanadeFrontEnd final : public FrontEnd {
 public:
  explicit LucasKanadeFrontEnd(const LucasKanadeOptions& options = {});
  void AddFrame(int frame, const cv::Mat& gray, const cv::Mat& mask) override;
  std::vector<Eigen::Vector2d> SamplePatches(int frame, int count) override;
  // Forward LK (and the mask test); with `forward_backward_in_track` also the forward-backward check.
  std::vector<TrackResult> Track(int target_frame, const std::vector<TrackRequest>& requests) override;
  // Forward-backward check of earlier Track results (no-op for results Track already checked).
  void Verify(int target_frame, const std::vector<TrackRequest>& requests, std::vector<TrackResult>* results) override;
  void ReleaseFrame(int frame) override;

  int num_frames_held() const { return static_cast<int>(frames_.size()); }

 private:
  struct Frame {
    cv::Mat gray;
    cv::Mat mask;       // dilated, or empty
    std::vector<cv::Mat> pyramid;
  };
  const Frame& Get(int frame) const;
  void BackwardCheck(int target_frame, const std::vector<TrackRequest>& requests,
                     std::vector<TrackResult>* results) const;

  LucasKanadeOptions options_;
  std::map<int, Frame> frames_;
};

}  // namespace m3c::vo
