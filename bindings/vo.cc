// Bindings for cpp/vo: the patch visual odometry (streaming class and whole-sequence function) and its options.
// Frames are uint8 numpy arrays (H, W) gray or (H, W, 3) RGB/BGR; masks bool/uint8 (H, W), non-zero = person;
// depth maps float (H, W) along the camera z axis (any consistent unit; <= 0 or non-finite = unknown).
#include <cmath>
#include <cstring>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <opencv2/imgproc.hpp>

#include "bindings/numpy_util.h"
#include "vo/front_end.h"
#include "vo/patch_vo.h"

namespace m3c::bindings {

namespace {

using m3c::Intrinsics;
using vo::PatchVO;
using vo::PatchVOOptions;
using vo::PatchVOResult;

using U8Array = py::array_t<uint8_t, py::array::c_style>;

// OpenCV indexes images with int; an empty image has nothing to track.
void CheckImageSize(py::ssize_t h, py::ssize_t w, const std::string& name) {
  if (h < 1 || w < 1 || h > 1 << 15 || w > 1 << 15) {
    throw py::value_error(name + " is " + std::to_string(h) + " x " + std::to_string(w) +
                          " pixels; expected 1..32768 pixels on each side");
  }
}

// A frame as a gray cv::Mat that owns its pixels (the numpy buffer may go away once the GIL is released).
cv::Mat FrameToGray(const py::handle& frame, const std::string& name, bool bgr) {
  const U8Array a = AsBytes(frame, name, "a uint8 image (H, W) or (H, W, 3)");
  if (a.ndim() >= 2) CheckImageSize(a.shape(0), a.shape(1), name);
  if (a.ndim() == 2) {
    return cv::Mat(static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), CV_8UC1,
                   const_cast<uint8_t*>(a.data()))
        .clone();
  }
  if (a.ndim() == 3 && a.shape(2) == 3) {
    const cv::Mat color(static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), CV_8UC3,
                        const_cast<uint8_t*>(a.data()));
    cv::Mat gray;
    cv::cvtColor(color, gray, bgr ? cv::COLOR_BGR2GRAY : cv::COLOR_RGB2GRAY);
    return gray;
  }
  ShapeError(name, "(H, W) or (H, W, 3)", a);
}

cv::Mat MaskToMat(const py::handle& obj, const std::string& name, int h, int w) {
  if (obj.is_none()) return cv::Mat();
  const U8Array c = AsBytes(obj, name, "a bool or uint8 mask (H, W)");
  if (c.ndim() != 2 || c.shape(0) != h || c.shape(1) != w) {
    ShapeError(name, "(" + std::to_string(h) + ", " + std::to_string(w) + ")", c);
  }
  return cv::Mat(h, w, CV_8UC1, const_cast<uint8_t*>(c.data())).clone();
}

cv::Mat DepthToMat(const py::handle& obj, const std::string& name, int h, int w) {
  if (obj.is_none()) return cv::Mat();
  auto a = AsArray<float>(obj, name, Cast::kSameKind);  // stored as float32; non-finite = unknown depth
  if (a.ndim() != 2 || a.shape(0) != h || a.shape(1) != w) {
    ShapeError(name, "(" + std::to_string(h) + ", " + std::to_string(w) + ")", a);
  }
  return cv::Mat(h, w, CV_32FC1, const_cast<float*>(a.data())).clone();
}

Intrinsics ParseIntrinsics(const py::handle& obj) {
  if (obj.is_none()) return Intrinsics{};
  auto a = AsArray<double>(obj, "intrinsics");
  if (a.ndim() != 1 || a.shape(0) != 4) ShapeError("intrinsics", "(4,) = (fx, fy, cx, cy)", a);
  RequireFinite(a, "intrinsics");
  const Intrinsics K{a.at(0), a.at(1), a.at(2), a.at(3)};
  if (!K.Valid()) throw py::value_error("intrinsics must be finite with fx, fy > 0");
  return K;
}

