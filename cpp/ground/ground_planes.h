// Per-person ground planes from body contacts (the seed thesis, section 4.1.3 "Ground Estimation"):
//  1. gather every contact vertex (contact probability > 0.5) of every person in a frame;
//  2. cluster them with DBSCAN;
//  3. fit a plane to each cluster (total least squares, optionally robust, with a minimum support);
//  4. associate each person with the plane closest to its contact vertices, its foot vertices examined first;
//  5. per track, keep for every frame the most recent plane its feet were in contact with; frames without foot
//     contact (a jump, a sit) never produce a plane, they are filled from the observed frames.
#pragma once

#include <cstdint>
#include <vector>

#include "ground/dbscan.h"
#include "ground/plane_fit.h"
#include "ground/types.h"

namespace m3c::ground {

// How a track's frames without a plane observation are filled.
enum class GapFill {
  kHold,    // the most recent observed plane (frames before the first observation take the first one)
  kLinear,  // interpolate between the observed planes around the gap (normal: normalised lerp, offset: lerp),
            // holding the first / last observation before / after them
};

struct GroundOptions {
  double eps = 0.15;              // DBSCAN radius, metres
  int min_samples = 10;           // DBSCAN core threshold (counts the point itself)
  PlaneFitOptions fit;            // per-cluster plane fit; clusters failing it give no plane
  double max_distance = 0.10;     // metres: a person's contact points must have median |distance| <= this
  GapFill fill = GapFill::kHold;  // temporal filling of frames without an observation
};

void ValidateGroundOptions(const GroundOptions& options);

struct FramePlanes {
  DbscanResult clusters;              // per contact point
  std::vector<Plane> planes;          // one per cluster; meaningful where plane_ok
  std::vector<uint8_t> plane_ok;      // per cluster: the fit met the support rule
  std::vector<int> person_plane;      // per person: cluster id of the associated plane, or -1
  std::vector<uint8_t> via_feet;      // per person: the association used foot contacts (only these feed tracks)
};

// One frame. points (N, 3): contact vertices of every person; person (N): the person (0..num_people-1) each point
// belongs to; is_foot (N): the point is a foot vertex. Association: a person's foot points if it has any, else all
// its points; the plane with the smallest median |signed distance| over them wins, if <= max_distance.
FramePlanes EstimateFramePlanes(const PointsRef& points, const std::vector<int>& person,
                                const std::vector<uint8_t>& is_foot, int num_people, const Eigen::Vector3d& up,
                                const GroundOptions& options);

struct TrackPlanes {
  Points3 normal;                 // (T, 3) unit normals; NaN where !valid
  Eigen::VectorXd offset;         // (T,) offsets; NaN where !valid
  std::vector<uint8_t> observed;  // (T,) the plane comes from this frame (feet in contact)
  std::vector<uint8_t> valid;     // (T,) a plane exists (observed or filled); false only for tracks never observed
};

// Fills a track from its observations: normal (T,3)/offset (T,) are read where observed, times (T,) are strictly
// increasing frame ids used as the interpolation abscissa. Returns the filled track.
TrackPlanes FillTrack(const Points3& normal, const Eigen::VectorXd& offset, const std::vector<uint8_t>& observed,
                      const std::vector<int64_t>& times, GapFill fill);

// All tracks of a video. Contact point i lies at points.row(i), belongs to track point_track[i] at step
// point_step[i] (an index into track_frames[track]), and is a foot vertex when is_foot[i]. track_frames[p] holds
// track p's frame ids, strictly increasing; tracks sharing a frame id are processed together in that frame.
std::vector<TrackPlanes> EstimateTrackPlanes(const PointsRef& points, const std::vector<int>& point_track,
                                             const std::vector<int>& point_step, const std::vector<uint8_t>& is_foot,
                                             const std::vector<std::vector<int64_t>>& track_frames,
                                             const Eigen::Vector3d& up, const GroundOptions& options);

}  // namespace m3c::ground
