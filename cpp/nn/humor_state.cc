#include "nn/humor_state.h"

namespace m3c::nn::humor {

void ToCanonicalBackward(const double* x_frame, int count, const double* const* x, const double* const* g,
                         double* const* grad, double* grad_frame) {
  const CanonicalFrame<double> f = ComputeCanonicalFrame(x_frame);
  const double c = f.c, s = f.s;
  double dc = 0, ds = 0, dtrans[2] = {0, 0}, dpelvis[2] = {0, 0};
  // o = A v with o0 = c v0 + s v1, o1 = -s v0 + c v1, o2 = v2: accumulates dL/dc, dL/ds, returns dL/dv.
  auto back = [&](double v0, double v1, const double* go, double* dv) {
    dc += go[0] * v0 + go[1] * v1;
    ds += go[0] * v1 - go[1] * v0;
    dv[0] += c * go[0] - s * go[1];
    dv[1] += s * go[0] + c * go[1];
    dv[2] += go[2];
  };
  for (int k = 0; k < count; ++k) {
    const double* xs = x[k];
    const double* gs = g[k];
    double* out = grad[k];
    double dv[3] = {0, 0, 0};
    back(xs[kTrans] - f.trans[0], xs[kTrans + 1] - f.trans[1], gs + kTrans, dv);
    for (int i = 0; i < 3; ++i) out[kTrans + i] += dv[i];
    dtrans[0] -= dv[0];
    dtrans[1] -= dv[1];
    back(xs[kTransVel], xs[kTransVel + 1], gs + kTransVel, out + kTransVel);
    for (int col = 0; col < 3; ++col) {
      const double go[3] = {gs[kRootOrient + col], gs[kRootOrient + 3 + col], gs[kRootOrient + 6 + col]};
      double d[3] = {0, 0, 0};
      back(xs[kRootOrient + col], xs[kRootOrient + 3 + col], go, d);
      for (int row = 0; row < 3; ++row) out[kRootOrient + 3 * row + col] += d[row];
    }
    back(xs[kRootOrientVel], xs[kRootOrientVel + 1], gs + kRootOrientVel, out + kRootOrientVel);
    for (int i = kPoseBody; i < kJoints; ++i) out[i] += gs[i];
    for (int j = 0; j < kNumStateJoints; ++j) {
      const double* p = xs + kJoints + 3 * j;
      const double* gp = gs + kJoints + 3 * j;
      double d[3] = {0, 0, 0};
      back(p[0] - f.pelvis[0], p[1] - f.pelvis[1], gp, d);
      for (int i = 0; i < 3; ++i) out[kJoints + 3 * j + i] += d[i];
      // o = A (p - pelvis) + (pelvis - trans)
      dpelvis[0] += gp[0] - d[0];
      dpelvis[1] += gp[1] - d[1];
      dtrans[0] -= gp[0];
      dtrans[1] -= gp[1];
      back(xs[kJointsVel + 3 * j], xs[kJointsVel + 3 * j + 1], gs + kJointsVel + 3 * j, out + kJointsVel + 3 * j);
    }
  }
  grad_frame[kTrans] += dtrans[0];
  grad_frame[kTrans + 1] += dtrans[1];
  grad_frame[kJoints] += dpelvis[0];
  grad_frame[kJoints + 1] += dpelvis[1];
  // (c, s) = (rx, ry) / |(rx, ry)| with (rx, ry) = -(R[0][0], R[1][0]).
  const double rx = -x_frame[kRootOrient], ry = -x_frame[kRootOrient + 3];
  const double n2 = rx * rx + ry * ry;
  if (n2 > 1e-24) {
    const double n3 = n2 * std::sqrt(n2);
    const double drx = (dc * ry * ry - ds * rx * ry) / n3;
    const double dry = (-dc * rx * ry + ds * rx * rx) / n3;
    grad_frame[kRootOrient] -= drx;
    grad_frame[kRootOrient + 3] -= dry;
  }
}

}  // namespace m3c::nn::humor
