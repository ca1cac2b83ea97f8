#include "vo/patch_vo.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>
#include <unordered_map>

#include <opencv2/imgproc.hpp>

#include "util/check.h"
#include "vo/pose_refine.h"

namespace m3c::vo {

namespace {

using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

double Median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  return v[mid];
}

}  // namespace

struct PatchVO::Impl {
  struct Patch {
    int host = 0;  // frame id
    Eigen::Vector2d uv = Eigen::Vector2d::Zero();
    double inverse_depth = 1.0;
    bool dead = false;       // its host stopped being a keyframe
    bool optimized = false;  // has been through a bundle adjustment
    Eigen::Vector2d last_uv = Eigen::Vector2d::Zero();
    std::vector<int> observations;
  };
  struct Observation {
    int patch = 0;
    int frame = 0;
    Eigen::Vector2d uv = Eigen::Vector2d::Zero();
    double weight = 1.0;
    bool outlier = false;
  };
  struct Frame {
    Rigid3 cam_from_world;  // keyframes; for the others see ref/delta
    bool keyframe = false;
    int ref = -1;            // non-keyframes: cam_from_world = delta * pose(ref); -1: identity (before the map)
    Rigid3 delta;
    bool released = false;   // the front-end no longer holds it
    bool motion_estimated = true;  // false: skipped before initialisation, delta is a placeholder
    FrameQuality quality;
    std::vector<int> observations;
    std::vector<int> hosted;
  };

  PatchVOOptions options;
  Intrinsics input_intrinsics;  // may be invalid until the first frame
  Intrinsics K;                 // processing resolution
  double scale = 1.0;
  cv::Size input_size, size;
  std::unique_ptr<FrontEnd> front_end;

  std::vector<Frame> frames;
  std::vector<Patch> patches;
  std::vector<Observation> observations;
  std::vector<int> keyframes;      // frame ids, in order
  std::vector<int> keyframe_index;  // per frame: index in `keyframes`, -1 if not a keyframe
  bool started = false;
  bool initialized = false;
  bool finished = false;
  double depth_scale = 1.0;  // inverse depth = depth_scale / depth_map
  int restarted_at = -1;     // last frame where tracking restarted before initialisation
  PatchVOStats stats;
  Clock::time_point start_time;

  // ---- poses ----
  Rigid3 PoseOf(int f) const {
    // Walk the chain of relative poses down to a keyframe (or the identity before the map).
    Rigid3 acc;
    while (f >= 0 && !frames[f].keyframe) {
      acc = acc * frames[f].delta;
      f = frames[f].ref;
    }
    return f >= 0 ? acc * frames[f].cam_from_world : acc;
  }

  Rigid3 PredictPose(int t) const {
    if (!initialized || t < 2) return t >= 1 ? PoseOf(t - 1) : Rigid3();
    const Rigid3 p1 = PoseOf(t - 1), p2 = PoseOf(t - 2);
    const Eigen::Matrix<double, 6, 1> step = LeftMinus(p1, p2);
    return LeftPlus(p1, options.motion_damping * step);
  }

  void RebuildKeyframeIndex() {
    keyframe_index.assign(frames.size(), -1);
    for (int i = 0; i < static_cast<int>(keyframes.size()); ++i) keyframe_index[keyframes[i]] = i;
  }

  // Reprojection of patch p into a camera (pixels); false if behind it.
  bool Project(const Patch& p, const Rigid3& target_from_world, Eigen::Vector2d* uv) const {
    const Rigid3 target_from_host = target_from_world * PoseOf(p.host).Inverse();
    const Eigen::Vector3d y =
        target_from_host.rotation * K.Unproject(p.uv) + p.inverse_depth * target_from_host.translation;
    if (y.z() < kMinDepthRatio) return false;
    *uv = Eigen::Vector2d(K.fx * y.x() / y.z() + K.cx, K.fy * y.y() / y.z() + K.cy);
    return std::isfinite(uv->x()) && std::isfinite(uv->y());
  }

  bool Inside(const Eigen::Vector2d& uv) const {
    return uv.x() >= 0 && uv.y() >= 0 && uv.x() <= size.width - 1 && uv.y() <= size.height - 1;
  }

  int AddObservation(int patch, int frame, const TrackResult& r) {
    Observation o;
    o.patch = patch;
    o.frame = frame;
    o.uv = r.uv;
    o.weight = r.weight;
    observations.push_back(o);
    const int id = static_cast<int>(observations.size()) - 1;
    patches[patch].observations.push_back(id);
    frames[frame].observations.push_back(id);
    return id;
  }

