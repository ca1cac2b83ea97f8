#include "ground/ground_planes.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "util/check.h"

namespace m3c::ground {

namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Median of |signed distance| of the selected points to `plane` (the upper median for an even count).
double MedianAbsDistance(const PointsRef& points, const std::vector<int>& selected, const Plane& plane) {
  std::vector<double> d(selected.size());
  for (size_t j = 0; j < selected.size(); ++j) {
    d[j] = std::abs(plane.SignedDistance(points.row(selected[j]).transpose()));
  }
  auto middle = d.begin() + d.size() / 2;
  std::nth_element(d.begin(), middle, d.end());
  return *middle;
}

}  // namespace

void ValidateGroundOptions(const GroundOptions& options) {
  M3C_CHECK(std::isfinite(options.eps) && options.eps > 0.0)
      << "eps must be a positive, finite distance (metres), got " << options.eps;
  M3C_CHECK(options.min_samples >= 1) << "min_samples must be >= 1, got " << options.min_samples;
  M3C_CHECK(std::isfinite(options.max_distance) && options.max_distance > 0.0)
      << "max_distance must be a positive, finite distance (metres), got " << options.max_distance;
  ValidatePlaneFitOptions(options.fit);
}

FramePlanes EstimateFramePlanes(const PointsRef& points, const std::vector<int>& person,
                                const std::vector<uint8_t>& is_foot, int num_people, const Eigen::Vector3d& up,
                                const GroundOptions& options) {
  ValidateGroundOptions(options);
  const int n = static_cast<int>(points.rows());
  M3C_CHECK(static_cast<int>(person.size()) == n) << "person must have one entry per point: " << person.size()
                                                  << " entries for " << n << " points";
  M3C_CHECK(static_cast<int>(is_foot.size()) == n) << "is_foot must have one entry per point: " << is_foot.size()
                                                   << " entries for " << n << " points";
  M3C_CHECK(num_people >= 0) << "num_people must be >= 0, got " << num_people;
  std::vector<std::vector<int>> points_of(num_people), feet_of(num_people);
  for (int i = 0; i < n; ++i) {
    M3C_CHECK(person[i] >= 0 && person[i] < num_people)
        << "person[" << i << "] = " << person[i] << " is outside [0, num_people = " << num_people << ")";
    points_of[person[i]].push_back(i);
    if (is_foot[i]) feet_of[person[i]].push_back(i);
  }

  FramePlanes out;
  out.clusters = Dbscan(points, options.eps, options.min_samples);
  const int num_clusters = out.clusters.num_clusters;
  std::vector<std::vector<int>> members(num_clusters);
  for (int i = 0; i < n; ++i) {
    if (out.clusters.labels[i] >= 0) members[out.clusters.labels[i]].push_back(i);
  }
  out.planes.resize(num_clusters);
  out.plane_ok.assign(num_clusters, 0);
  for (int k = 0; k < num_clusters; ++k) {
    Points3 cluster(members[k].size(), 3);
    for (size_t j = 0; j < members[k].size(); ++j) cluster.row(j) = points.row(members[k][j]);
    const PlaneFit fit = FitPlane(cluster, up, options.fit);
    out.planes[k] = fit.plane;
    out.plane_ok[k] = fit.ok();
  }

  out.person_plane.assign(num_people, -1);
  out.via_feet.assign(num_people, 0);
  for (int p = 0; p < num_people; ++p) {
    // Feet first: a person with foot contacts is placed by its feet alone.
    const bool use_feet = !feet_of[p].empty();
    const std::vector<int>& selected = use_feet ? feet_of[p] : points_of[p];
    if (selected.empty()) continue;
    double best = options.max_distance;
    for (int k = 0; k < num_clusters; ++k) {
      if (!out.plane_ok[k]) continue;
      const double d = MedianAbsDistance(points, selected, out.planes[k]);
      if (d <= best) {
        if (out.person_plane[p] >= 0 && d == best) continue;  // ties keep the lower cluster id
        best = d;
        out.person_plane[p] = k;
      }
    }
    out.via_feet[p] = out.person_plane[p] >= 0 && use_feet;
  }
  return out;
}