py::dict ResultToDict(const PatchVOResult& r) {
  const py::ssize_t T = static_cast<py::ssize_t>(r.world_from_cam.size());
  py::array_t<double> poses({T, py::ssize_t{4}, py::ssize_t{4}});
  auto pm = poses.mutable_unchecked<3>();
  py::array_t<int32_t> attempted(T), tracked(T), inliers(T);
  py::array_t<double> rms(T);
  py::array_t<bool> keyframe(T), interpolated(T), refined(T);
  for (py::ssize_t t = 0; t < T; ++t) {
    const Eigen::Matrix4d m = r.world_from_cam[t].ToMatrix();
    for (int i = 0; i < 4; ++i)
      for (int j = 0; j < 4; ++j) pm(t, i, j) = m(i, j);
    const vo::FrameQuality& q = r.quality[t];
    attempted.mutable_at(t) = q.attempted;
    tracked.mutable_at(t) = q.tracked;
    inliers.mutable_at(t) = q.inliers;
    rms.mutable_at(t) = q.reprojection_rms_px;
    keyframe.mutable_at(t) = q.keyframe;
    interpolated.mutable_at(t) = q.interpolated;
    refined.mutable_at(t) = q.refined;
  }
  py::array_t<double> K(4);
  K.mutable_at(0) = r.intrinsics.fx, K.mutable_at(1) = r.intrinsics.fy;
  K.mutable_at(2) = r.intrinsics.cx, K.mutable_at(3) = r.intrinsics.cy;
  py::dict quality;
  quality["attempted"] = attempted;
  quality["tracked"] = tracked;
  quality["inliers"] = inliers;
  quality["reprojection_rms_px"] = rms;
  quality["keyframe"] = keyframe;
  quality["interpolated"] = interpolated;
  quality["refined"] = refined;
  const vo::PatchVOStats& s = r.stats;
  py::dict stats;
  stats["num_frames"] = s.num_frames;
  stats["num_keyframes"] = s.num_keyframes;
  stats["num_patches"] = s.num_patches;
  stats["num_observations"] = s.num_observations;
  stats["window_ba_count"] = s.window_ba_count;
  stats["window_ba_seconds"] = s.window_ba_seconds;
  stats["init_ba_starts"] = s.init_ba_starts;
  stats["init_ba_iterations"] = s.init_ba_iterations;
  stats["init_ba_initial_cost"] = s.init_ba_initial_cost;
  stats["init_ba_final_cost"] = s.init_ba_final_cost;
  stats["init_ba_seconds"] = s.init_ba_seconds;
  stats["final_ba_iterations"] = s.final_ba_iterations;
  stats["final_ba_seconds"] = s.final_ba_seconds;
  stats["front_end_seconds"] = s.front_end_seconds;
  stats["total_seconds"] = s.total_seconds;
  stats["keyframe_fit_rms_px"] = s.keyframe_fit_rms_px;
  const py::ssize_t M = static_cast<py::ssize_t>(r.points.size());
  py::array_t<double> points({M, py::ssize_t{3}}), pixels({M, py::ssize_t{2}});
  py::array_t<int32_t> point_frames(M), point_inliers(M);
  auto xm = points.mutable_unchecked<2>();
  auto uvm = pixels.mutable_unchecked<2>();
  for (py::ssize_t i = 0; i < M; ++i) {
    const vo::MapPoint& p = r.points[i];
    for (int k = 0; k < 3; ++k) xm(i, k) = p.world[k];
    uvm(i, 0) = p.host_uv.x(), uvm(i, 1) = p.host_uv.y();
    point_frames.mutable_at(i) = p.host_frame;
    point_inliers.mutable_at(i) = p.inlier_observations;
  }
  py::dict out;
  out["world_from_cam"] = poses;
  out["points"] = points;
  out["point_frames"] = point_frames;
  out["point_pixels"] = pixels;
  out["point_inliers"] = point_inliers;
  out["intrinsics"] = K;
  out["processing_scale"] = r.processing_scale;
  out["quality"] = quality;
  out["static_camera"] = r.static_camera;
  out["stats"] = stats;
  out["message"] = r.message;
  return out;
}

py::array_t<uint8_t> MatToArray(const cv::Mat& m) {
  py::array_t<uint8_t> out({m.rows, m.cols});
  for (int r = 0; r < m.rows; ++r) std::memcpy(out.mutable_data(r, 0), m.ptr<uint8_t>(r), m.cols);
  return out;
}