  // ---- input ----
  void Prepare(const cv::Mat& image, const cv::Mat& mask, const cv::Mat& depth, cv::Mat* gray_out, cv::Mat* mask_out,
               cv::Mat* depth_out) {
    M3C_CHECK(!image.empty()) << "frame " << frames.size() << " is empty";
    M3C_CHECK(image.depth() == CV_8U && (image.channels() == 1 || image.channels() == 3))
        << "frame " << frames.size() << " must be 8-bit gray or 3-channel";
    if (frames.empty()) {
      input_size = image.size();
      M3C_CHECK(input_size.width >= 32 && input_size.height >= 32)
          << "frames must be at least 32x32 pixels, got " << input_size.width << "x" << input_size.height;
      if (!input_intrinsics.Valid()) input_intrinsics = Intrinsics::Default(input_size.width, input_size.height);
      const int side = std::max(input_size.width, input_size.height);
      scale = (options.max_image_side > 0 && side > options.max_image_side)
                  ? double(options.max_image_side) / side
                  : 1.0;
      size = scale < 1.0 ? cv::Size(std::max(1, static_cast<int>(std::lround(input_size.width * scale))),
                                    std::max(1, static_cast<int>(std::lround(input_size.height * scale))))
                         : input_size;
      // The exact resize factor per axis can differ from `scale` by rounding; use the horizontal one.
      scale = double(size.width) / input_size.width;
      K = input_intrinsics.Scaled(scale);
    }
    M3C_CHECK(image.size() == input_size) << "frame " << frames.size() << " is " << image.cols << "x" << image.rows
                                          << ", the first frame was " << input_size.width << "x" << input_size.height;
    cv::Mat gray;
    if (image.channels() == 3) {
      cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
    } else {
      gray = image;
    }
    if (size != input_size) {
      cv::resize(gray, *gray_out, size, 0, 0, cv::INTER_AREA);
    } else {
      *gray_out = gray.clone();
    }
    if (!mask.empty()) {
      M3C_CHECK(mask.size() == input_size && mask.type() == CV_8UC1)
          << "mask " << frames.size() << " must be CV_8UC1 with the frame size";
      cv::Mat m;
      if (size != input_size) {
        cv::resize(mask, m, size, 0, 0, cv::INTER_AREA);
      } else {
        m = mask;
      }
      cv::compare(m, 0, *mask_out, cv::CMP_GT);  // any coverage masks the pixel
    }
    if (!depth.empty() && options.use_depth) {
      M3C_CHECK(depth.size() == input_size && depth.type() == CV_32FC1)
          << "depth " << frames.size() << " must be CV_32FC1 with the frame size";
      if (size != input_size) {
        cv::resize(depth, *depth_out, size, 0, 0, cv::INTER_NEAREST);
      } else {
        *depth_out = depth.clone();
      }
    }
  }

  // Median depth-map value around a pixel; NaN where unknown.
  double DepthAt(const cv::Mat& depth, const Eigen::Vector2d& uv) const {
    const int r = std::max(0, options.depth_window_px);
    const int cx = static_cast<int>(std::lround(uv.x())), cy = static_cast<int>(std::lround(uv.y()));
    std::vector<double> values;
    for (int y = std::max(0, cy - r); y <= std::min(depth.rows - 1, cy + r); ++y) {
      for (int x = std::max(0, cx - r); x <= std::min(depth.cols - 1, cx + r); ++x) {
        const float d = depth.at<float>(y, x);
        if (std::isfinite(d) && d > 0) values.push_back(d);
      }
    }
    return Median(values);
  }

  // ---- patches ----
  double MedianRecentInverseDepth() const {
    std::vector<double> v;
    const int K_now = static_cast<int>(keyframes.size());
    for (int i = std::max(0, K_now - 3); i < K_now; ++i) {
      for (int p : frames[keyframes[i]].hosted) {
        if (!patches[p].dead) v.push_back(patches[p].inverse_depth);
      }
    }
    return v.empty() ? 1.0 : Median(v);
  }

  // Aligns the depth map's scale to the current map through the patches just measured in frame t.
  void AlignDepthScale(int t, const cv::Mat& depth, const Rigid3& cam_from_world) {
    std::vector<double> ratios;
    for (int o : frames[t].observations) {
      const Patch& p = patches[observations[o].patch];
      if (!p.optimized || p.dead) continue;
      const Rigid3 t_from_h = cam_from_world * PoseOf(p.host).Inverse();
      const Eigen::Vector3d y = t_from_h.rotation * K.Unproject(p.uv) + p.inverse_depth * t_from_h.translation;
      const double map_depth = DepthAt(depth, observations[o].uv);
      if (!(y.z() > kMinDepthRatio) || !std::isfinite(map_depth)) continue;
      ratios.push_back(p.inverse_depth * map_depth / y.z());  // inverse depth in t times map depth
    }
    if (ratios.size() >= 8) depth_scale = Median(ratios);
  }

  void CreatePatches(int t, const cv::Mat& depth) {
    const auto t0 = Clock::now();
    const std::vector<Eigen::Vector2d> centres = front_end->SamplePatches(t, options.patches_per_frame);
    stats.front_end_seconds += Seconds(t0);
    const double fallback = MedianRecentInverseDepth();
    for (const Eigen::Vector2d& uv : centres) {
      Patch p;
      p.host = t;
      p.uv = uv;
      p.last_uv = uv;
      p.inverse_depth = fallback;
      if (!depth.empty()) {
        const double d = DepthAt(depth, uv);
        if (std::isfinite(d)) p.inverse_depth = std::clamp(depth_scale / d, 1e-3, 10.0);
      }
      frames[t].hosted.push_back(static_cast<int>(patches.size()));
      patches.push_back(p);
    }
  }

