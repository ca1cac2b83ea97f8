#include "vo/patch_ba.h"

#include <ceres/autodiff_cost_function.h>
#include <gtest/gtest.h>

#include <random>

namespace m3c::vo {
namespace {

Rigid3 RandomPose(std::mt19937* rng, double rot_scale, double trans_scale) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Vector3d phi(n(*rng) * rot_scale, n(*rng) * rot_scale, n(*rng) * rot_scale);
  const Eigen::Vector3d t(n(*rng) * trans_scale, n(*rng) * trans_scale, n(*rng) * trans_scale);
  return Rigid3(ExpSO3(phi), t);
}

// The residual as a function of the tangent perturbations (rho, phi) of both poses, for Ceres autodiff.
struct TangentResidual {
  PatchReprojectionResidual residual;
  Rigid3 host, target;

  template <typename T>
  static void Plus(const Rigid3& pose, const T* delta, T* out) {
    T q[4];
    ExpSO3(delta + 3, q);
    const Eigen::Quaternion<T> dq(q[0], q[1], q[2], q[3]);
    const Eigen::Quaternion<T> r = dq * pose.rotation.cast<T>();
    const Eigen::Matrix<T, 3, 1> rho(delta[0], delta[1], delta[2]);
    const Eigen::Matrix<T, 3, 1> t = dq * pose.translation.cast<T>() + rho;
    out[0] = r.x(), out[1] = r.y(), out[2] = r.z(), out[3] = r.w();
    out[4] = t[0], out[5] = t[1], out[6] = t[2];
  }

  template <typename T>
  bool operator()(const T* d_host, const T* d_target, const T* inverse_depth, T* out) const {
    T h[7], j[7];
    Plus(host, d_host, h);
    Plus(target, d_target, j);
    return residual(h, j, inverse_depth, out);
  }
};

struct Config {
  PatchReprojectionResidual r;
  Rigid3 host, target;
  double inverse_depth;
};

Config RandomConfig(std::mt19937* rng, double inverse_depth) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Config c;
  c.r.K = {420.0, 410.0, 321.0, 239.0};
  c.r.bearing = c.r.K.Unproject(Eigen::Vector2d(40 + 560 * u(*rng), 30 + 420 * u(*rng)));
  c.r.observed = Eigen::Vector2d(600 * u(*rng), 450 * u(*rng));
  c.r.sqrt_weight = 0.5 + u(*rng);
  c.host = RandomPose(rng, 0.3, 0.5);
  // Target close to the host so the point stays in front (depth ratio well above the clamp).
  c.target = LeftPlus(c.host, (Eigen::Matrix<double, 6, 1>() << 0.1 * u(*rng), -0.05, 0.1 * u(*rng), 0.05,
                               -0.08 * u(*rng), 0.02)
                                  .finished());
  c.inverse_depth = inverse_depth;
  return c;
}

void ExpectJacobiansMatchAutodiff(const Config& c) {
  Eigen::Vector2d res;
  Eigen::Matrix<double, 2, 6> jh, jt;
  Eigen::Vector2d jd;
  double host[7], target[7];
  c.host.ToParams(host);
  c.target.ToParams(target);
  PatchReprojectionCost::TangentJacobians(c.r, host, target, c.inverse_depth, &res, &jh, &jt, &jd);

  ceres::AutoDiffCostFunction<TangentResidual, 2, 6, 6, 1> autodiff(new TangentResidual{c.r, c.host, c.target});
  const double zero[6] = {0, 0, 0, 0, 0, 0};
  const double* params[3] = {zero, zero, &c.inverse_depth};
  double ad_res[2];
  Eigen::Matrix<double, 2, 6, Eigen::RowMajor> ad_h, ad_t;
  Eigen::Vector2d ad_d;
  double* jacs[3] = {ad_h.data(), ad_t.data(), ad_d.data()};
  ASSERT_TRUE(autodiff.Evaluate(params, ad_res, jacs));
  EXPECT_NEAR(res.x(), ad_res[0], 1e-9);
  EXPECT_NEAR(res.y(), ad_res[1], 1e-9);
  const double scale = 1.0 + ad_h.cwiseAbs().maxCoeff();
  EXPECT_LT((jh - ad_h).cwiseAbs().maxCoeff(), 1e-9 * scale) << "host\n" << jh << "\nvs\n" << ad_h;
  EXPECT_LT((jt - ad_t).cwiseAbs().maxCoeff(), 1e-9 * scale) << "target\n" << jt << "\nvs\n" << ad_t;
  EXPECT_LT((jd - ad_d).cwiseAbs().maxCoeff(), 1e-9 * scale) << "depth\n" << jd << "\nvs\n" << ad_d;
}

