#include "vo/lk_front_end.h"

#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "util/check.h"

namespace m3c::vo {

LucasKanadeFrontEnd::LucasKanadeFrontEnd(const LucasKanadeOptions& options) : options_(options) {
  M3C_CHECK(options.window_px >= 5 && options.window_px % 2 == 1) << "LK window must be odd and >= 5";
  M3C_CHECK(options.pyramid_levels >= 0 && options.pyramid_levels <= 6) << "pyramid levels must be in [0, 6]";
}

void LucasKanadeFrontEnd::AddFrame(int frame, const cv::Mat& gray, const cv::Mat& mask) {
  M3C_CHECK(gray.type() == CV_8UC1) << "front-end frames must be CV_8UC1";
  M3C_CHECK(mask.empty() || (mask.type() == CV_8UC1 && mask.size() == gray.size()))
      << "mask must be CV_8UC1 with the image size";
  Frame f;
  f.gray = gray;
  f.mask = DilateMask(mask, options_.sampling.mask_dilation_px);
  cv::buildOpticalFlowPyramid(gray, f.pyramid, cv::Size(options_.window_px, options_.window_px),
                              options_.pyramid_levels, true, cv::BORDER_REFLECT_101, cv::BORDER_CONSTANT, true);
  frames_[frame] = std::move(f);
}

const LucasKanadeFrontEnd::Frame& LucasKanadeFrontEnd::Get(int frame) const {
  const auto it = frames_.find(frame);
  M3C_CHECK(it != frames_.end()) << "front-end does not hold frame " << frame;
  return it->second;
}

std::vector<Eigen::Vector2d> LucasKanadeFrontEnd::SamplePatches(int frame, int count) {
  const Frame& f = Get(frame);
  // The mask is already dilated; PooledGradient must not dilate it again.
  GradientSamplingOptions sampling = options_.sampling;
  sampling.mask_dilation_px = 0;
  sampling.margin_px = std::max(sampling.margin_px, options_.window_px / 2 + 2);
  const cv::Mat pooled = PooledGradient(f.gray, f.mask, sampling);
  std::mt19937 rng(options_.seed * 7919u + static_cast<unsigned>(frame));
  return SampleGradientBiased(pooled, count, sampling, &rng);
}

std::vector<TrackResult> LucasKanadeFrontEnd::Track(int target_frame, const std::vector<TrackRequest>& requests) {
  std::vector<TrackResult> results(requests.size());
  if (requests.empty()) return results;
  const Frame& target = Get(target_frame);
  const cv::Size win(options_.window_px, options_.window_px);
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, options_.max_iterations,
                                  options_.epsilon);
  const double margin = options_.window_px / 2 + 1;
  const double max_x = target.gray.cols - 1 - margin, max_y = target.gray.rows - 1 - margin;

  // One LK call per host frame.
  std::map<int, std::vector<int>> by_host;
  for (int i = 0; i < static_cast<int>(requests.size()); ++i) by_host[requests[i].host_frame].push_back(i);
  std::vector<cv::Point2f> host_pts, fwd_pts;
  std::vector<uchar> status;
  std::vector<float> err;
  for (const auto& [host_id, idx] : by_host) {
    const Frame& host = Get(host_id);
    host_pts.resize(idx.size());
    fwd_pts.resize(idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      const TrackRequest& r = requests[idx[k]];
      host_pts[k] = cv::Point2f(static_cast<float>(r.host_uv.x()), static_cast<float>(r.host_uv.y()));
      fwd_pts[k] = cv::Point2f(static_cast<float>(r.predicted_uv.x()), static_cast<float>(r.predicted_uv.y()));
    }
    cv::calcOpticalFlowPyrLK(host.pyramid, target.pyramid, host_pts, fwd_pts, status, err, win,
                             options_.pyramid_levels, criteria, cv::OPTFLOW_USE_INITIAL_FLOW, options_.min_eigen);
    for (size_t k = 0; k < idx.size(); ++k) {
      if (!status[k]) continue;
      const cv::Point2f p = fwd_pts[k];
      if (!(p.x >= margin && p.y >= margin && p.x <= max_x && p.y <= max_y)) continue;
      if (options_.reject_masked && !target.mask.empty() &&
          target.mask.at<uchar>(cvRound(p.y), cvRound(p.x)) != 0) {
        continue;
      }
      TrackResult& out = results[idx[k]];
      out.uv = Eigen::Vector2d(p.x, p.y);
      out.weight = 1.0;
      out.ok = true;
    }
  }
  if (options_.forward_backward_in_track) BackwardCheck(target_frame, requests, &results);
  return results;
}

void LucasKanadeFrontEnd::Verify(int target_frame, const std::vector<TrackRequest>& requests,
                                 std::vector<TrackResult>* results) {
  if (!options_.forward_backward_in_track) BackwardCheck(target_frame, requests, results);
}

void LucasKanadeFrontEnd::BackwardCheck(int target_frame, const std::vector<TrackRequest>& requests,
                                        std::vector<TrackResult>* results) const {
  M3C_CHECK(results->size() == requests.size()) << results->size() << " results for " << requests.size() << " requests";
  const Frame& target = Get(target_frame);
  const cv::Size win(options_.window_px, options_.window_px);
  const cv::TermCriteria criteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, options_.max_iterations,
                                  options_.epsilon);
  std::map<int, std::vector<int>> by_host;
  for (int i = 0; i < static_cast<int>(requests.size()); ++i) {
    if ((*results)[i].ok) by_host[requests[i].host_frame].push_back(i);
  }
  std::vector<cv::Point2f> host_pts, fwd_pts, back_pts;
  std::vector<uchar> status;
  std::vector<float> err;
  const double max_fb2 = options_.forward_backward_px * options_.forward_backward_px;
  for (const auto& [host_id, idx] : by_host) {
    const Frame& host = Get(host_id);
    host_pts.resize(idx.size());
    fwd_pts.resize(idx.size());
    for (size_t k = 0; k < idx.size(); ++k) {
      const TrackRequest& r = requests[idx[k]];
      host_pts[k] = cv::Point2f(static_cast<float>(r.host_uv.x()), static_cast<float>(r.host_uv.y()));
      const Eigen::Vector2d& uv = (*results)[idx[k]].uv;
      fwd_pts[k] = cv::Point2f(static_cast<float>(uv.x()), static_cast<float>(uv.y()));
    }
    back_pts = host_pts;
    cv::calcOpticalFlowPyrLK(target.pyramid, host.pyramid, fwd_pts, back_pts, status, err, win,
                             options_.pyramid_levels, criteria, cv::OPTFLOW_USE_INITIAL_FLOW, options_.min_eigen);
    for (size_t k = 0; k < idx.size(); ++k) {
      const cv::Point2f fb = back_pts[k] - host_pts[k];
      if (!status[k] || fb.x * fb.x + fb.y * fb.y > max_fb2) (*results)[idx[k]].ok = false;
    }
  }
}

void LucasKanadeFrontEnd::ReleaseFrame(int frame) { frames_.erase(frame); }

}  // namespace m3c::vo
