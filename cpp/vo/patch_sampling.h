// Gradient-biased patch sampling (DPVO's GRADIENT_BIAS) with the thesis's human masking: the image gradient is
// zeroed inside the (dilated) person masks, pooled over the patch footprint, and of 3M uniformly drawn candidate
// centres the M with the largest pooled gradient are kept.
#pragma once

#include <random>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace m3c::vo {

struct GradientSamplingOptions {
  int pool_px = 7;                 // side of the box the gradient magnitude is averaged over
  int candidate_factor = 3;        // candidates drawn per kept patch (DPVO: 3)
  double min_gradient = 3.0;       // pooled |grad I| (grey levels per pixel) below which a spot is textureless
  int margin_px = 10;              // keep centres this far from the border (the tracker's window must fit)
  int mask_dilation_px = 4;        // grow the masks so the strong edge around a person is not picked either
};

// Mean |grad I| over a pool_px box at every pixel (CV_32F), with the gradient zeroed where the dilated mask is set.
// gray: CV_8UC1; mask: CV_8UC1 (non-zero = masked) of the same size, or empty.
cv::Mat PooledGradient(const cv::Mat& gray, const cv::Mat& mask, const GradientSamplingOptions& options);

// Dilates a mask by `radius_px` (square structuring element); empty stays empty.
cv::Mat DilateMask(const cv::Mat& mask, int radius_px);

// Draws candidate_factor * count centres uniformly inside the margin and keeps the `count` best by pooled gradient,
// dropping those below min_gradient. Returns integer pixel centres as doubles, best first.
std::vector<Eigen::Vector2d> SampleGradientBiased(const cv::Mat& pooled_gradient, int count,
                                                  const GradientSamplingOptions& options, std::mt19937* rng);

}  // namespace m3c::vo