TEST(PatchReprojectionCost, JacobiansMatchAutodiff) {
  std::mt19937 rng(3);
  for (int i = 0; i < 50; ++i) ExpectJacobiansMatchAutodiff(RandomConfig(&rng, 0.05 + 2.0 * (i % 7) / 7.0));
}

TEST(PatchReprojectionCost, JacobiansMatchAutodiffAtInfinity) {
  std::mt19937 rng(4);
  for (int i = 0; i < 10; ++i) ExpectJacobiansMatchAutodiff(RandomConfig(&rng, 0.0));
}

TEST(PatchReprojectionCost, ResidualMatchesExplicitGeometry) {
  // Independent path: back-project to a 3D world point with 4x4 matrices, project with K.
  std::mt19937 rng(5);
  const Config c = RandomConfig(&rng, 0.4);
  const Eigen::Vector3d point_in_host = c.r.bearing / c.inverse_depth;
  const Eigen::Vector4d point_in_world = c.host.ToMatrix().inverse() * point_in_host.homogeneous();
  const Eigen::Vector3d point_in_target = (c.target.ToMatrix() * point_in_world).head<3>();
  const Eigen::Vector2d uv = c.r.K.Project(point_in_target);
  double host[7], target[7];
  c.host.ToParams(host);
  c.target.ToParams(target);
  Eigen::Vector2d res;
  PatchReprojectionCost::TangentJacobians(c.r, host, target, c.inverse_depth, &res, nullptr, nullptr, nullptr);
  EXPECT_LT((res - c.r.sqrt_weight * (uv - c.r.observed)).norm(), 1e-9);
}

TEST(PatchReprojectionCost, CeresSeesTangentJacobianThroughManifold) {
  // Problem::Evaluate returns Jacobians in tangent coordinates; they must equal the autodiff tangent Jacobians.
  std::mt19937 rng(6);
  const Config c = RandomConfig(&rng, 0.7);
  double host[7], target[7], depth = c.inverse_depth;
  c.host.ToParams(host);
  c.target.ToParams(target);
  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  LeftSE3Manifold manifold;
  problem.AddResidualBlock(new PatchReprojectionCost(c.r), nullptr, host, target, &depth);
  problem.SetManifold(host, &manifold);
  problem.SetManifold(target, &manifold);
  ceres::CRSMatrix jac;
  ceres::Problem::EvaluateOptions eo;
  eo.parameter_blocks = {host, target, &depth};
  ASSERT_TRUE(problem.Evaluate(eo, nullptr, nullptr, nullptr, &jac));
  ASSERT_EQ(jac.num_rows, 2);
  ASSERT_EQ(jac.num_cols, 13);
  Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(2, 13);
  for (int r = 0; r < 2; ++r)
    for (int k = jac.rows[r]; k < jac.rows[r + 1]; ++k) dense(r, jac.cols[k]) = jac.values[k];

  ceres::AutoDiffCostFunction<TangentResidual, 2, 6, 6, 1> autodiff(new TangentResidual{c.r, c.host, c.target});
  const double zero[6] = {0, 0, 0, 0, 0, 0};
  const double* params[3] = {zero, zero, &c.inverse_depth};
  double ad_res[2];
  Eigen::Matrix<double, 2, 6, Eigen::RowMajor> ad_h, ad_t;
  Eigen::Vector2d ad_d;
  double* jacs[3] = {ad_h.data(), ad_t.data(), ad_d.data()};
  ASSERT_TRUE(autodiff.Evaluate(params, ad_res, jacs));
  EXPECT_LT((dense.leftCols(6) - ad_h).cwiseAbs().maxCoeff(), 1e-8);
  EXPECT_LT((dense.middleCols(6, 6) - ad_t).cwiseAbs().maxCoeff(), 1e-8);
  EXPECT_LT((dense.col(12) - ad_d).cwiseAbs().maxCoeff(), 1e-8);
}