  // First keyframe: depth scale from its own depth map (median inverse depth 1), identity pose.
  bool TryStart(int t, const cv::Mat& depth) {
    const auto t0 = Clock::now();
    const std::vector<Eigen::Vector2d> probe = front_end->SamplePatches(t, options.patches_per_frame);
    stats.front_end_seconds += Seconds(t0);
    if (static_cast<int>(probe.size()) < options.min_texture_patches) return false;
    if (!depth.empty()) {
      std::vector<double> ds;
      for (const auto& uv : probe) {
        const double d = DepthAt(depth, uv);
        if (std::isfinite(d)) ds.push_back(d);
      }
      if (ds.size() >= 8) depth_scale = Median(ds);
    }
    frames[t].keyframe = true;
    frames[t].cam_from_world = Rigid3();
    keyframes.push_back(t);
    RebuildKeyframeIndex();
    CreatePatches(t, depth);
    frames[t].quality.keyframe = true;
    frames[t].quality.attempted = frames[t].quality.tracked = static_cast<int>(frames[t].hosted.size());
    started = true;
    return true;
  }

  // Drops every keyframe (tracking lost before the map was initialised); their frames keep the identity.
  void Restart() {
    for (int f : keyframes) {
      for (int p : frames[f].hosted) patches[p].dead = true;
      frames[f].keyframe = false;
      frames[f].ref = -1;
      frames[f].delta = Rigid3();
      frames[f].quality.keyframe = false;
      Release(f);
    }
    keyframes.clear();
    RebuildKeyframeIndex();
    started = false;
  }

  void Release(int f) {
    if (!frames[f].released) {
      front_end->ReleaseFrame(f);
      frames[f].released = true;
    }
  }

  // ---- bundle adjustment ----
  // Poses of keyframes with index >= first_free are optimised; patches hosted at index >= first_patch_host.
  PatchBASummary RunBA(int first_free, int first_patch_host, int iterations) {
    PatchBAData data;
    data.intrinsics = K;
    std::unordered_map<int, int> pose_slot;  // frame id -> index in data
    auto slot = [&](int frame) {
      auto it = pose_slot.find(frame);
      if (it != pose_slot.end()) return it->second;
      const int s = static_cast<int>(data.cam_from_world.size());
      pose_slot.emplace(frame, s);
      data.cam_from_world.push_back(frames[frame].cam_from_world);
      data.pose_fixed.push_back(keyframe_index[frame] < first_free ? 1 : 0);
      return s;
    };
    std::vector<int> patch_ids;
    for (int k = std::max(0, first_patch_host); k < static_cast<int>(keyframes.size()); ++k) {
      for (int p : frames[keyframes[k]].hosted) {
        const Patch& patch = patches[p];
        if (patch.dead) continue;
        int used = 0;
        const int patch_slot = static_cast<int>(data.patches.size());
        for (int o : patch.observations) {
          const Observation& ob = observations[o];
          if (ob.outlier || keyframe_index[ob.frame] < 0) continue;
          if (used == 0) {
            PatchBAPatch bp;
            bp.host = slot(patch.host);
            bp.uv = patch.uv;
            bp.inverse_depth = patch.inverse_depth;
            data.patches.push_back(bp);
            patch_ids.push_back(p);
          }
          PatchBAObservation bo;
          bo.patch = patch_slot;
          bo.target = slot(ob.frame);
          bo.uv = ob.uv;
          bo.weight = ob.weight;
          data.observations.push_back(bo);
          ++used;
        }
      }
    }
    PatchBAOptions ba;
    ba.loss = PatchBAOptions::Loss::kCauchy;
    ba.loss_scale_px = options.loss_scale_px;
    ba.max_iterations = iterations;
    ba.num_threads = options.num_threads;
    PatchBASummary summary = SolvePatchBA(ba, &data);
    if (!summary.usable) return summary;
    for (const auto& [frame, s] : pose_slot) {
      if (!data.pose_fixed[s]) frames[frame].cam_from_world = data.cam_from_world[s];
    }
    for (size_t i = 0; i < patch_ids.size(); ++i) {
      patches[patch_ids[i]].inverse_depth = data.patches[i].inverse_depth;
      patches[patch_ids[i]].optimized = true;
    }
    return summary;
  }

  double ObservationError(const Observation& o) const {
    Eigen::Vector2d uv;
    if (!Project(patches[o.patch], PoseOf(o.frame), &uv)) return std::numeric_limits<double>::infinity();
    return (uv - o.uv).norm();
  }

  // Adds the squared errors and the count of frame f's inlier measurements (of patches still in the map).
  void AddInlierErrors(int f, double* sum, int* inliers) const {
    for (int o : frames[f].observations) {
      if (patches[observations[o].patch].dead) continue;
      const double e = ObservationError(observations[o]);
      if (e < options.outlier_threshold_px) {
        *sum += e * e;
        ++*inliers;
      }
    }
  }

