#include "vo/patch_sampling.h"

#include <algorithm>

#include <opencv2/imgproc.hpp>

#include "util/check.h"

namespace m3c::vo {

cv::Mat DilateMask(const cv::Mat& mask, int radius_px) {
  if (mask.empty() || radius_px <= 0) return mask;
  cv::Mat out;
  const cv::Mat kernel = cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * radius_px + 1, 2 * radius_px + 1));
  cv::dilate(mask, out, kernel);
  return out;
}

cv::Mat PooledGradient(const cv::Mat& gray, const cv::Mat& mask, const GradientSamplingOptions& options) {
  M3C_CHECK(gray.type() == CV_8UC1) << "gray image must be CV_8UC1";
  M3C_CHECK(mask.empty() || (mask.type() == CV_8UC1 && mask.size() == gray.size()))
      << "mask must be CV_8UC1 with the image size";
  cv::Mat dx, dy, magnitude;
  // Sobel scaled by 1/8 gives the gradient in grey levels per pixel.
  cv::Sobel(gray, dx, CV_32F, 1, 0, 3, 1.0 / 8.0, 0.0, cv::BORDER_REPLICATE);
  cv::Sobel(gray, dy, CV_32F, 0, 1, 3, 1.0 / 8.0, 0.0, cv::BORDER_REPLICATE);
  cv::magnitude(dx, dy, magnitude);
  if (!mask.empty()) magnitude.setTo(0.0f, DilateMask(mask, options.mask_dilation_px));
  cv::Mat pooled;
  const int k = std::max(1, options.pool_px);
  cv::boxFilter(magnitude, pooled, CV_32F, cv::Size(k, k), cv::Point(-1, -1), true, cv::BORDER_REPLICATE);
  return pooled;
}

std::vector<Eigen::Vector2d> SampleGradientBiased(const cv::Mat& pooled_gradient, int count,
                                                  const GradientSamplingOptions& options, std::mt19937* rng) {
  M3C_CHECK(pooled_gradient.type() == CV_32FC1) << "pooled gradient must be CV_32FC1";
  std::vector<Eigen::Vector2d> out;
  const int m = options.margin_px;
  const int w = pooled_gradient.cols, h = pooled_gradient.rows;
  if (count <= 0 || w <= 2 * m || h <= 2 * m) return out;
  std::uniform_int_distribution<int> ux(m, w - 1 - m), uy(m, h - 1 - m);
  struct Candidate {
    float score;
    int x, y;
  };
  const int num_candidates = std::max(1, options.candidate_factor) * count;
  std::vector<Candidate> candidates;
  candidates.reserve(num_candidates);
  for (int i = 0; i < num_candidates; ++i) {
    const int x = ux(*rng), y = uy(*rng);
    const float s = pooled_gradient.at<float>(y, x);
    if (s >= options.min_gradient) candidates.push_back({s, x, y});
  }
  const size_t keep = std::min<size_t>(count, candidates.size());
  std::partial_sort(candidates.begin(), candidates.begin() + keep, candidates.end(),
                    [](const Candidate& a, const Candidate& b) { return a.score > b.score; });
  out.reserve(keep);
  for (size_t i = 0; i < keep; ++i) out.emplace_back(candidates[i].x, candidates[i].y);
  return out;
}

}  // namespace m3c::vo
