#include "vo/patch_vo.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <opencv2/imgproc.hpp>

namespace m3c::vo {
namespace {

constexpr int kW = 320, kH = 240;

cv::Mat Texture(int size, unsigned seed) {
  cv::RNG rng(seed);
  cv::Mat coarse(size, size, CV_32F), fine(size, size, CV_32F);
  rng.fill(coarse, cv::RNG::NORMAL, 0.0, 1.0);
  rng.fill(fine, cv::RNG::NORMAL, 0.0, 1.0);
  cv::GaussianBlur(coarse, coarse, cv::Size(0, 0), 8.0);
  cv::GaussianBlur(fine, fine, cv::Size(0, 0), 2.0);
  cv::Mat sum = coarse * 10.0 + fine * 3.0;
  cv::normalize(sum, sum, 15, 240, cv::NORM_MINMAX);
  cv::Mat out;
  sum.convertTo(out, CV_8U);
  return out;
}

// Exact rendering of a textured plane z = depth (world) by a homography: texture pixel (s, t) is the world point
// (x0 + res s, y0 + res t, depth).
cv::Mat RenderPlane(const cv::Mat& texture, const Intrinsics& K, const Rigid3& cam_from_world, double depth) {
  const double res = 0.01, x0 = -0.5 * texture.cols * res, y0 = -0.5 * texture.rows * res;
  Eigen::Matrix3d A;
  A << res, 0, x0, 0, res, y0, 0, 0, depth;
  Eigen::Matrix3d Km;
  Km << K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1;
  Eigen::Matrix3d M = cam_from_world.rotation.toRotationMatrix() * A;
  M.col(2) += cam_from_world.translation;
  const Eigen::Matrix3d H = Km * M;
  cv::Mat Hcv(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) Hcv.at<double>(r, c) = H(r, c);
  cv::Mat out;
  cv::warpPerspective(texture, out, Hcv, cv::Size(kW, kH), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0));
  return out;
}

Rigid3 CamFromWorldAt(double i) {
  // Camera centre along a gentle curve, slowly yawing; cam_from_world = inverse of world_from_cam.
  const Eigen::Vector3d centre(0.04 * i, 0.01 * std::sin(0.3 * i), 0.03 * i);
  const Eigen::Quaterniond world_from_cam = ExpSO3(Eigen::Vector3d(0.0, 0.004 * i, 0.002 * i));
  return Rigid3(world_from_cam, centre).Inverse();
}

double AteOverPathLength(const std::vector<Rigid3>& estimated_world_from_cam,
                         const std::vector<Rigid3>& true_world_from_cam) {
  const int n = static_cast<int>(estimated_world_from_cam.size());
  Eigen::Matrix3Xd est(3, n), gt(3, n);
  double path = 0.0;
  for (int i = 0; i < n; ++i) {
    est.col(i) = estimated_world_from_cam[i].translation;
    gt.col(i) = true_world_from_cam[i].translation;
    if (i > 0) path += (gt.col(i) - gt.col(i - 1)).norm();
  }
  const Eigen::Matrix4d sim = Eigen::umeyama(est, gt, true);
  const Eigen::Matrix3Xd aligned = (sim.topLeftCorner<3, 3>() * est).colwise() + sim.topRightCorner<3, 1>();
  return std::sqrt((aligned - gt).colwise().squaredNorm().mean()) / path;
}

TEST(PatchVO, PlanarSceneTrajectoryWithinTwoPercent) {
  const cv::Mat texture = Texture(900, 1);
  const Intrinsics K = Intrinsics::Default(kW, kH);
  PatchVOOptions options;
  options.patches_per_frame = 64;
  PatchVO vo(options);  // default intrinsics == K
  std::vector<Rigid3> truth;
  const Rigid3 world_from_first = CamFromWorldAt(0).Inverse();
  for (int i = 0; i < 30; ++i) {
    vo.AddFrame(RenderPlane(texture, K, CamFromWorldAt(i), 3.0));
    truth.push_back(world_from_first.Inverse() * CamFromWorldAt(i).Inverse());
  }
  const PatchVOResult r = vo.Finish();
  ASSERT_EQ(r.world_from_cam.size(), 30u);
  EXPECT_FALSE(r.static_camera);
  EXPECT_DOUBLE_EQ(r.intrinsics.fx, K.fx);
  EXPECT_LT(LeftMinus(r.world_from_cam[0], Rigid3()).norm(), 1e-12);
  const double ate = AteOverPathLength(r.world_from_cam, truth);
  EXPECT_LT(ate, 0.02) << "ATE / path length";
  // Rotation follows the truth (rotations are scale free).
  for (int i = 0; i < 30; ++i) {
    EXPECT_LT(LogSO3(r.world_from_cam[i].rotation * truth[i].rotation.conjugate()).norm(), 0.01) << i;
  }
  EXPECT_GT(r.stats.num_keyframes, 2);
  for (const auto& q : r.quality) EXPECT_GE(q.tracked, 0);
}

// A front-end that measures exactly: patches on a grid, measurements are the true projections of the sloped
// plane z = 3 + 0.4 y (world) seen through the host pixel. Exercises the graph and the bundle adjustment alone.
class OracleFrontEnd final : public FrontEnd {
 public:
  OracleFrontEnd(const Intrinsics& K, std::vector<Rigid3> cam_from_world) : K_(K), poses_(std::move(cam_from_world)) {}
  void AddFrame(int, const cv::Mat&, const cv::Mat&) override {}
  std::vector<Eigen::Vector2d> SamplePatches(int frame, int count) override {
    std::vector<Eigen::Vector2d> out;
    for (int i = 0; i < count; ++i) {
      out.emplace_back(20.0 + std::fmod(37.0 * i + 11.0 * frame, 280.0),
                       20.0 + std::fmod(23.0 * i + 7.0 * frame, 200.0));
    }
    return out;
  }
  std::vector<TrackResult> Track(int target, const std::vector<TrackRequest>& requests) override {
    std::vector<TrackResult> results(requests.size());
    for (size_t i = 0; i < requests.size(); ++i) {
      const Rigid3 world_from_host = poses_[requests[i].host_frame].Inverse();
      const Eigen::Vector3d origin = world_from_host.translation;
      const Eigen::Vector3d ray = world_from_host.rotation * K_.Unproject(requests[i].host_uv);
      // z - 0.4 y = 3 along origin + s ray.
      const double s = (3.0 - origin.z() + 0.4 * origin.y()) / (ray.z() - 0.4 * ray.y());
      const Eigen::Vector3d x_in_target = poses_[target] * (origin + s * ray);
      if (s <= 0 || x_in_target.z() <= 0.1) continue;
      const Eigen::Vector2d uv = K_.Project(x_in_target);
      if (uv.x() < 0 || uv.y() < 0 || uv.x() > kW - 1 || uv.y() > kH - 1) continue;
      results[i].uv = uv;
      results[i].weight = 1.0;
      results[i].ok = true;
    }
    return results;
  }
  void ReleaseFrame(int) override {}