  double FitRms() const {
    if (!initialized) return std::numeric_limits<double>::infinity();
    double sum = 0.0;
    int inliers = 0;
    for (int f : keyframes) AddInlierErrors(f, &sum, &inliers);
    return inliers > 0 ? std::sqrt(sum / inliers) : std::numeric_limits<double>::infinity();
  }

  // Re-flags outliers among the observations (in keyframes) of patches hosted at keyframe index >= first_host.
  int UpdateOutliers(int first_host) {
    int changed = 0;
    for (int k = std::max(0, first_host); k < static_cast<int>(keyframes.size()); ++k) {
      for (int p : frames[keyframes[k]].hosted) {
        if (patches[p].dead) continue;
        for (int o : patches[p].observations) {
          Observation& ob = observations[o];
          if (keyframe_index[ob.frame] < 0) continue;
          const bool outlier = !(ObservationError(ob) < options.outlier_threshold_px);
          changed += outlier != ob.outlier;
          ob.outlier = outlier;
        }
      }
    }
    return changed;
  }

  // DPVO's flow_mag: mean of beta |full flow| + (1 - beta) |translation-only flow| of the patches hosted at
  // `host_frame` when seen from `target_from_world`; infinity when the host has no patches.
  double FlowMagnitude(int host_frame, const Rigid3& target_from_world) const {
    const Rigid3 j_from_i = target_from_world * frames[host_frame].cam_from_world.Inverse();
    const Eigen::Matrix3d R = j_from_i.rotation.toRotationMatrix();
    double sum = 0.0;
    int n = 0;
    for (int p : frames[host_frame].hosted) {
      const Patch& patch = patches[p];
      if (patch.dead) continue;
      const Eigen::Vector3d b = K.Unproject(patch.uv);
      const Eigen::Vector3d full = R * b + patch.inverse_depth * j_from_i.translation;
      const Eigen::Vector3d tonly = b + patch.inverse_depth * j_from_i.translation;
      if (full.z() < kMinDepthRatio || tonly.z() < kMinDepthRatio) continue;
      const double f1 = (K.Project(full) - patch.uv).norm();
      const double f2 = (K.Project(tonly) - patch.uv).norm();
      sum += options.flow_beta * f1 + (1.0 - options.flow_beta) * f2;
      ++n;
    }
    return n > 0 ? sum / n : std::numeric_limits<double>::infinity();
  }

  void MaybeRemoveKeyframe() {
    const int n = static_cast<int>(keyframes.size());
    const int k = n - options.keyframe_index;
    const int i = k - 1, j = k + 1;
    if (i < 0 || k < 1 || j >= n) return;
    const double m = 0.5 * (FlowMagnitude(keyframes[i], frames[keyframes[j]].cam_from_world) +
                            FlowMagnitude(keyframes[j], frames[keyframes[i]].cam_from_world));
    if (!(m < options.keyframe_threshold_px)) return;
    const int f = keyframes[k], ref = keyframes[k - 1];
    Frame& frame = frames[f];
    frame.delta = frame.cam_from_world * frames[ref].cam_from_world.Inverse();
    frame.ref = ref;
    frame.keyframe = false;
    frame.quality.keyframe = false;
    for (int p : frame.hosted) patches[p].dead = true;
    keyframes.erase(keyframes.begin() + k);
    RebuildKeyframeIndex();
    Release(f);
  }

  void ReleaseOldKeyframes() {
    const int n = static_cast<int>(keyframes.size());
    const int keep = std::max(options.patch_lifetime, options.backward_frames) + 2;
    for (int k = 0; k < n - keep; ++k) Release(keyframes[k]);
  }