// A front-end written in Python (e.g. DPVO's networks, m3c.vo.dpvo): an object with
//   add_frame(frame: int, gray: uint8 (h, w), mask: uint8 (h, w) or None)
//   sample_patches(frame: int, count: int) -> float (n, 2) patch centres, pixels
//   track(target: int, hosts: int (n,), host_uv: float (n, 2), predicted_uv: float (n, 2))
//       -> (uv float (n, 2), weight float (n,), ok bool (n,))
//   release_frame(frame: int)
// at PatchVO's processing resolution. Each call takes the GIL (PatchVO runs without it).
class PyFrontEnd final : public vo::FrontEnd {
 public:
  explicit PyFrontEnd(py::object impl) : impl_(std::move(impl)) {}
  ~PyFrontEnd() override {
    py::gil_scoped_acquire gil;
    impl_ = py::object();
  }

  void AddFrame(int frame, const cv::Mat& gray, const cv::Mat& mask) override {
    py::gil_scoped_acquire gil;
    impl_.attr("add_frame")(frame, MatToArray(gray), mask.empty() ? py::object(py::none()) : MatToArray(mask));
  }

  std::vector<Eigen::Vector2d> SamplePatches(int frame, int count) override {
    py::gil_scoped_acquire gil;
    const auto centres = AsArray<double>(impl_.attr("sample_patches")(frame, count), "sample_patches()");
    if (centres.ndim() != 2 || centres.shape(1) != 2) ShapeError("sample_patches()", "(n, 2)", centres);
    std::vector<Eigen::Vector2d> out;
    for (py::ssize_t i = 0; i < centres.shape(0); ++i) out.emplace_back(centres.at(i, 0), centres.at(i, 1));
    return out;
  }

  std::vector<vo::TrackResult> Track(int target, const std::vector<vo::TrackRequest>& requests) override {
    py::gil_scoped_acquire gil;
    const py::ssize_t n = static_cast<py::ssize_t>(requests.size());
    py::array_t<int64_t> hosts(n);
    py::array_t<double> host_uv({n, py::ssize_t{2}}), predicted({n, py::ssize_t{2}});
    for (py::ssize_t i = 0; i < n; ++i) {
      hosts.mutable_at(i) = requests[i].host_frame;
      for (int c = 0; c < 2; ++c) {
        host_uv.mutable_at(i, c) = requests[i].host_uv[c];
        predicted.mutable_at(i, c) = requests[i].predicted_uv[c];
      }
    }
    const py::tuple out = impl_.attr("track")(target, hosts, host_uv, predicted);
    if (out.size() != 3) throw py::value_error("track() must return (uv, weight, ok)");
    const auto uv = AsArray<double>(out[0], "track() uv");
    const auto weight = AsArray<double>(out[1], "track() weight");
    const auto ok = py::array_t<bool, py::array::c_style | py::array::forcecast>::ensure(out[2]);
    if (uv.ndim() != 2 || uv.shape(0) != n || uv.shape(1) != 2) ShapeError("track() uv", "(n, 2)", uv);
    if (weight.ndim() != 1 || weight.shape(0) != n) ShapeError("track() weight", "(n,)", weight);
    if (!ok || ok.ndim() != 1 || ok.shape(0) != n) throw py::value_error("track() ok must be bool (n,)");
    std::vector<vo::TrackResult> results(requests.size());
    for (py::ssize_t i = 0; i < n; ++i) {
      results[i].uv = Eigen::Vector2d(uv.at(i, 0), uv.at(i, 1));
      results[i].weight = weight.at(i);
      results[i].ok = ok.at(i) && std::isfinite(weight.at(i)) && weight.at(i) > 0 && results[i].uv.allFinite();
    }
    return results;
  }

  void ReleaseFrame(int frame) override {
    py::gil_scoped_acquire gil;
    impl_.attr("release_frame")(frame);
  }

 private:
  py::object impl_;
};