TrackPlanes FillTrack(const Points3& normal, const Eigen::VectorXd& offset, const std::vector<uint8_t>& observed,
                      const std::vector<int64_t>& times, GapFill fill) {
  const int T = static_cast<int>(observed.size());
  M3C_CHECK(normal.rows() == T && offset.size() == T && static_cast<int>(times.size()) == T)
      << "normal (" << normal.rows() << ", 3), offset (" << offset.size() << ",), times (" << times.size()
      << ",) and observed (" << T << ",) must have the same length";
  std::vector<int> seen;
  for (int t = 0; t < T; ++t) {
    if (t > 0) M3C_CHECK(times[t] > times[t - 1]) << "frame ids must be strictly increasing, got " << times[t - 1]
                                                  << " then " << times[t] << " at index " << t;
    if (!observed[t]) continue;
    M3C_CHECK(normal.row(t).allFinite() && std::isfinite(offset(t)) && std::abs(normal.row(t).norm() - 1.0) < 1e-6)
        << "observed plane " << t << " needs a finite unit normal and a finite offset";
    seen.push_back(t);
  }
  TrackPlanes out;
  out.normal = Points3::Constant(T, 3, kNaN);
  out.offset = Eigen::VectorXd::Constant(T, kNaN);
  out.observed = observed;
  out.valid.assign(T, 0);
  if (seen.empty()) return out;
  size_t next = 0;  // index into `seen` of the first observation at or after t
  for (int t = 0; t < T; ++t) {
    while (next < seen.size() && seen[next] < t) ++next;
    const int before = next > 0 ? seen[next - 1] : -1;  // last observation before t
    const int after = next < seen.size() ? seen[next] : -1;
    int source = -1;  // frame to copy, or -1 to interpolate between `before` and `after`
    if (observed[t]) {
      source = t;
    } else if (before < 0) {
      source = after;  // ahead of the first observation
    } else if (after < 0 || fill == GapFill::kHold) {
      source = before;
    }
    if (source >= 0) {
      out.normal.row(t) = normal.row(source);
      out.offset(t) = offset(source);
    } else {
      const int a = before, b = after;
      const double w = static_cast<double>(times[t] - times[a]) / static_cast<double>(times[b] - times[a]);
      const Eigen::Vector3d blend = (1.0 - w) * normal.row(a) + w * normal.row(b);
      // Opposite normals have no meaningful blend; hold the earlier plane then.
      const bool usable = blend.norm() > 1e-6;
      out.normal.row(t) = usable ? Eigen::Vector3d(blend.normalized()) : Eigen::Vector3d(normal.row(a));
      out.offset(t) = usable ? (1.0 - w) * offset(a) + w * offset(b) : offset(a);
    }
    out.valid[t] = 1;
  }
  return out;
}