  // ---- per frame ----
  void AddFrame(const cv::Mat& image, const cv::Mat& mask_in, const cv::Mat& depth_in) {
    if (frames.empty()) start_time = Clock::now();
    M3C_CHECK(!finished) << "PatchVO::AddFrame after Finish";
    cv::Mat gray, mask, depth;
    Prepare(image, mask_in, depth_in, &gray, &mask, &depth);
    const int t = static_cast<int>(frames.size());
    frames.emplace_back();
    keyframe_index.push_back(-1);
    auto t0 = Clock::now();
    front_end->AddFrame(t, gray, mask);
    stats.front_end_seconds += Seconds(t0);

    if (!started) {
      if (!TryStart(t, depth)) Release(t);
      return;
    }

    // Forward edges: live patches into the new frame.
    const Rigid3 predicted = PredictPose(t);
    const int n = static_cast<int>(keyframes.size());
    std::vector<TrackRequest> requests;
    std::vector<int> request_patch;
    for (int k = std::max(0, n - options.patch_lifetime); k < n; ++k) {
      const int host = keyframes[k];
      if (frames[host].released) continue;
      for (int p : frames[host].hosted) {
        const Patch& patch = patches[p];
        if (patch.dead) continue;
        TrackRequest r;
        r.host_frame = host;
        r.host_uv = patch.uv;
        r.predicted_uv = patch.last_uv;
        Eigen::Vector2d uv;
        if (patch.optimized && Project(patch, predicted, &uv) && Inside(uv)) r.predicted_uv = uv;
        requests.push_back(r);
        request_patch.push_back(p);
      }
    }
    t0 = Clock::now();
    std::vector<TrackResult> results = front_end->Track(t, requests);
    stats.front_end_seconds += Seconds(t0);
    frames[t].quality.attempted = static_cast<int>(requests.size());
    bool verified = false;

    // Commits the measurements still marked ok; returns how many.
    auto commit = [&](const std::vector<TrackResult>& res) {
      int count = 0;
      for (size_t i = 0; i < res.size(); ++i) {
        if (!res[i].ok) continue;
        AddObservation(request_patch[i], t, res[i]);
        patches[request_patch[i]].last_uv = res[i].uv;
        ++count;
      }
      frames[t].quality.tracked = count;
      return count;
    };
    auto verify = [&]() {
      if (verified) return;
      t0 = Clock::now();
      front_end->Verify(t, requests, &results);
      stats.front_end_seconds += Seconds(t0);
      verified = true;
    };

    if (!initialized) {
      // Before the map exists every decision rests on raw measurements, so check them all.
      verify();
      int measured = 0;
      for (const TrackResult& r : results) measured += r.ok;
      if (measured < options.min_texture_patches) {
        // Lost before the map existed: start again from this frame if it has texture, else keep waiting.
        if (static_cast<int>(front_end->SamplePatches(t, options.patches_per_frame).size()) >=
            options.min_texture_patches) {
          Restart();
          TryStart(t, depth);
          restarted_at = t;
        } else {
          commit(results);
          frames[t].ref = keyframes.back();
          frames[t].motion_estimated = false;
          Release(t);
        }
        return;
      }
      // Motion probe: median displacement since the last keyframe.
      const int last = keyframes.back();
      std::vector<double> flow;
      for (size_t i = 0; i < results.size(); ++i) {
        if (!results[i].ok) continue;
        const Patch& patch = patches[request_patch[i]];
        Eigen::Vector2d prev = patch.uv;
        bool found = patch.host == last;
        for (int po : patch.observations) {
          if (!found && observations[po].frame == last) {
            prev = observations[po].uv;
            found = true;
          }
        }
        if (found) flow.push_back((results[i].uv - prev).norm());
      }
      if (flow.empty() || Median(flow) < options.init_min_flow_px) {
        commit(results);
        frames[t].ref = last;
        frames[t].delta = Rigid3();
        frames[t].motion_estimated = false;
        Release(t);
        return;
      }
    }

    Rigid3 pose = predicted;
    if (initialized && options.new_keyframe_flow_px > 0) {
      // Motion-only pose against the current map. A frame that moved less than new_keyframe_flow_px (DPVO's
      // flow measure) since the last keyframe stays out of the graph, its pose kept relative to that keyframe:
      // it would be removed by the keyframe test anyway, and skipping it saves its patches and a window BA.
      std::vector<Eigen::Vector4d> points;
      std::vector<Eigen::Vector2d> uvs;
      for (size_t i = 0; i < results.size(); ++i) {
        const Patch& p = patches[request_patch[i]];
        if (!results[i].ok || !p.optimized || p.dead) continue;
        points.push_back(WorldPoint(p, false));
        uvs.push_back(results[i].uv);
      }
      if (static_cast<int>(points.size()) >= options.min_refine_observations) {
        PoseRefineOptions ro;
        ro.loss_scale_px = options.loss_scale_px;
        ro.max_iterations = 6;
        const PoseRefineResult r = RefinePose(K, points, uvs, predicted, ro);
        if (r.improved) pose = r.cam_from_world;
        const int last = keyframes.back();
        if (FlowMagnitude(last, pose) < options.new_keyframe_flow_px) {
          // Unverified measurements are gated by their reprojection error under the fitted pose instead.
          for (size_t i = 0; i < results.size(); ++i) {
            const Patch& p = patches[request_patch[i]];
            Eigen::Vector2d uv;
            if (results[i].ok && p.optimized &&
                !(Project(p, pose, &uv) && (uv - results[i].uv).norm() < options.outlier_threshold_px)) {
              results[i].ok = false;
            }
          }
          commit(results);
          frames[t].ref = last;
          frames[t].delta = pose * frames[last].cam_from_world.Inverse();
          Release(t);
          return;
        }
      }
    }
    verify();
    commit(results);

    // The new frame becomes a keyframe.
    frames[t].keyframe = true;
    frames[t].quality.keyframe = true;
    frames[t].cam_from_world = pose;
    keyframes.push_back(t);
    RebuildKeyframeIndex();
    if (!depth.empty() && initialized) AlignDepthScale(t, depth, pose);
    CreatePatches(t, depth);

    // Backward edges: the new patches into the previous keyframes.
    const int nk = static_cast<int>(keyframes.size());
    for (int k = std::max(0, nk - 1 - options.backward_frames); k < nk - 1; ++k) {
      const int target = keyframes[k];
      if (frames[target].released) continue;
      std::vector<TrackRequest> back;
      std::vector<int> back_patch;
      for (int p : frames[t].hosted) {
        TrackRequest r;
        r.host_frame = t;
        r.host_uv = patches[p].uv;
        r.predicted_uv = patches[p].uv;
        Eigen::Vector2d uv;
        if (initialized && Project(patches[p], frames[target].cam_from_world, &uv) && Inside(uv)) r.predicted_uv = uv;
        back.push_back(r);
        back_patch.push_back(p);
      }
      t0 = Clock::now();
      std::vector<TrackResult> back_results = front_end->Track(target, back);
      front_end->Verify(target, back, &back_results);
      stats.front_end_seconds += Seconds(t0);
      for (size_t i = 0; i < back_results.size(); ++i) {
        if (back_results[i].ok) AddObservation(back_patch[i], target, back_results[i]);
      }
    }

    if (!initialized) {
      if (nk >= options.init_frames) Initialise();
    } else {
      const int first_free = std::max(nk - options.optimization_window, 1);
      const int first_host = std::max(nk - options.removal_window, 0);
      const PatchBASummary s = RunBA(first_free, first_host, options.window_iterations);
      stats.window_ba_count += 1;
      stats.window_ba_seconds += s.solve_seconds;
      UpdateOutliers(first_host);
      MaybeRemoveKeyframe();
    }
    ReleaseOldKeyframes();
  }