// A streaming wrapper that converts numpy frames.
class PyPatchVO {
 public:
  PyPatchVO(const PatchVOOptions& options, const py::handle& intrinsics, bool bgr, const py::object& front_end)
      : vo_(options, ParseIntrinsics(intrinsics),
            front_end.is_none() ? nullptr : std::make_unique<PyFrontEnd>(front_end)),
        bgr_(bgr) {}

  void AddFrame(const py::handle& frame, const py::handle& mask, const py::handle& depth) {
    const std::string idx = "[" + std::to_string(vo_.num_frames()) + "]";
    cv::Mat gray = FrameToGray(frame, "frame" + idx, bgr_);
    cv::Mat m = MaskToMat(mask, "mask" + idx, gray.rows, gray.cols);
    cv::Mat d = DepthToMat(depth, "depth" + idx, gray.rows, gray.cols);
    py::gil_scoped_release release;
    vo_.AddFrame(gray, m, d);
  }

  py::dict Finish() {
    PatchVOResult r;
    {
      py::gil_scoped_release release;
      r = vo_.Finish();
    }
    return ResultToDict(r);
  }

  int num_frames() const { return vo_.num_frames(); }
  double fit_rms() const { return vo_.FitRms(); }

 private:
  PatchVO vo_;
  bool bgr_;
};

py::dict RunPatchVO(const py::handle& frames_in, const py::handle& masks, const py::handle& depths,
                    const py::handle& intrinsics, const PatchVOOptions& options, bool bgr) {
  const U8Array frames = AsBytes(frames_in, "frames", "uint8 frames (T, H, W) or (T, H, W, 3)");
  if (!(frames.ndim() == 3 || (frames.ndim() == 4 && frames.shape(3) == 3))) {
    ShapeError("frames", "(T, H, W) or (T, H, W, 3)", frames);
  }
  const int T = CountOf(frames.shape(0), "frames");
  CheckImageSize(frames.shape(1), frames.shape(2), "each frame");
  const int H = static_cast<int>(frames.shape(1)), W = static_cast<int>(frames.shape(2));
  const bool color = frames.ndim() == 4;
  const std::string expected =
      "(T=" + std::to_string(T) + ", H=" + std::to_string(H) + ", W=" + std::to_string(W) + ")";
  U8Array mask_arr;
  if (!masks.is_none()) {
    mask_arr = AsBytes(masks, "masks", "bool or uint8 masks (T, H, W)");
    if (mask_arr.ndim() != 3 || mask_arr.shape(0) != T || mask_arr.shape(1) != H || mask_arr.shape(2) != W) {
      ShapeError("masks", expected, mask_arr);
    }
  }
  py::array_t<float, py::array::c_style> depth_arr;
  if (!depths.is_none()) {
    depth_arr = AsArray<float>(depths, "depths", Cast::kSameKind);  // stored as float32; non-finite = unknown
    if (depth_arr.ndim() != 3 || depth_arr.shape(0) != T || depth_arr.shape(1) != H || depth_arr.shape(2) != W) {
      ShapeError("depths", expected, depth_arr);
    }
  }
  const Intrinsics K = ParseIntrinsics(intrinsics);
  const uint8_t* fp = frames.data();
  const uint8_t* mp = masks.is_none() ? nullptr : mask_arr.data();
  const float* dp = depths.is_none() ? nullptr : depth_arr.data();
  PatchVOResult r;
  {
    py::gil_scoped_release release;
    PatchVO vo(options, K);
    const size_t plane = static_cast<size_t>(H) * W;
    for (int t = 0; t < T; ++t) {
      cv::Mat gray;
      if (color) {
        const cv::Mat c(H, W, CV_8UC3, const_cast<uint8_t*>(fp + 3 * plane * t));
        cv::cvtColor(c, gray, bgr ? cv::COLOR_BGR2GRAY : cv::COLOR_RGB2GRAY);
      } else {
        gray = cv::Mat(H, W, CV_8UC1, const_cast<uint8_t*>(fp + plane * t));
      }
      const cv::Mat m = mp ? cv::Mat(H, W, CV_8UC1, const_cast<uint8_t*>(mp + plane * t)) : cv::Mat();
      const cv::Mat d = dp ? cv::Mat(H, W, CV_32FC1, const_cast<float*>(dp + plane * t)) : cv::Mat();
      vo.AddFrame(gray, m, d);  // PatchVO copies what it keeps
    }
    r = vo.Finish();
  }
  return ResultToDict(r);
}

}  // namespace