std::vector<TrackPlanes> EstimateTrackPlanes(const PointsRef& points, const std::vector<int>& point_track,
                                             const std::vector<int>& point_step, const std::vector<uint8_t>& is_foot,
                                             const std::vector<std::vector<int64_t>>& track_frames,
                                             const Eigen::Vector3d& up, const GroundOptions& options) {
  ValidateGroundOptions(options);
  const int n = static_cast<int>(points.rows());
  const int num_tracks = static_cast<int>(track_frames.size());
  M3C_CHECK(static_cast<int>(point_track.size()) == n && static_cast<int>(point_step.size()) == n &&
            static_cast<int>(is_foot.size()) == n)
      << "point_track (" << point_track.size() << "), point_step (" << point_step.size() << ") and is_foot ("
      << is_foot.size() << ") need one entry per point (" << n << ")";

  // Slots: one per (track, step); slot_begin[p] + step.
  std::vector<int> slot_begin(num_tracks + 1, 0);
  std::vector<int64_t> all_frames;
  for (int p = 0; p < num_tracks; ++p) {
    const auto& frames = track_frames[p];
    for (size_t s = 1; s < frames.size(); ++s) {
      M3C_CHECK(frames[s] > frames[s - 1]) << "track " << p << ": frame ids must be strictly increasing, got "
                                           << frames[s - 1] << " then " << frames[s] << " at step " << s;
    }
    slot_begin[p + 1] = slot_begin[p] + static_cast<int>(frames.size());
    all_frames.insert(all_frames.end(), frames.begin(), frames.end());
  }
  const int num_slots = slot_begin[num_tracks];
  std::sort(all_frames.begin(), all_frames.end());
  all_frames.erase(std::unique(all_frames.begin(), all_frames.end()), all_frames.end());
  const int num_frames = static_cast<int>(all_frames.size());

  // Frame of each slot, and each slot's person index inside its frame (slots of a frame ordered by track).
  std::vector<int> slot_frame(num_slots), slot_person(num_slots), frame_people(num_frames, 0);
  for (int p = 0; p < num_tracks; ++p) {
    for (size_t s = 0; s < track_frames[p].size(); ++s) {
      const int slot = slot_begin[p] + static_cast<int>(s);
      const int f = static_cast<int>(std::lower_bound(all_frames.begin(), all_frames.end(), track_frames[p][s]) -
                                     all_frames.begin());
      slot_frame[slot] = f;
      slot_person[slot] = frame_people[f]++;
    }
  }
  // Points bucketed by frame.
  std::vector<int> frame_point_begin(num_frames + 1, 0), point_slot(n);
  for (int i = 0; i < n; ++i) {
    const int p = point_track[i];
    M3C_CHECK(p >= 0 && p < num_tracks) << "point_track[" << i << "] = " << p << " is outside [0, " << num_tracks
                                        << ")";
    const int steps = slot_begin[p + 1] - slot_begin[p];
    M3C_CHECK(point_step[i] >= 0 && point_step[i] < steps)
        << "point_step[" << i << "] = " << point_step[i] << " is outside track " << p << "'s " << steps << " steps";
    point_slot[i] = slot_begin[p] + point_step[i];
    ++frame_point_begin[slot_frame[point_slot[i]] + 1];
  }
  for (int f = 0; f < num_frames; ++f) frame_point_begin[f + 1] += frame_point_begin[f];
  std::vector<int> frame_points(n), fill_at(frame_point_begin.begin(), frame_point_begin.end() - 1);
  for (int i = 0; i < n; ++i) frame_points[fill_at[slot_frame[point_slot[i]]]++] = i;

  // Observations: frames whose feet touch a plane.
  Points3 slot_normal = Points3::Constant(num_slots, 3, kNaN);
  Eigen::VectorXd slot_offset = Eigen::VectorXd::Constant(num_slots, kNaN);
  std::vector<uint8_t> slot_observed(num_slots, 0);
  std::vector<int> person_slot;
  for (int f = 0; f < num_frames; ++f) {
    const int begin = frame_point_begin[f], count = frame_point_begin[f + 1] - begin;
    if (count == 0) continue;
    Points3 frame_xyz(count, 3);
    std::vector<int> person(count);
    std::vector<uint8_t> foot(count);
    person_slot.assign(frame_people[f], -1);
    for (int j = 0; j < count; ++j) {
      const int i = frame_points[begin + j];
      frame_xyz.row(j) = points.row(i);
      person[j] = slot_person[point_slot[i]];
      foot[j] = is_foot[i];
      person_slot[person[j]] = point_slot[i];
    }
    const FramePlanes planes = EstimateFramePlanes(frame_xyz, person, foot, frame_people[f], up, options);
    for (int q = 0; q < frame_people[f]; ++q) {
      if (person_slot[q] < 0 || !planes.via_feet[q]) continue;
      const Plane& plane = planes.planes[planes.person_plane[q]];
      slot_normal.row(person_slot[q]) = plane.normal;
      slot_offset(person_slot[q]) = plane.offset;
      slot_observed[person_slot[q]] = 1;
    }
  }

  std::vector<TrackPlanes> tracks(num_tracks);
  for (int p = 0; p < num_tracks; ++p) {
    const int b = slot_begin[p], T = slot_begin[p + 1] - b;
    tracks[p] = FillTrack(slot_normal.middleRows(b, T), slot_offset.segment(b, T),
                          std::vector<uint8_t>(slot_observed.begin() + b, slot_observed.begin() + b + T),
                          track_frames[p], options.fill);
  }
  return tracks;
}

}  // namespace m3c::ground