  // The first bundle adjustment, from identity poses. With little parallax it has a local minimum that trades the
  // translation direction against rotation; with init_multi_start it also starts from a straight motion along
  // each camera axis (both signs, DPVO-like step per keyframe) and keeps the start with the lowest robust cost.
  void Initialise() {
    const int n = static_cast<int>(keyframes.size());
    std::vector<int> patch_ids;
    for (int f : keyframes) {
      for (int p : frames[f].hosted) {
        if (!patches[p].dead) patch_ids.push_back(p);
      }
    }
    std::vector<double> start_depths;
    for (int p : patch_ids) start_depths.push_back(patches[p].inverse_depth);
    std::vector<Eigen::Vector3d> directions = {Eigen::Vector3d::Zero()};
    if (options.init_multi_start) {
      for (int axis = 0; axis < 3; ++axis) {
        for (double sign : {1.0, -1.0}) directions.push_back(sign * Eigen::Vector3d::Unit(axis));
      }
    }
    const double step = options.init_min_flow_px / K.fx;  // camera shift per keyframe, in units of patch depth
    double best_cost = std::numeric_limits<double>::infinity();
    std::vector<Rigid3> best_poses;
    std::vector<double> best_depths;
    for (size_t d = 0; d < directions.size(); ++d) {
      for (size_t i = 0; i < patch_ids.size(); ++i) patches[patch_ids[i]].inverse_depth = start_depths[i];
      for (int k = 0; k < n; ++k) {
        frames[keyframes[k]].cam_from_world = Rigid3(Eigen::Quaterniond::Identity(), -(step * k) * directions[d]);
      }
      const PatchBASummary s = RunBA(1, 0, options.init_iterations);
      stats.init_ba_seconds += s.solve_seconds;
      stats.init_ba_starts += 1;
      if (d == 0) stats.init_ba_initial_cost = s.initial_cost;
      if (!s.usable || !(s.final_cost < best_cost)) continue;
      best_cost = s.final_cost;
      stats.init_ba_iterations = s.iterations;
      stats.init_ba_final_cost = s.final_cost;
      best_poses.clear();
      for (int f : keyframes) best_poses.push_back(frames[f].cam_from_world);
      best_depths.clear();
      for (int p : patch_ids) best_depths.push_back(patches[p].inverse_depth);
    }
    if (!best_poses.empty()) {
      for (int k = 0; k < n; ++k) frames[keyframes[k]].cam_from_world = best_poses[k];
      for (size_t i = 0; i < patch_ids.size(); ++i) patches[patch_ids[i]].inverse_depth = best_depths[i];
    }
    initialized = true;
    UpdateOutliers(0);
  }

