// Rigid transforms for the patch VO: a rotation quaternion and a translation, the left-multiplied retraction
// the bundle adjustment uses, and the SO(3) exp/log it needs. Templated where the tests run them on ceres::Jet.
//
// Tangent vectors are ordered (rho, phi): translation part first, rotation part second (as in lietorch/DPVO).
// The retraction is left multiplication by [Exp(phi), rho]:
//   Plus(T, (rho, phi)) = [Exp(phi) R, Exp(phi) t + rho],
// which agrees with SE(3)'s exponential to first order, so a point X' = R X + t moves by rho - [X']x phi.
#pragma once

#include <cmath>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace m3c::vo {

// target_from_source: x_in_target = rotation * x_in_source + translation.
struct Rigid3 {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3() = default;
  Rigid3(const Eigen::Quaterniond& q, const Eigen::Vector3d& t) : rotation(q.normalized()), translation(t) {}

  Eigen::Vector3d operator*(const Eigen::Vector3d& x) const { return rotation * x + translation; }
  Rigid3 operator*(const Rigid3& other) const {
    return Rigid3(rotation * other.rotation, rotation * other.translation + translation);
  }
  Rigid3 Inverse() const {
    const Eigen::Quaterniond inv = rotation.conjugate();
    return Rigid3(inv, -(inv * translation));
  }
  Eigen::Matrix4d ToMatrix() const {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = rotation.toRotationMatrix();
    m.topRightCorner<3, 1>() = translation;
    return m;
  }
  static Rigid3 FromMatrix(const Eigen::Matrix4d& m) {
    return Rigid3(Eigen::Quaterniond(Eigen::Matrix3d(m.topLeftCorner<3, 3>())), m.topRightCorner<3, 1>());
  }

  // Packing used for Ceres parameter blocks: (qx, qy, qz, qw, tx, ty, tz).
  void ToParams(double* p) const {
    p[0] = rotation.x(), p[1] = rotation.y(), p[2] = rotation.z(), p[3] = rotation.w();
    p[4] = translation.x(), p[5] = translation.y(), p[6] = translation.z();
  }
  static Rigid3 FromParams(const double* p) {
    return Rigid3(Eigen::Quaterniond(p[3], p[0], p[1], p[2]), Eigen::Vector3d(p[4], p[5], p[6]));
  }
};

inline Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

// Unit quaternion (w, x, y, z in q[0..3]) of the rotation by axis-angle phi. The small-angle branch keeps
// the value and the first derivative exact at phi = 0, where ceres::Jet would otherwise divide by zero.
template <typename T>
void ExpSO3(const T* phi, T* q_wxyz) {
  using std::cos;
  using std::sin;
  using std::sqrt;
  const T theta2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2];
  T real, imag_scale;
  if (theta2 > T(1e-12)) {
    const T theta = sqrt(theta2);
    real = cos(theta / T(2));
    imag_scale = sin(theta / T(2)) / theta;
  } else {
    real = T(1) - theta2 / T(8);
    imag_scale = T(0.5) - theta2 / T(48);
  }
  q_wxyz[0] = real;
  q_wxyz[1] = imag_scale * phi[0];
  q_wxyz[2] = imag_scale * phi[1];
  q_wxyz[3] = imag_scale * phi[2];
}

inline Eigen::Quaterniond ExpSO3(const Eigen::Vector3d& phi) {
  double q[4];
  ExpSO3(phi.data(), q);
  return Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized();
}

// Axis-angle of a unit quaternion, angle in [0, pi].
inline Eigen::Vector3d LogSO3(const Eigen::Quaterniond& q_in) {
  Eigen::Quaterniond q = q_in.normalized();
  if (q.w() < 0) q.coeffs() *= -1.0;  // q and -q are the same rotation; pick the short way round
  const Eigen::Vector3d v = q.vec();
  const double s = v.norm();
  if (s < 1e-10) return 2.0 * v / q.w();
  return (2.0 * std::atan2(s, q.w()) / s) * v;
}

// Plus(T, delta) with delta = (rho, phi), see the header comment.
inline Rigid3 LeftPlus(const Rigid3& pose, const Eigen::Matrix<double, 6, 1>& delta) {
  const Eigen::Quaterniond dq = ExpSO3(Eigen::Vector3d(delta.tail<3>()));
  return Rigid3(dq * pose.rotation, dq * pose.translation + delta.head<3>());
}

// The inverse of LeftPlus: delta with LeftPlus(from, delta) == to.
inline Eigen::Matrix<double, 6, 1> LeftMinus(const Rigid3& to, const Rigid3& from) {
  const Eigen::Quaterniond dq = to.rotation * from.rotation.conjugate();
  Eigen::Matrix<double, 6, 1> delta;
  delta.tail<3>() = LogSO3(dq);
  delta.head<3>() = to.translation - dq.normalized() * from.translation;
  return delta;
}

// Geodesic-per-part interpolation between two poses: slerp on rotation, linear on the camera centre.
inline Rigid3 Interpolate(const Rigid3& a, const Rigid3& b, double alpha) {
  const Rigid3 a_inv = a.Inverse(), b_inv = b.Inverse();
  const Eigen::Quaterniond q = a_inv.rotation.slerp(alpha, b_inv.rotation);
  const Eigen::Vector3d centre = (1.0 - alpha) * a_inv.translation + alpha * b_inv.translation;
  return Rigid3(q, centre).Inverse();
}

// Rotation angle of a pose, radians.
inline double RotationAngle(const Rigid3& pose) { return LogSO3(pose.rotation).norm(); }

}  // namespace m3c::vo
