// Pinhole intrinsics for the patch VO (OpenCV camera frame: x right, y down, z forward; pixels).
#pragma once

#include <cmath>

#include <Eigen/Core>

namespace m3c::vo {

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
  bool Valid() const {
    return std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy) && fx > 0 && fy > 0;
  }
};

}  // namespace m3c::vo