  // ---- end of sequence ----
  PatchVOResult Finish() {
    M3C_CHECK(!finished) << "PatchVO::Finish called twice";
    M3C_CHECK(frames.size() >= 2) << "too few frames: patch VO needs at least 2, got " << frames.size();
    M3C_CHECK(started) << "no texture: no frame had " << options.min_texture_patches
                       << " patches with pooled gradient >= " << options.lucas_kanade.sampling.min_gradient
                       << " grey levels/pixel outside the masks; check the frames (blank, overexposed, fully masked?)";
    finished = true;
    PatchVOResult result;
    result.intrinsics = input_intrinsics;
    result.processing_scale = scale;
    const int T = static_cast<int>(frames.size());
    const int first = keyframes.front();

    // Short sequences that moved but never reached init_frames keyframes are initialised with what there is.
    if (!initialized && keyframes.size() >= 2) Initialise();
    if (!initialized) {
      result.static_camera = true;
      FitStaticRotations();
      std::ostringstream message;
      message << "near-static camera: no frame moved the patches by " << options.init_min_flow_px
              << " px (median, processing resolution) from the first; translation set to zero, rotation fitted";
      result.message = message.str();
    } else {
      // Final pass over all keyframes; a second one when the outlier set moved.
      PatchBASummary s = RunBA(1, 0, options.final_iterations);
      stats.final_ba_iterations += s.iterations;
      stats.final_ba_seconds += s.solve_seconds;
      if (UpdateOutliers(0) > 0) {
        s = RunBA(1, 0, options.final_iterations);
        stats.final_ba_iterations += s.iterations;
        stats.final_ba_seconds += s.solve_seconds;
        UpdateOutliers(0);
      }
      ResolveNonKeyframes(false, options.refine_non_keyframes);
      result.message = "ok";
    }

    if (restarted_at >= 0) {
      result.message += "; tracking was lost before initialisation and restarted at frame " +
                        std::to_string(restarted_at) + ", earlier frames keep the identity pose";
    }

    // Quality per frame at the final estimate.
    for (int t = 0; t < T; ++t) {
      FrameQuality& q = frames[t].quality;
      double sum = 0.0;
      int inliers = 0;
      AddInlierErrors(t, &sum, &inliers);
      q.inliers = inliers;
      q.reprojection_rms_px = inliers > 0 ? std::sqrt(sum / inliers) : 0.0;
    }

    // world = the first keyframe's camera (identity by construction; frames before it have no motion estimate).
    const Rigid3 first_from_world = PoseOf(first);
    result.world_from_cam.resize(T);
    result.quality.resize(T);
    for (int t = 0; t < T; ++t) {
      result.world_from_cam[t] = t < first ? Rigid3() : first_from_world * PoseOf(t).Inverse();
      result.quality[t] = frames[t].quality;
    }
    if (initialized) CollectMapPoints(first_from_world, &result.points);
    stats.num_frames = T;
    stats.num_keyframes = static_cast<int>(keyframes.size());
    stats.num_patches = static_cast<int>(patches.size());
    stats.num_observations = static_cast<int>(observations.size());
    stats.keyframe_fit_rms_px = FitRms();
    stats.total_seconds = Seconds(start_time);
    result.stats = stats;
    return result;
  }

  // The final map (see PatchVOResult::points), in the result's world frame (`first_from_world` * internal world).
  void CollectMapPoints(const Rigid3& first_from_world, std::vector<MapPoint>* points) const {
    for (int f : keyframes) {
      for (int id : frames[f].hosted) {
        const Patch& p = patches[id];
        if (p.dead || !p.optimized || !(p.inverse_depth > 0) || !std::isfinite(p.inverse_depth)) continue;
        int inliers = 0;
        for (int o : p.observations) {
          const Observation& ob = observations[o];
          if (keyframe_index[ob.frame] >= 0 && ObservationError(ob) < options.outlier_threshold_px) ++inliers;
        }
        if (inliers == 0) continue;
        const Eigen::Vector4d x = WorldPoint(p, false);
        MapPoint m;
        m.world = first_from_world * Eigen::Vector3d(x.head<3>() / x.w());
        m.host_frame = p.host;
        // Inverse of Intrinsics::Scaled's pixel mapping (pixel centres at integer + 0.5).
        m.host_uv = (p.uv.array() + 0.5) / scale - 0.5;
        m.inlier_observations = inliers;
        points->push_back(m);
      }
    }
  }

  // Homogeneous world point of a patch (w = inverse depth; at infinity when `at_infinity`).
  Eigen::Vector4d WorldPoint(const Patch& p, bool at_infinity) const {
    const Rigid3 host_from_world = frames[p.host].cam_from_world;
    const double d = at_infinity ? 0.0 : p.inverse_depth;
    const Eigen::Vector3d b = K.Unproject(p.uv);
    Eigen::Vector4d x;
    x.head<3>() = host_from_world.rotation.conjugate() * (b - d * host_from_world.translation);
    x.w() = d;
    return x;
  }

