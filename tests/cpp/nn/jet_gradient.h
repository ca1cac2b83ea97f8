// Gradients by forward-mode automatic differentiation (ceres::Jet), N partials per pass: the independent
// reference for the hand-written reverse passes.
#pragma once

#include <ceres/jet.h>

#include <algorithm>
#include <vector>

namespace m3c::nn::testing {

template <int N, typename F>
std::vector<double> JetGradient(const std::vector<double>& x, F&& f) {
  using Jet = ceres::Jet<double, N>;
  const int n = static_cast<int>(x.size());
  std::vector<double> grad(n);
  for (int start = 0; start < n; start += N) {
    std::vector<Jet> xj(n);
    for (int i = 0; i < n; ++i) xj[i] = Jet(x[i]);
    for (int i = start; i < std::min(n, start + N); ++i) xj[i].v[i - start] = 1.0;
    const Jet r = f(xj);
    for (int i = start; i < std::min(n, start + N); ++i) grad[i] = r.v[i - start];
  }
  return grad;
}

inline double MaxRelativeError(const std::vector<double>& a, const std::vector<double>& b) {
  double scale = 0, err = 0;
  for (size_t i = 0; i < a.size(); ++i) {
    scale = std::max(scale, std::abs(b[i]));
    err = std::max(err, std::abs(a[i] - b[i]));
  }
  return err / std::max(scale, 1e-300);
}

}  // namespace m3c::nn::testing
