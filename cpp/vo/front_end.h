// The frame front-end of the patch VO: where patches are placed and where they are seen again.
//
// PatchVO asks a FrontEnd two things, the same two things DPVO's network provides: new patch centres in a frame
// (DPVO: patchify with gradient bias) and, for an edge (patch -> target frame), the measured position of the patch
// centre in the target plus a confidence (DPVO: the update operator's target and weight). A learned front-end plugs
// in by implementing this interface; LucasKanadeFrontEnd (lk_front_end.h) is the classical one.
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace m3c::vo {

struct TrackRequest {
  int host_frame = 0;
  Eigen::Vector2d host_uv = Eigen::Vector2d::Zero();       // patch centre in the host frame, pixels
  Eigen::Vector2d predicted_uv = Eigen::Vector2d::Zero();  // current reprojection in the target (initial guess)
};

struct TrackResult {
  Eigen::Vector2d uv = Eigen::Vector2d::Zero();  // measured centre in the target, pixels
  double weight = 0.0;                           // confidence multiplying the squared residual
  bool ok = false;
};

class FrontEnd {
 public:
  virtual ~FrontEnd() = default;
  // A new frame at processing resolution: gray CV_8UC1, mask CV_8UC1 (non-zero = person, or empty).
  virtual void AddFrame(int frame, const cv::Mat& gray, const cv::Mat& mask) = 0;
  // Up to `count` patch centres in `frame`; fewer where the frame lacks texture outside the masks.
  virtual std::vector<Eigen::Vector2d> SamplePatches(int frame, int count) = 0;
  // Measures each request (patch from its host frame) in `target_frame`. All hosts and the target must be held.
  virtual std::vector<TrackResult> Track(int target_frame, const std::vector<TrackRequest>& requests) = 0;
  // A stricter second look at measurements before they enter the bundle adjustment (the LK front-end: a
  // forward-backward check); clears `ok` where it fails. PatchVO calls it only for keyframes, so frames that
  // stay out of the graph pay for one pass. The default accepts everything.
  virtual void Verify(int target_frame, const std::vector<TrackRequest>& requests,
                      std::vector<TrackResult>* results) {
    (void)target_frame, (void)requests, (void)results;
  }
  // The VO no longer needs this frame (neither as host nor as target).
  virtual void ReleaseFrame(int frame) = 0;
};

}  // namespace m3c::vo