  // Every non-keyframe ends with an absolute pose (ref = -1, delta = cam_from_world): composed from its relative
  // pose, or interpolated when it was skipped before initialisation; with `refine`, then fitted motion-only to
  // the (fixed) final map. For a static camera (rotation_only) every frame's rotation is fitted to the first
  // keyframe's patches taken at infinity.
  void ResolveNonKeyframes(bool rotation_only, bool refine) {
    const int T = static_cast<int>(frames.size());
    const int first = keyframes.front();
    std::vector<Rigid3> pose(T);
    for (int t = 0; t < T; ++t) pose[t] = PoseOf(t);
    if (!rotation_only) {
      // Frames skipped before initialisation have no motion estimate of their own: interpolate between the
      // keyframes around them (slerp on rotation, linear on the camera centre).
      for (int t = first + 1; t < T; ++t) {
        if (frames[t].keyframe || frames[t].motion_estimated) continue;
        const auto next = std::lower_bound(keyframes.begin(), keyframes.end(), t);
        if (next == keyframes.end() || next == keyframes.begin()) continue;
        const int b = *next, a = *(next - 1);
        pose[t] = Interpolate(pose[a], pose[b], double(t - a) / double(b - a));
        frames[t].quality.interpolated = true;
      }
    }
    for (int t = first + 1; t < T && refine; ++t) {
      if (frames[t].keyframe && !rotation_only) continue;
      std::vector<Eigen::Vector4d> points;
      std::vector<Eigen::Vector2d> uvs;
      for (int o : frames[t].observations) {
        const Observation& ob = observations[o];
        const Patch& p = patches[ob.patch];
        if (p.dead || keyframe_index[p.host] < 0 || (rotation_only && p.host != first)) continue;
        points.push_back(WorldPoint(p, rotation_only));
        uvs.push_back(ob.uv);
      }
      if (static_cast<int>(points.size()) < options.min_refine_observations) continue;
      PoseRefineOptions ro;
      ro.rotation_only = rotation_only;
      ro.loss_scale_px = options.loss_scale_px;
      const PoseRefineResult r = RefinePose(K, points, uvs, pose[t], ro);
      if (!r.improved) continue;
      pose[t] = r.cam_from_world;
      frames[t].quality.refined = true;
    }
    for (int t = 0; t < T; ++t) {
      if (!frames[t].keyframe) {
        frames[t].ref = -1;
        frames[t].delta = pose[t];
      } else if (rotation_only) {
        frames[t].cam_from_world = pose[t];
      }
    }
  }

  void FitStaticRotations() {
    // Every keyframe stays at the identity; translations are zero; rotations against patches at infinity.
    for (int f : keyframes) frames[f].cam_from_world = Rigid3();
    ResolveNonKeyframes(true, true);
  }
};

PatchVO::PatchVO(const PatchVOOptions& options, const Intrinsics& intrinsics, std::unique_ptr<FrontEnd> front_end)
    : impl_(std::make_unique<Impl>()) {
  M3C_CHECK(options.patches_per_frame >= 8) << "patches_per_frame must be >= 8";
  M3C_CHECK(options.patch_lifetime >= 2) << "patch_lifetime must be >= 2";
  M3C_CHECK(options.optimization_window >= 2) << "optimization_window must be >= 2";
  M3C_CHECK(options.removal_window >= options.optimization_window) << "removal_window must be >= optimization_window";
  M3C_CHECK(options.init_frames >= 2) << "init_frames must be >= 2";
  M3C_CHECK(options.keyframe_index >= 2) << "keyframe_index must be >= 2";
  M3C_CHECK(options.backward_frames >= 0 && options.backward_frames < options.patch_lifetime)
      << "backward_frames must be in [0, patch_lifetime)";
  M3C_CHECK(options.loss_scale_px > 0 && options.outlier_threshold_px > 0) << "loss scale and outlier threshold > 0";
  M3C_CHECK(options.num_threads >= 1) << "num_threads must be >= 1, got " << options.num_threads;
  const bool given = intrinsics.fx != 0 || intrinsics.fy != 0 || intrinsics.cx != 0 || intrinsics.cy != 0;
  M3C_CHECK(!given || intrinsics.Valid()) << "intrinsics must have finite fx, fy > 0 (got fx=" << intrinsics.fx
                                          << ", fy=" << intrinsics.fy << ")";
  impl_->options = options;
  impl_->input_intrinsics = intrinsics;
  impl_->front_end = front_end ? std::move(front_end) : std::make_unique<LucasKanadeFrontEnd>(options.lucas_kanade);
}

PatchVO::~PatchVO() = default;

void PatchVO::AddFrame(const cv::Mat& image, const cv::Mat& mask, const cv::Mat& depth) {
  impl_->AddFrame(image, mask, depth);
}

PatchVOResult PatchVO::Finish() { return impl_->Finish(); }

double PatchVO::FitRms() const { return impl_->FitRms(); }

int PatchVO::num_frames() const { return static_cast<int>(impl_->frames.size()); }

PatchVOResult RunPatchVO(const std::vector<cv::Mat>& frames, const std::vector<cv::Mat>& masks,
                         const std::vector<cv::Mat>& depths, const Intrinsics& intrinsics,
                         const PatchVOOptions& options) {
  M3C_CHECK(masks.empty() || masks.size() == frames.size())
      << masks.size() << " masks for " << frames.size() << " frames";
  M3C_CHECK(depths.empty() || depths.size() == frames.size())
      << depths.size() << " depth maps for " << frames.size() << " frames";
  PatchVO vo(options, intrinsics);
  for (size_t t = 0; t < frames.size(); ++t) {
    vo.AddFrame(frames[t], masks.empty() ? cv::Mat() : masks[t], depths.empty() ? cv::Mat() : depths[t]);
  }
  return vo.Finish();
}

}  // namespace m3c::vo