void BindVO(py::module_& m) {
  m.def(
      "default_intrinsics",
      [](int width, int height) {
        if (width <= 0 || height <= 0) {
          throw py::value_error("image size must be positive, got " + std::to_string(width) + " x " +
                                std::to_string(height));
        }
        const Intrinsics K = Intrinsics::Default(width, height);
        return py::make_tuple(K.fx, K.fy, K.cx, K.cy);
      },
      py::arg("width"), py::arg("height"),
      "(fx, fy, cx, cy) of a camera nobody calibrated (util/pinhole.h, the one rule; m3c.io.video.default_intrinsics).");
  py::class_<vo::GradientSamplingOptions>(
      m, "GradientSamplingOptions", "Gradient-biased patch sampling (DPVO GRADIENT_BIAS, masks zero the gradient).")
      .def(py::init<>())
      .def_readwrite("pool_px", &vo::GradientSamplingOptions::pool_px)
      .def_readwrite("candidate_factor", &vo::GradientSamplingOptions::candidate_factor)
      .def_readwrite("min_gradient", &vo::GradientSamplingOptions::min_gradient)
      .def_readwrite("margin_px", &vo::GradientSamplingOptions::margin_px)
      .def_readwrite("mask_dilation_px", &vo::GradientSamplingOptions::mask_dilation_px);

  py::class_<vo::LucasKanadeOptions>(m, "LucasKanadeOptions", "Pyramidal Lucas-Kanade front-end settings.")
      .def(py::init<>())
      .def_readwrite("sampling", &vo::LucasKanadeOptions::sampling)
      .def_readwrite("window_px", &vo::LucasKanadeOptions::window_px)
      .def_readwrite("pyramid_levels", &vo::LucasKanadeOptions::pyramid_levels)
      .def_readwrite("max_iterations", &vo::LucasKanadeOptions::max_iterations)
      .def_readwrite("epsilon", &vo::LucasKanadeOptions::epsilon)
      .def_readwrite("min_eigen", &vo::LucasKanadeOptions::min_eigen)
      .def_readwrite("forward_backward_px", &vo::LucasKanadeOptions::forward_backward_px)
      .def_readwrite("reject_masked", &vo::LucasKanadeOptions::reject_masked)
      .def_readwrite("seed", &vo::LucasKanadeOptions::seed);

  py::class_<PatchVOOptions>(m, "PatchVOOptions", "Patch VO settings; see cpp/vo/patch_vo.h for each field.")
      .def(py::init<>())
      .def_readwrite("max_image_side", &PatchVOOptions::max_image_side)
      .def_readwrite("patches_per_frame", &PatchVOOptions::patches_per_frame)
      .def_readwrite("patch_lifetime", &PatchVOOptions::patch_lifetime)
      .def_readwrite("backward_frames", &PatchVOOptions::backward_frames)
      .def_readwrite("optimization_window", &PatchVOOptions::optimization_window)
      .def_readwrite("removal_window", &PatchVOOptions::removal_window)
      .def_readwrite("keyframe_index", &PatchVOOptions::keyframe_index)
      .def_readwrite("keyframe_threshold_px", &PatchVOOptions::keyframe_threshold_px)
      .def_readwrite("new_keyframe_flow_px", &PatchVOOptions::new_keyframe_flow_px)
      .def_readwrite("flow_beta", &PatchVOOptions::flow_beta)
      .def_readwrite("init_frames", &PatchVOOptions::init_frames)
      .def_readwrite("init_min_flow_px", &PatchVOOptions::init_min_flow_px)
      .def_readwrite("init_iterations", &PatchVOOptions::init_iterations)
      .def_readwrite("init_multi_start", &PatchVOOptions::init_multi_start)
      .def_readwrite("motion_damping", &PatchVOOptions::motion_damping)
      .def_readwrite("window_iterations", &PatchVOOptions::window_iterations)
      .def_readwrite("final_iterations", &PatchVOOptions::final_iterations)
      .def_readwrite("loss_scale_px", &PatchVOOptions::loss_scale_px)
      .def_readwrite("outlier_threshold_px", &PatchVOOptions::outlier_threshold_px)
      .def_readwrite("num_threads", &PatchVOOptions::num_threads)
      .def_readwrite("refine_non_keyframes", &PatchVOOptions::refine_non_keyframes)
      .def_readwrite("min_refine_observations", &PatchVOOptions::min_refine_observations)
      .def_readwrite("use_depth", &PatchVOOptions::use_depth)
      .def_readwrite("depth_window_px", &PatchVOOptions::depth_window_px)
      .def_readwrite("min_texture_patches", &PatchVOOptions::min_texture_patches)
      .def_readwrite("lucas_kanade", &PatchVOOptions::lucas_kanade);

  py::class_<PyPatchVO>(m, "PatchVO", R"doc(
Streaming patch visual odometry (DPVO-style patch graph, Ceres bundle adjustment, Lucas-Kanade front-end).

Args:
    options: PatchVOOptions.
    intrinsics: None or (4,) = (fx, fy, cx, cy) in pixels of the input frames; None uses
        f = sqrt(W^2 + H^2), (cx, cy) = (W/2, H/2).
    bgr: 3-channel frames are BGR (OpenCV) rather than RGB.
    front_end: None (Lucas-Kanade) or a Python object with add_frame(frame, gray, mask),
        sample_patches(frame, count) -> (n, 2), track(target, hosts, host_uv, predicted_uv) -> (uv (n, 2),
        weight (n,), ok (n,)) and release_frame(frame), all at PatchVO's processing resolution (e.g.
        m3c.vo.dpvo.DPVOFrontEnd: DPVO's networks give the measurements and their weights).
)doc")
      .def(py::init<const PatchVOOptions&, const py::handle&, bool, const py::object&>(), py::arg("options"),
           py::arg("intrinsics") = py::none(), py::arg("bgr") = false, py::arg("front_end") = py::none())
      .def("add_frame", &PyPatchVO::AddFrame, py::arg("frame"), py::arg("mask") = py::none(),
           py::arg("depth") = py::none(),
           "Adds one frame: uint8 (H, W) or (H, W, 3); mask None or bool/uint8 (H, W); depth None or float (H, W).")
      .def("finish", &PyPatchVO::Finish, "Final optimisation; returns the result dict (see run_patch_vo).")
      .def("fit_rms", &PyPatchVO::fit_rms,
           "Reprojection rms (px, processing resolution) of the inlier measurements into the keyframes at the "
           "current estimate; inf before the map exists (vo::PatchVO::FitRms).")
      .def_property_readonly("num_frames", &PyPatchVO::num_frames);

  m.def("run_patch_vo", &RunPatchVO, py::arg("frames"), py::arg("masks") = py::none(),
        py::arg("depths") = py::none(), py::arg("intrinsics") = py::none(),
        py::arg_v("options", PatchVOOptions(), "PatchVOOptions()"), py::arg("bgr") = false, R"doc(
Patch visual odometry over a whole sequence.

Args:
    frames: uint8 (T, H, W) gray or (T, H, W, 3) RGB (BGR with bgr=True).
    masks: None or bool/uint8 (T, H, W); True = person (gradient zeroed, measurements rejected).
    depths: None or float (T, H, W) depth along z, any consistent unit; <= 0 or non-finite = unknown.
    intrinsics: None or (4,) = (fx, fy, cx, cy), pixels.
    options: PatchVOOptions.

Returns:
    dict with world_from_cam (T, 4, 4) float64 (world = first camera, OpenCV axes, arbitrary scale),
    points (M, 3) float64 (the final map: patches of the final keyframes after bundle adjustment, world frame,
    VO units), point_frames (M,) int32 host frame, point_pixels (M, 2) host pixel (input resolution),
    point_inliers (M,) int32 inlier keyframe measurements (>= 1),
    intrinsics (4,), processing_scale, quality (per-frame arrays attempted, tracked, inliers,
    reprojection_rms_px, keyframe, interpolated, refined), static_camera, stats, message.
)doc");
}

}  // namespace m3c::bindings
