// The pinhole camera of every area (OpenCV camera frame: x right, y down, z forward; pixels) and the robust 2D
// reprojection residual shared by the camera-local fit (cpp/fit) and the world optimizer (cpp/motion).
#pragma once

#include <cmath>

#include <Eigen/Core>

namespace m3c {

struct Intrinsics {
  double fx = 0, fy = 0, cx = 0, cy = 0;

  // The default when the camera is unknown, as WHAM does: f = sqrt(W^2 + H^2) (a ~53 degree diagonal field
  // of view), principal point at the image centre (W/2, H/2).
  static Intrinsics Default(int width, int height) {
    const double f = std::sqrt(double(width) * width + double(height) * height);
    return {f, f, 0.5 * width, 0.5 * height};
  }

  // Intrinsics of the same camera after resizing the image by `scale` (pixel centres at integer + 0.5).
  Intrinsics Scaled(double scale) const {
    return {fx * scale, fy * scale, (cx + 0.5) * scale - 0.5, (cy + 0.5) * scale - 0.5};
  }

  // Normalised bearing [(u - cx)/fx, (v - cy)/fy, 1].
  Eigen::Vector3d Unproject(const Eigen::Vector2d& uv) const {
    return {(uv.x() - cx) / fx, (uv.y() - cy) / fy, 1.0};
  }
  Eigen::Vector2d Project(const Eigen::Vector3d& x) const {
    return {fx * x.x() / x.z() + cx, fy * x.y() / x.z() + cy};
  }
  // d Project / d x (2 x 3) at x.
  Eigen::Matrix<double, 2, 3> ProjectJacobian(const Eigen::Vector3d& x) const {
    const double iz = 1.0 / x.z();
    Eigen::Matrix<double, 2, 3> d;
    d << fx * iz, 0.0, -fx * x.x() * iz * iz, 0.0, fy * iz, -fy * x.y() * iz * iz;
    return d;
  }
  bool Valid() const {
    return std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy) && fx > 0 && fy > 0;
  }
};

// Geman-McClure shaping of an error vector e (SLAHMR's robust form): r = a g e with g = sigma / sqrt(sigma^2 +
// |e|^2), so |r|^2 = a^2 GM(|e|^2) with GM(s) = sigma^2 s / (sigma^2 + s), smooth at 0. Writes r to `residual`
// and returns d r / d e = a (g I - g^3 / sigma^2 e e^T).
template <int N>
Eigen::Matrix<double, N, N> ShapeGemanMcClure(const Eigen::Matrix<double, N, 1>& e, double a, double sigma,
                                              double* residual) {
  const double s2 = sigma * sigma;
  const double g = sigma / std::sqrt(s2 + e.squaredNorm());
  Eigen::Map<Eigen::Matrix<double, N, 1>> out(residual);
  out = a * g * e;
  return a * (g * Eigen::Matrix<double, N, N>::Identity() - (g * g * g / s2) * e * e.transpose());
}

// The robust reprojection residual of one keypoint: x_cam the point in the camera (z > 0), observed (u, v) in
// pixels, a = confidence * sqrt(weight). Writes the 2 residuals and returns d residual / d x_cam (2 x 3).
inline Eigen::Matrix<double, 2, 3> RobustReprojection(const Intrinsics& camera, const Eigen::Vector3d& x_cam,
                                                      double u, double v, double a, double sigma,
                                                      double* residual) {
  const double iz = 1.0 / x_cam.z();
  const Eigen::Vector2d e(camera.fx * x_cam.x() * iz + camera.cx - u, camera.fy * x_cam.y() * iz + camera.cy - v);
  return ShapeGemanMcClure<2>(e, a, sigma, residual) * camera.ProjectJacobian(x_cam);
}

}  // namespace m3c