TEST(LeftSE3Manifold, PlusMinusRoundTrip) {
  std::mt19937 rng(7);
  LeftSE3Manifold m;
  for (int i = 0; i < 20; ++i) {
    const Rigid3 x = RandomPose(&rng, 1.0, 2.0);
    Eigen::Matrix<double, 6, 1> delta;
    std::normal_distribution<double> n(0.0, 0.5);
    for (int k = 0; k < 6; ++k) delta[k] = n(rng);
    double xp[7], yp[7], back[6];
    x.ToParams(xp);
    ASSERT_TRUE(m.Plus(xp, delta.data(), yp));
    ASSERT_TRUE(m.Minus(yp, xp, back));
    for (int k = 0; k < 6; ++k) EXPECT_NEAR(back[k], delta[k], 1e-10);
    // Plus is left multiplication: y = [Exp(phi), rho] * x as 4x4 matrices.
    Eigen::Matrix4d left = Eigen::Matrix4d::Identity();
    const Eigen::Vector3d phi = delta.tail<3>();
    left.topLeftCorner<3, 3>() = Eigen::AngleAxisd(phi.norm(), phi.normalized()).toRotationMatrix();
    left.topRightCorner<3, 1>() = delta.head<3>();
    const Eigen::Matrix4d expected = left * x.ToMatrix();
    EXPECT_LT((Rigid3::FromParams(yp).ToMatrix() - expected).cwiseAbs().maxCoeff(), 1e-12);
  }
}

// A synthetic scene: poses around a forward path, patches on random points seen from their host.
struct Scene {
  PatchBAData truth;
};

Scene MakeScene(int num_poses, int patches_per_pose, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Scene s;
  PatchBAData& d = s.truth;
  d.intrinsics = {300.0, 300.0, 160.0, 120.0};
  for (int i = 0; i < num_poses; ++i) {
    const Eigen::Vector3d centre(0.15 * i, 0.03 * std::sin(i), 0.1 * i);
    const Eigen::Quaterniond q = ExpSO3(Eigen::Vector3d(0.02 * i, -0.03 * i, 0.01));
    // cam_from_world with the camera centre at `centre`.
    d.cam_from_world.push_back(Rigid3(q, -(q * centre)));
  }
  for (int h = 0; h < num_poses; ++h) {
    for (int k = 0; k < patches_per_pose; ++k) {
      PatchBAPatch p;
      p.host = h;
      p.uv = Eigen::Vector2d(20 + 280 * u(rng), 20 + 200 * u(rng));
      p.inverse_depth = 1.0 / (2.0 + 6.0 * u(rng));
      d.patches.push_back(p);
      const int id = static_cast<int>(d.patches.size()) - 1;
      for (int j = std::max(0, h - 3); j < std::min(num_poses, h + 4); ++j) {
        if (j == h) continue;
        const Rigid3 j_from_h = d.cam_from_world[j] * d.cam_from_world[h].Inverse();
        const Eigen::Vector3d y =
            j_from_h.rotation * d.intrinsics.Unproject(p.uv) + p.inverse_depth * j_from_h.translation;
        PatchBAObservation o;
        o.patch = id;
        o.target = j;
        o.uv = d.intrinsics.Project(y);
        d.observations.push_back(o);
      }
    }
  }
  return s;
}

PatchBAData Perturb(const PatchBAData& truth, int num_fixed, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  PatchBAData d = truth;
  d.pose_fixed.assign(d.cam_from_world.size(), 0);
  for (int i = 0; i < static_cast<int>(d.cam_from_world.size()); ++i) {
    if (i < num_fixed) {
      d.pose_fixed[i] = 1;
      continue;
    }
    Eigen::Matrix<double, 6, 1> delta;
    for (int k = 0; k < 3; ++k) delta[k] = 0.02 * n(rng);
    for (int k = 3; k < 6; ++k) delta[k] = 0.01 * n(rng);
    d.cam_from_world[i] = LeftPlus(d.cam_from_world[i], delta);
  }
  for (auto& p : d.patches) p.inverse_depth *= std::exp(0.2 * n(rng));
  return d;
}

double MaxPoseError(const PatchBAData& a, const PatchBAData& b) {
  double e = 0.0;
  for (size_t i = 0; i < a.cam_from_world.size(); ++i) {
    e = std::max(e, LeftMinus(a.cam_from_world[i], b.cam_from_world[i]).cwiseAbs().maxCoeff());
  }
  return e;
}

