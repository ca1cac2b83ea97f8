#include "ground/ground_planes.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace m3c::ground {
namespace {

const Eigen::Vector3d kCameraUp(0, -1, 0);  // OpenCV camera frame: y points down

// Contact points of one person standing at (x, z) on the horizontal plane y = floor_y (camera frame): two soles of
// 25 x 10 cm, 40 points each with 3 mm noise, and optionally 15 hand points 0.8 m above them.
struct Contacts {
  std::vector<Eigen::RowVector3d> points;
  std::vector<uint8_t> is_foot;
};

Contacts Standing(double x, double z, double floor_y, bool feet_down, bool hands, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> length(-0.125, 0.125), width(-0.05, 0.05);
  std::normal_distribution<double> noise(0.0, 0.003);
  Contacts c;
  if (feet_down) {
    for (double side : {-0.1, 0.1}) {
      for (int i = 0; i < 40; ++i) {
        c.points.emplace_back(x + side + width(rng), floor_y + noise(rng), z + length(rng));
        c.is_foot.push_back(1);
      }
    }
  }
  if (hands) {
    for (int i = 0; i < 15; ++i) {
      c.points.emplace_back(x + 0.4 + width(rng), floor_y - 0.8 + width(rng), z + width(rng));
      c.is_foot.push_back(0);
    }
  }
  return c;
}

void Append(const Contacts& c, int person, std::vector<Eigen::RowVector3d>* points, std::vector<int>* owner,
            std::vector<uint8_t>* foot) {
  points->insert(points->end(), c.points.begin(), c.points.end());
  owner->insert(owner->end(), c.points.size(), person);
  foot->insert(foot->end(), c.is_foot.begin(), c.is_foot.end());
}

// Height above `plane` of the point (x, y, z); small when the plane passes through a person's feet there.
double HeightAt(const Plane& plane, double x, double y, double z) { return plane.SignedDistance({x, y, z}); }

// Angle in degrees between a plane's normal and the camera's up direction.
double TiltDegrees(const Plane& plane) { return std::acos(std::min(1.0, plane.normal.dot(kCameraUp))) * 180 / M_PI; }

Points3 Stack(const std::vector<Eigen::RowVector3d>& rows) {
  Points3 x(rows.size(), 3);
  for (size_t i = 0; i < rows.size(); ++i) x.row(i) = rows[i];
  return x;
}

TEST(FramePlanes, TwoLevelsTwoPlanesRightAssociation) {
  // Person 0 on the floor 1.5 m below the camera, person 1 on a 20 cm step 1.5 m to the side, person 2 far away on
  // the floor again, person 3 only touches with hands (no plane of its own can be fitted: too few points).
  std::vector<Eigen::RowVector3d> points;
  std::vector<int> owner;
  std::vector<uint8_t> foot;
  Append(Standing(-0.5, 3.0, 1.5, true, false, 1), 0, &points, &owner, &foot);
  Append(Standing(1.0, 3.0, 1.3, true, false, 2), 1, &points, &owner, &foot);
  Append(Standing(-0.6, 6.0, 1.5, true, true, 3), 2, &points, &owner, &foot);
  GroundOptions options;
  const FramePlanes out = EstimateFramePlanes(Stack(points), owner, foot, 3, kCameraUp, options);
  // Clusters: floor person 0, step person 1, floor person 2, hands of person 2 (15 points < min_support: no plane).
  ASSERT_EQ(out.clusters.num_clusters, 4);
  int ok = 0;
  for (uint8_t f : out.plane_ok) ok += f;
  EXPECT_EQ(ok, 3);
  ASSERT_GE(out.person_plane[0], 0);
  ASSERT_GE(out.person_plane[1], 0);
  ASSERT_GE(out.person_plane[2], 0);
  EXPECT_NE(out.person_plane[0], out.person_plane[1]);
  EXPECT_NE(out.person_plane[1], out.person_plane[2]);
  // Each plane passes through its person's feet (not through the other level 20 cm away) and is nearly level:
  // a local plane from two soles has a few degrees of tilt noise, so heights are checked where the feet are.
  const Plane& floor = out.planes[out.person_plane[0]];
  const Plane& step = out.planes[out.person_plane[1]];
  const Plane& far_floor = out.planes[out.person_plane[2]];
  EXPECT_LT(std::abs(HeightAt(floor, -0.5, 1.5, 3.0)), 0.005);
  EXPECT_LT(std::abs(HeightAt(step, 1.0, 1.3, 3.0)), 0.005);
  EXPECT_LT(std::abs(HeightAt(far_floor, -0.6, 1.5, 6.0)), 0.005);
  EXPECT_NEAR(HeightAt(floor, 1.0, 1.3, 3.0), 0.2, 0.03);  // the step is 20 cm above the floor plane
  for (const Plane* plane : {&floor, &step, &far_floor}) EXPECT_LT(TiltDegrees(*plane), 3.0);
  EXPECT_TRUE(out.via_feet[0] && out.via_feet[1] && out.via_feet[2]);
}

TEST(FramePlanes, FeetFirstThenOtherContactsAndMaxDistance) {
  // Person 0 stands on the floor; person 1 sits with only hips/hands touching near the floor's height (not feet);
  // person 2's contacts float 40 cm above every plane.
  std::vector<Eigen::RowVector3d> points;
  std::vector<int> owner;
  std::vector<uint8_t> foot;
  Append(Standing(0.0, 3.0, 1.5, true, false, 4), 0, &points, &owner, &foot);
  Contacts sitting = Standing(0.3, 3.0, 1.5, true, false, 5);  // close enough to share person 0's cluster
  for (auto& f : sitting.is_foot) f = 0;
  Append(sitting, 1, &points, &owner, &foot);
  Append(Standing(3.0, 3.0, 1.1, false, true, 6), 2, &points, &owner, &foot);
  const FramePlanes out = EstimateFramePlanes(Stack(points), owner, foot, 3, kCameraUp, GroundOptions{});
  EXPECT_GE(out.person_plane[0], 0);
  EXPECT_TRUE(out.via_feet[0]);
  EXPECT_EQ(out.person_plane[1], out.person_plane[0]);  // associated through non-foot contacts...
  EXPECT_FALSE(out.via_feet[1]);                        // ...which never feed a track
  EXPECT_EQ(out.person_plane[2], -1);
}

TEST(FillTrack, HoldAndLinear) {
  const int T = 6;
  Points3 normal = Points3::Constant(T, 3, std::nan(""));
  Eigen::VectorXd offset = Eigen::VectorXd::Constant(T, std::nan(""));
  std::vector<uint8_t> observed = {0, 1, 0, 0, 1, 0};
  const std::vector<int64_t> times = {10, 11, 12, 14, 15, 20};  // frame 13 missing: gaps are measured in frames
  normal.row(1) = Eigen::RowVector3d(0, -1, 0);
  offset(1) = 1.5;
  normal.row(4) = Eigen::RowVector3d(std::sin(0.2), -std::cos(0.2), 0);
  offset(4) = 1.3;
  const TrackPlanes hold = FillTrack(normal, offset, observed, times, GapFill::kHold);
  const std::vector<double> hold_offsets = {1.5, 1.5, 1.5, 1.5, 1.3, 1.3};
  for (int t = 0; t < T; ++t) {
    EXPECT_EQ(hold.offset(t), hold_offsets[t]) << t;
    EXPECT_TRUE(hold.valid[t]);
  }
  EXPECT_EQ(hold.observed, observed);
  const TrackPlanes linear = FillTrack(normal, offset, observed, times, GapFill::kLinear);
  // Frame 12 lies 1/4 of the way from frame 11 to frame 15, frame 14 3/4 of the way.
  EXPECT_NEAR(linear.offset(2), 1.45, 1e-12);
  EXPECT_NEAR(linear.offset(3), 1.35, 1e-12);
  const Eigen::Vector3d blend = (0.25 * normal.row(1) + 0.75 * normal.row(4)).normalized();
  EXPECT_LT((linear.normal.row(3).transpose() - blend).norm(), 1e-12);
  EXPECT_EQ(linear.offset(0), 1.5);
  EXPECT_EQ(linear.offset(5), 1.3);
  const TrackPlanes never = FillTrack(normal, offset, std::vector<uint8_t>(T, 0), times, GapFill::kHold);
  for (int t = 0; t < T; ++t) {
    EXPECT_FALSE(never.valid[t]);
    EXPECT_TRUE(std::isnan(never.offset(t)));
  }
}

TEST(TrackPlanes, JumpKeepsTheLastPlane) {
  // Track 0 walks on the floor, jumps (frames 4-6: no contacts, then only hands at frame 6) and lands on a step;
  // track 1 shares the frames and stands on the floor throughout, on the other side.
  std::vector<Eigen::RowVector3d> points;
  std::vector<int> track, step;
  std::vector<uint8_t> foot;
  auto add = [&](const Contacts& c, int p, int s) {
    points.insert(points.end(), c.points.begin(), c.points.end());
    track.insert(track.end(), c.points.size(), p);
    step.insert(step.end(), c.points.size(), s);
    foot.insert(foot.end(), c.is_foot.begin(), c.is_foot.end());
  };
  const int T = 10;
  for (int s = 0; s < T; ++s) {
    if (s < 4) add(Standing(0.1 * s, 3.0, 1.5, true, false, 10 + s), 0, s);
    if (s == 6) add(Standing(0.6, 3.0, 0.9, false, true, 30), 0, s);
    if (s > 6) add(Standing(0.1 * s, 3.0, 1.3, true, false, 10 + s), 0, s);
    add(Standing(-2.0, 4.0, 1.5, true, false, 50 + s), 1, s);
  }
  std::vector<std::vector<int64_t>> frames(2);
  for (int s = 0; s < T; ++s) {
    frames[0].push_back(100 + s);
    frames[1].push_back(100 + s);
  }
  const std::vector<TrackPlanes> out =
      EstimateTrackPlanes(Stack(points), track, step, foot, frames, kCameraUp, GroundOptions{});
  ASSERT_EQ(out.size(), 2u);
  for (int s = 0; s < T; ++s) {
    EXPECT_EQ(out[0].observed[s], s < 4 || s > 6) << s;
    EXPECT_TRUE(out[0].valid[s]);
    EXPECT_TRUE(out[1].observed[s]);
    EXPECT_LT(std::abs(HeightAt(Plane{out[1].normal.row(s).transpose(), out[1].offset(s)}, -2.0, 1.5, 4.0)), 0.005);
    const Plane plane{out[0].normal.row(s).transpose(), out[0].offset(s)};
    if (s < 4) EXPECT_LT(std::abs(HeightAt(plane, 0.1 * s, 1.5, 3.0)), 0.005) << s;
    if (s > 6) EXPECT_LT(std::abs(HeightAt(plane, 0.1 * s, 1.3, 3.0)), 0.005) << s;
    if (s >= 4 && s <= 6) {  // mid-air: exactly the plane of the last contact, frame 3
      EXPECT_EQ(out[0].normal.row(s), out[0].normal.row(3)) << s;
      EXPECT_EQ(out[0].offset(s), out[0].offset(3)) << s;
    }
  }
}

TEST(TrackPlanes, RejectsBadInput) {
  const Points3 x = Points3::Zero(2, 3);
  std::vector<std::vector<int64_t>> frames = {{0, 1}};
  EXPECT_THROW(EstimateTrackPlanes(x, {0, 0}, {0, 2}, {1, 1}, frames, kCameraUp, GroundOptions{}),
               std::invalid_argument);  // step 2 of a 2-step track
  EXPECT_THROW(EstimateTrackPlanes(x, {0, 1}, {0, 0}, {1, 1}, frames, kCameraUp, GroundOptions{}),
               std::invalid_argument);  // track 1 of 1
  EXPECT_THROW(EstimateTrackPlanes(x, {0}, {0, 0}, {1, 1}, frames, kCameraUp, GroundOptions{}),
               std::invalid_argument);  // sizes
  frames = {{1, 1}};
  EXPECT_THROW(EstimateTrackPlanes(x, {0, 0}, {0, 1}, {1, 1}, frames, kCameraUp, GroundOptions{}),
               std::invalid_argument);  // repeated frame id
  GroundOptions bad;
  bad.eps = 0.0;
  frames = {{0, 1}};
  EXPECT_THROW(EstimateTrackPlanes(x, {0, 0}, {0, 1}, {1, 1}, frames, kCameraUp, bad), std::invalid_argument);
}

}  // namespace
}  // namespace m3c::ground