 private:
  Intrinsics K_;
  std::vector<Rigid3> poses_;
};

TEST(PatchVO, ExactMeasurementsGiveExactTrajectoryThroughAReplaceableFrontEnd) {
  const Intrinsics K = Intrinsics::Default(kW, kH);
  std::vector<Rigid3> cam_from_world, truth;
  for (int i = 0; i < 40; ++i) cam_from_world.push_back(CamFromWorldAt(i));
  const Rigid3 first_from_world = cam_from_world[0];
  for (const Rigid3& p : cam_from_world) truth.push_back(first_from_world * p.Inverse());
  PatchVOOptions options;
  options.final_iterations = 50;
  PatchVO vo(options, K, std::make_unique<OracleFrontEnd>(K, cam_from_world));
  const cv::Mat blank(kH, kW, CV_8U, cv::Scalar(0));  // the oracle ignores pixels
  for (int i = 0; i < 40; ++i) vo.AddFrame(blank);
  const PatchVOResult r = vo.Finish();
  EXPECT_FALSE(r.static_camera);
  EXPECT_LT(AteOverPathLength(r.world_from_cam, truth), 1e-4);
  for (int i = 0; i < 40; ++i) {
    EXPECT_LT(LogSO3(r.world_from_cam[i].rotation * truth[i].rotation.conjugate()).norm(), 1e-5) << i;
    EXPECT_LT(r.quality[i].reprojection_rms_px, 1e-3) << i;
  }
  // The final map, aligned by the trajectory's similarity, lies on the plane and projects onto its host pixel
  // through the true host camera.
  const int n = static_cast<int>(r.world_from_cam.size());
  Eigen::Matrix3Xd est(3, n), gt(3, n);
  for (int i = 0; i < n; ++i) est.col(i) = r.world_from_cam[i].translation, gt.col(i) = truth[i].translation;
  const Eigen::Matrix4d sim = Eigen::umeyama(est, gt, true);
  ASSERT_GT(r.points.size(), 100u);
  for (const MapPoint& p : r.points) {
    const Eigen::Vector3d in_first = sim.topLeftCorner<3, 3>() * p.world + sim.topRightCorner<3, 1>();
    const Eigen::Vector3d x = first_from_world.Inverse() * in_first;
    EXPECT_NEAR(x.z() - 0.4 * x.y(), 3.0, 3e-3);
    ASSERT_TRUE(p.host_frame >= 0 && p.host_frame < 40);
    EXPECT_TRUE(r.quality[p.host_frame].keyframe);
    EXPECT_GE(p.inlier_observations, 1);
    EXPECT_LT((K.Project(cam_from_world[p.host_frame] * x) - p.host_uv).norm(), 1e-2);
  }
}

TEST(PatchVO, FramesSkippedBeforeInitialisationAreInterpolated) {
  // A slow start (a quarter step per frame, ~1 px of flow) makes the motion probe skip frames; they are then
  // interpolated between the keyframes around them.
  const cv::Mat texture = Texture(900, 4);
  const Intrinsics K = Intrinsics::Default(kW, kH);
  std::vector<double> s;
  for (int i = 0; i < 16; ++i) s.push_back(0.25 * i);
  while (s.size() < 40) s.push_back(s.back() + 1.0);
  PatchVOOptions options;
  options.refine_non_keyframes = false;
  PatchVO vo(options);
  std::vector<Rigid3> truth;
  for (double si : s) {
    vo.AddFrame(RenderPlane(texture, K, CamFromWorldAt(si), 3.0));
    truth.push_back(CamFromWorldAt(0) * CamFromWorldAt(si).Inverse());
  }
  const PatchVOResult r = vo.Finish();
  int interpolated = 0;
  for (const FrameQuality& q : r.quality) interpolated += q.interpolated;
  EXPECT_GE(interpolated, 4);
  EXPECT_LT(AteOverPathLength(r.world_from_cam, truth), 0.02);
}

TEST(PatchVO, SceneCutBeforeInitialisationRestartsTracking) {
  const cv::Mat first_scene = Texture(900, 5), second_scene = Texture(900, 6);
  const Intrinsics K = Intrinsics::Default(kW, kH);
  PatchVO vo;
  for (int i = 0; i < 3; ++i) vo.AddFrame(RenderPlane(first_scene, K, CamFromWorldAt(0.1 * i), 3.0));
  std::vector<Rigid3> truth;
  for (int i = 0; i < 30; ++i) {
    vo.AddFrame(RenderPlane(second_scene, K, CamFromWorldAt(i), 3.0));
    truth.push_back(CamFromWorldAt(0) * CamFromWorldAt(i).Inverse());
  }
  const PatchVOResult r = vo.Finish();
  EXPECT_NE(r.message.find("restarted at frame 3"), std::string::npos) << r.message;
  for (int i = 0; i < 3; ++i) EXPECT_LT(LeftMinus(r.world_from_cam[i], Rigid3()).norm(), 1e-12);
  const std::vector<Rigid3> after(r.world_from_cam.begin() + 3, r.world_from_cam.end());
  EXPECT_LT(LeftMinus(after[0], Rigid3()).norm(), 1e-12);  // the new first camera is the world
  EXPECT_LT(AteOverPathLength(after, truth), 0.02);
}

TEST(PatchVO, StaticCameraIsReportedWithIdentityTrajectory) {
  const cv::Mat texture = Texture(900, 2);
  const cv::Mat frame = RenderPlane(texture, Intrinsics::Default(kW, kH), Rigid3(), 3.0);
  PatchVO vo;
  for (int i = 0; i < 15; ++i) vo.AddFrame(frame);
  const PatchVOResult r = vo.Finish();
  EXPECT_TRUE(r.static_camera);
  for (const auto& pose : r.world_from_cam) EXPECT_LT(LeftMinus(pose, Rigid3()).norm(), 1e-6);
}

TEST(PatchVO, ClearErrorsForUnusableInput) {
  const cv::Mat texture = Texture(900, 3);
  const cv::Mat frame = RenderPlane(texture, Intrinsics::Default(kW, kH), Rigid3(), 3.0);
  {
    PatchVO vo;
    vo.AddFrame(frame);
    try {
      vo.Finish();
      FAIL() << "one frame must be rejected";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("too few frames"), std::string::npos) << e.what();
    }
  }
  {
    PatchVO vo;
    const cv::Mat flat(kH, kW, CV_8U, cv::Scalar(90));
    for (int i = 0; i < 5; ++i) vo.AddFrame(flat);
    try {
      vo.Finish();
      FAIL() << "textureless frames must be rejected";
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find("no texture"), std::string::npos) << e.what();
    }
  }
  {
    PatchVO vo;
    vo.AddFrame(frame);
    EXPECT_THROW(vo.AddFrame(cv::Mat(100, 100, CV_8U, cv::Scalar(0))), std::invalid_argument);
    EXPECT_THROW(vo.AddFrame(frame, cv::Mat(10, 10, CV_8U)), std::invalid_argument);
    EXPECT_THROW(vo.AddFrame(frame, cv::Mat(), cv::Mat(kH, kW, CV_64F)), std::invalid_argument);
  }
  EXPECT_THROW(PatchVO(PatchVOOptions{}, Intrinsics{-1, 1, 0, 0}), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::vo