TEST(SolvePatchBA, RecoversPosesAndDepthsDenseAndSparse) {
  const Scene scene = MakeScene(8, 30, 11);
  for (auto solver : {PatchBAOptions::Solver::kDenseSchur, PatchBAOptions::Solver::kSparseSchur}) {
    PatchBAData d = Perturb(scene.truth, 2, 12);
    ASSERT_GT(MaxPoseError(d, scene.truth), 1e-2);
    PatchBAOptions o;
    o.solver = solver;
    o.max_iterations = 50;
    o.function_tolerance = 1e-14;
    const PatchBASummary s = SolvePatchBA(o, &d);
    EXPECT_TRUE(s.usable) << s.message;
    EXPECT_EQ(s.num_free_poses, 6);
    EXPECT_LT(s.final_cost, 1e-12 * s.initial_cost + 1e-16);
    EXPECT_LT(MaxPoseError(d, scene.truth), 1e-6);
    for (size_t p = 0; p < d.patches.size(); ++p) {
      EXPECT_NEAR(d.patches[p].inverse_depth, scene.truth.patches[p].inverse_depth, 1e-6);
    }
    // Fixed poses did not move.
    for (int i = 0; i < 2; ++i) {
      EXPECT_LT(LeftMinus(d.cam_from_world[i], scene.truth.cam_from_world[i]).cwiseAbs().maxCoeff(), 1e-14);
    }
  }
}

TEST(SolvePatchBA, CauchyLossResistsGrossOutliers) {
  const Scene scene = MakeScene(8, 30, 21);
  PatchBAData corrupted = Perturb(scene.truth, 2, 22);
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> u(-40.0, 40.0);
  for (size_t i = 0; i < corrupted.observations.size(); i += 10) {
    corrupted.observations[i].uv += Eigen::Vector2d(u(rng), u(rng));
  }

  PatchBAOptions robust;
  robust.max_iterations = 50;
  PatchBAOptions plain = robust;
  plain.loss = PatchBAOptions::Loss::kTrivial;
  PatchBAData a = corrupted, b = corrupted;
  SolvePatchBA(robust, &a);
  SolvePatchBA(plain, &b);
  const double robust_error = MaxPoseError(a, scene.truth), plain_error = MaxPoseError(b, scene.truth);
  EXPECT_LT(robust_error, 5e-3);
  EXPECT_LT(robust_error, 0.25 * plain_error);
  // The gross outliers stand out in the reprojection errors at the robust solution.
  const std::vector<double> err = ReprojectionErrors(a);
  for (size_t i = 0; i < err.size(); ++i) {
    if (i % 10 != 0) {
      EXPECT_LT(err[i], 0.5) << i;
    }
  }
}

TEST(SolvePatchBA, RejectsInconsistentIndices) {
  Scene scene = MakeScene(3, 2, 31);
  PatchBAData d = scene.truth;
  d.observations[0].target = d.patches[d.observations[0].patch].host;
  EXPECT_THROW(SolvePatchBA(PatchBAOptions{}, &d), std::invalid_argument);
  d = scene.truth;
  d.observations[0].patch = 999;
  EXPECT_THROW(SolvePatchBA(PatchBAOptions{}, &d), std::invalid_argument);
  d = scene.truth;
  d.pose_fixed = {1};
  EXPECT_THROW(SolvePatchBA(PatchBAOptions{}, &d), std::invalid_argument);
}

TEST(SolvePatchBA, InverseDepthStaysInsideBounds) {
  Scene scene = MakeScene(4, 10, 41);
  PatchBAData d = scene.truth;
  d.pose_fixed.assign(d.cam_from_world.size(), 1);
  for (auto& o : d.observations) o.uv += Eigen::Vector2d(25.0, 0.0);  // pulls depths far out of range
  PatchBAOptions opt;
  opt.loss = PatchBAOptions::Loss::kTrivial;
  opt.min_inverse_depth = 0.05;
  opt.max_inverse_depth = 0.6;
  SolvePatchBA(opt, &d);
  for (const auto& p : d.patches) {
    EXPECT_GE(p.inverse_depth, 0.05 - 1e-12);
    EXPECT_LE(p.inverse_depth, 0.6 + 1e-12);
  }
}

}  // namespace
}  // namespace m3c::vo
