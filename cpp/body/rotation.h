// SO(3) helpers templated on the scalar so they run on double, float and ceres::Jet.
// Rotation matrices are row-major 3x3 arrays R[3*r + c].
#pragma once

#include <cmath>

#include <Eigen/Core>

namespace m3c {

namespace internal {
using std::cos;
using std::sin;
using std::sqrt;
}  // namespace internal

// Rodrigues: R = I + a [k]x + b [k]x^2 with a = sin(t)/t, b = (1 - cos t)/t^2 for k = theta (unnormalised).
// Near t = 0 the Taylor series keeps the result and its derivatives exact to double precision.
template <typename T>
void AxisAngleToRotation(const T* theta, T* R) {
  using namespace internal;
  const T x = theta[0], y = theta[1], z = theta[2];
  const T t2 = x * x + y * y + z * z;
  T a, b;
  if (t2 > T(1e-8)) {
    const T t = sqrt(t2);
    a = sin(t) / t;
    b = (T(1) - cos(t)) / t2;
  } else {
    a = T(1) - t2 / T(6) + t2 * t2 / T(120);
    b = T(0.5) - t2 / T(24) + t2 * t2 / T(720);
  }
  // [k]x^2 = k k^T - t2 I
  R[0] = T(1) + b * (x * x - t2);
  R[1] = -a * z + b * x * y;
  R[2] = a * y + b * x * z;
  R[3] = a * z + b * x * y;
  R[4] = T(1) + b * (y * y - t2);
  R[5] = -a * x + b * y * z;
  R[6] = -a * y + b * x * z;
  R[7] = a * x + b * y * z;
  R[8] = T(1) + b * (z * z - t2);
}

// Right Jacobian of SO(3): Exp(theta + d) = Exp(theta) Exp(Jr(theta) d) + O(d^2).
// Jr = I - b [k]x + c [k]x^2 with b = (1 - cos t)/t^2 and c = (t - sin t)/t^3.
inline Eigen::Matrix3d RightJacobianSO3(const double* theta) {
  const Eigen::Vector3d k(theta[0], theta[1], theta[2]);
  const double t2 = k.squaredNorm();
  double b, c;
  if (t2 > 1e-8) {
    const double t = std::sqrt(t2);
    b = (1.0 - std::cos(t)) / t2;
    c = (t - std::sin(t)) / (t2 * t);
  } else {
    b = 0.5 - t2 / 24.0 + t2 * t2 / 720.0;
    c = 1.0 / 6.0 - t2 / 120.0 + t2 * t2 / 5040.0;
  }
  Eigen::Matrix3d K;
  K << 0, -k.z(), k.y(), k.z(), 0, -k.x(), -k.y(), k.x(), 0;
  return Eigen::Matrix3d::Identity() - b * K + c * K * K;
}

inline Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d S;
  S << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return S;
}

}  // namespace m3c
