#include <gtest/gtest.h>

#include <random>

#include <opencv2/imgproc.hpp>

#include "vo/lk_front_end.h"
#include "vo/patch_sampling.h"

namespace m3c::vo {
namespace {

// Smooth random texture: blurred noise at two scales, 8-bit.
cv::Mat Texture(int width, int height, unsigned seed) {
  cv::RNG rng(seed);
  cv::Mat coarse(height, width, CV_32F), fine(height, width, CV_32F);
  rng.fill(coarse, cv::RNG::NORMAL, 0.0, 1.0);
  rng.fill(fine, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(coarse, coarse, cv::Size(0, 0), 6.0);
  cv::GaussianBlur(fine, fine, cv::Size(0, 0), 1.5);
  cv::Mat sum = coarse * 8.0 + fine * 3.0;
  cv::normalize(sum, sum, 20, 235, cv::NORM_MINMAX);
  cv::Mat out;
  sum.convertTo(out, CV_8U);
  return out;
}

TEST(PooledGradient, MatchesBruteForce) {
  const cv::Mat img = Texture(64, 48, 1);
  GradientSamplingOptions o;
  o.pool_px = 5;
  const cv::Mat pooled = PooledGradient(img, cv::Mat(), o);
  auto at = [&](int x, int y) {
    x = std::clamp(x, 0, img.cols - 1);
    y = std::clamp(y, 0, img.rows - 1);
    return static_cast<double>(img.at<uchar>(y, x));
  };
  // Sobel / 8 with replicated borders, magnitude, 5x5 mean (replicated border of the magnitude).
  auto mag = [&](int x, int y) {
    x = std::clamp(x, 0, img.cols - 1);
    y = std::clamp(y, 0, img.rows - 1);
    const double gx = (at(x + 1, y - 1) + 2 * at(x + 1, y) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2 * at(x - 1, y) -
                       at(x - 1, y + 1)) / 8.0;
    const double gy = (at(x - 1, y + 1) + 2 * at(x, y + 1) + at(x + 1, y + 1) - at(x - 1, y - 1) - 2 * at(x, y - 1) -
                       at(x + 1, y - 1)) / 8.0;
    return std::sqrt(gx * gx + gy * gy);
  };
  for (int y = 0; y < img.rows; y += 7) {
    for (int x = 0; x < img.cols; x += 5) {
      double s = 0.0;
      for (int dy = -2; dy <= 2; ++dy)
        for (int dx = -2; dx <= 2; ++dx) s += mag(x + dx, y + dy);
      EXPECT_NEAR(pooled.at<float>(y, x), s / 25.0, 1e-3) << x << "," << y;
    }
  }
}

TEST(SampleGradientBiased, KeepsTopScoresOfCandidates) {
  const cv::Mat img = Texture(160, 120, 2);
  GradientSamplingOptions o;
  o.min_gradient = 0.0;
  const cv::Mat pooled = PooledGradient(img, cv::Mat(), o);
  std::mt19937 a(5), b(5);
  const auto picked = SampleGradientBiased(pooled, 20, o, &a);
  ASSERT_EQ(picked.size(), 20u);
  // Re-draw the same candidates and check the picks are exactly the 20 best.
  std::uniform_int_distribution<int> ux(o.margin_px, 160 - 1 - o.margin_px), uy(o.margin_px, 120 - 1 - o.margin_px);
  std::vector<float> scores;
  for (int i = 0; i < 60; ++i) {
    const int x = ux(b), y = uy(b);
    scores.push_back(pooled.at<float>(y, x));
  }
  std::sort(scores.rbegin(), scores.rend());
  for (size_t i = 0; i < picked.size(); ++i) {
    EXPECT_FLOAT_EQ(pooled.at<float>(static_cast<int>(picked[i].y()), static_cast<int>(picked[i].x())), scores[i]);
    EXPECT_GE(picked[i].x(), o.margin_px);
    EXPECT_LE(picked[i].y(), 120 - 1 - o.margin_px);
  }
}

TEST(SampleGradientBiased, MaskZeroesGradientAndTexturelessGivesNothing) {
  const cv::Mat img = Texture(160, 120, 3);
  cv::Mat mask = cv::Mat::zeros(120, 160, CV_8U);
  mask(cv::Rect(0, 0, 100, 120)).setTo(255);
  GradientSamplingOptions o;
  o.min_gradient = 0.5;
  const cv::Mat pooled = PooledGradient(img, mask, o);
  // Inside the dilated mask, and pool/2 beyond it, the pooled gradient is exactly zero.
  EXPECT_EQ(cv::countNonZero(pooled(cv::Rect(0, 0, 100 + o.mask_dilation_px - o.pool_px / 2, 120))), 0);
  std::mt19937 rng(1);
  for (const auto& uv : SampleGradientBiased(pooled, 50, o, &rng)) {
    EXPECT_GE(uv.x(), 100 + o.mask_dilation_px - o.pool_px / 2);
  }
  const cv::Mat flat(120, 160, CV_8U, cv::Scalar(128));
  EXPECT_TRUE(SampleGradientBiased(PooledGradient(flat, cv::Mat(), o), 50, o, &rng).empty());
}

TEST(LucasKanadeFrontEnd, TracksKnownShiftAndRejectsMasked) {
  const cv::Mat big = Texture(400, 300, 4);
  const cv::Mat a = big(cv::Rect(40, 40, 320, 240)).clone();
  // Sub-pixel shift (+3.4, -2.3) by an exact affine warp with bilinear interpolation.
  cv::Mat b;
  const cv::Mat shift = (cv::Mat_<double>(2, 3) << 1, 0, 3.4, 0, 1, -2.3);
  cv::warpAffine(a, b, shift, a.size(), cv::INTER_LINEAR, cv::BORDER_REFLECT);
  cv::Mat mask_b = cv::Mat::zeros(240, 320, CV_8U);
  mask_b(cv::Rect(0, 0, 60, 240)).setTo(255);

  LucasKanadeFrontEnd fe;
  fe.AddFrame(0, a, cv::Mat());
  fe.AddFrame(1, b, mask_b);
  const auto centres = fe.SamplePatches(0, 60);
  ASSERT_GE(centres.size(), 40u);
  std::vector<TrackRequest> req;
  for (const auto& c : centres) req.push_back({0, c, c});
  auto res = fe.Track(1, req);
  fe.Verify(1, req, &res);
  int ok = 0, masked_region = 0;
  for (size_t i = 0; i < res.size(); ++i) {
    const Eigen::Vector2d expected = centres[i] + Eigen::Vector2d(3.4, -2.3);
    if (expected.x() < 66) {  // mask (60 px) + dilation (4 px) + rounding
      masked_region += 1;
      if (expected.x() < 63) {
        EXPECT_FALSE(res[i].ok) << "measurement inside the target mask was kept";
      }
      continue;
    }
    if (!res[i].ok) continue;
    ++ok;
    EXPECT_LT((res[i].uv - expected).norm(), 0.1) << centres[i].transpose();
  }
  EXPECT_GT(ok, static_cast<int>(0.8 * (res.size() - masked_region)));
  EXPECT_EQ(fe.num_frames_held(), 2);
  fe.ReleaseFrame(0);
  EXPECT_THROW(fe.Track(1, req), std::invalid_argument);
}

TEST(LucasKanadeFrontEnd, ForwardBackwardCheckRejectsUnrelatedImage) {
  const cv::Mat a = Texture(320, 240, 5), b = Texture(320, 240, 6);
  LucasKanadeFrontEnd fe;
  fe.AddFrame(0, a, cv::Mat());
  fe.AddFrame(1, b, cv::Mat());
  const auto centres = fe.SamplePatches(0, 80);
  std::vector<TrackRequest> req;
  for (const auto& c : centres) req.push_back({0, c, c});
  auto res = fe.Track(1, req);
  int forward_ok = 0, ok = 0;
  for (const auto& r : res) forward_ok += r.ok;
  fe.Verify(1, req, &res);
  for (const auto& r : res) ok += r.ok;
  EXPECT_LT(ok, static_cast<int>(0.2 * centres.size()));
  EXPECT_LT(ok, forward_ok);  // the check removed measurements the forward pass had accepted
}

}  // namespace
}  // namespace m3c::vo
