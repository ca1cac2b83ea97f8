// Bindings for cpp/fit: the per-frame camera-local body fit over a track's frames. The Python package
// (m3c.perception.body) owns the public API.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <string>
#include <vector>

#include "bindings/numpy_util.h"
#include "body/body_model.h"
#include "fit/frame_fit.h"
#include "nn/vposer.h"

namespace m3c::bindings {

namespace {

using namespace m3c::fit;

py::dict FitSequence(const body::BodyModel& model, const body::KeypointRegressor& regressor,
                     const py::handle& keypoints_obj, const py::handle& intrinsics_obj,
                     const py::handle& keypoints3d_obj, const py::handle& restart_obj, const py::handle& times_obj,
                     const FitOptions& options, const nn::VPoser* pose_prior) {
  const py::ssize_t K = regressor.num_keypoints();
  const auto keypoints = AsArray<double>(keypoints_obj, "keypoints");
  if (keypoints.ndim() != 3 || keypoints.shape(1) != K || keypoints.shape(2) != 3) {
    ShapeError("keypoints", "(N, " + std::to_string(K) + ", 3)", keypoints);
  }
  const py::ssize_t N = CountOf(keypoints.shape(0), "keypoints frames");
  const auto intrinsics = AsArray<double>(intrinsics_obj, "intrinsics");
  const bool shared_intrinsics = intrinsics.ndim() == 1 && intrinsics.shape(0) == 4;
  if (!shared_intrinsics && !(intrinsics.ndim() == 2 && intrinsics.shape(0) == N && intrinsics.shape(1) == 4)) {
    ShapeError("intrinsics", "(4,) or (N=" + std::to_string(N) + ", 4)", intrinsics);
  }
  py::array_t<double, py::array::c_style> keypoints3d;
  const bool has3d = !keypoints3d_obj.is_none();
  if (has3d) {
    keypoints3d = AsArray<double>(keypoints3d_obj, "keypoints3d");
    if (keypoints3d.ndim() != 3 || keypoints3d.shape(0) != N || keypoints3d.shape(1) != K || keypoints3d.shape(2) != 4) {
      ShapeError("keypoints3d", "(N=" + std::to_string(N) + ", " + std::to_string(K) + ", 4)", keypoints3d);
    }
  }
  std::vector<char> restart;
  if (!restart_obj.is_none()) {
    const auto flags = AsIntegers(restart_obj, "restart");
    if (flags.ndim() != 1 || flags.shape(0) != N) ShapeError("restart", "(N=" + std::to_string(N) + ",)", flags);
    for (py::ssize_t i = 0; i < N; ++i) restart.push_back(flags.data()[i] != 0);
  }
  std::vector<double> times;
  if (!times_obj.is_none()) {
    const auto t = AsArray<double>(times_obj, "times");
    if (t.ndim() != 1 || t.shape(0) != N) ShapeError("times", "(N=" + std::to_string(N) + ",)", t);
    RequireFinite(t, "times");
    times.assign(t.data(), t.data() + N);
  }
  std::vector<FrameObservation> observations(N);
  for (py::ssize_t i = 0; i < N; ++i) {
    FrameObservation& o = observations[i];
    o.keypoints = Eigen::Map<const Observations3>(keypoints.data() + i * K * 3, K, 3);
    if (has3d) o.keypoints3d = Eigen::Map<const Observations4>(keypoints3d.data() + i * K * 4, K, 4);
    const double* c = intrinsics.data() + (shared_intrinsics ? 0 : 4 * i);
    o.intrinsics = {c[0], c[1], c[2], c[3]};
  }
  const BodyFitter fitter(&model, &regressor, options, pose_prior);
  std::vector<FrameFitResult> results;
  {
    py::gil_scoped_release release;
    results = fitter.FitSequence(observations, restart, times);
  }
  const py::ssize_t J = model.num_joints(), B = model.num_betas();
  py::array_t<double> transl({N, py::ssize_t{3}}), root({N, py::ssize_t{3}}), body({N, J - 1, py::ssize_t{3}}),
      betas({N, B}), error({N}), keypoint_error({N, K}), cost({N});
  py::array_t<int> used({N}), iterations({N});
  py::array_t<bool> warm({N});
  py::list status;
  for (py::ssize_t i = 0; i < N; ++i) {
    const FrameFitResult& r = results[i];
    std::copy(r.state.transl.data(), r.state.transl.data() + 3, transl.mutable_data(i));
    std::copy(r.state.root.data(), r.state.root.data() + 3, root.mutable_data(i));
    std::copy(r.state.body.data(), r.state.body.data() + 3 * (J - 1), body.mutable_data(i));
    std::copy(r.state.betas.data(), r.state.betas.data() + B, betas.mutable_data(i));
    std::copy(r.keypoint_error_px.data(), r.keypoint_error_px.data() + K, keypoint_error.mutable_data(i));
    error.mutable_at(i) = r.reprojection_error_px;
    cost.mutable_at(i) = r.cost;
    used.mutable_at(i) = r.num_keypoints;
    iterations.mutable_at(i) = r.iterations;
    warm.mutable_at(i) = r.warm_started;
    status.append(r.status);
  }
  py::dict out;
  out["transl"] = transl;
  out["root_orient"] = root;
  out["body_pose"] = body;
  out["betas"] = betas;
  out["reprojection_error_px"] = error;
  out["keypoint_error_px"] = keypoint_error;
  out["num_keypoints"] = used;
  out["iterations"] = iterations;
  out["cost"] = cost;
  out["warm_started"] = warm;
  out["status"] = status;
  return out;
}

}  // namespace

void BindFit(py::module_& m) {
  py::class_<FitOptions>(m, "BodyFitOptions", "Options of the per-frame camera-local body fit (cpp/fit).")
      .def(py::init<>())
      .def_readwrite("robust_sigma_px", &FitOptions::robust_sigma_px)
      .def_readwrite("min_confidence", &FitOptions::min_confidence)
      .def_readwrite("min_keypoints", &FitOptions::min_keypoints)
      .def_readwrite("keypoints3d_weight", &FitOptions::keypoints3d_weight)
      .def_readwrite("keypoints3d_sigma", &FitOptions::keypoints3d_sigma)
      .def_readwrite("pose_prior_weight", &FitOptions::pose_prior_weight)
      .def_readwrite("vposer_weight", &FitOptions::vposer_weight)
      .def_readwrite("shape_prior_weight", &FitOptions::shape_prior_weight)
      .def_readwrite("temporal_pose_weight", &FitOptions::temporal_pose_weight)
      .def_readwrite("temporal_betas_weight", &FitOptions::temporal_betas_weight)
      .def_readwrite("temporal_transl_weight", &FitOptions::temporal_transl_weight)
      .def_readwrite("optimize_betas", &FitOptions::optimize_betas)
      .def_readwrite("min_depth", &FitOptions::min_depth)
      .def_readwrite("max_iterations", &FitOptions::max_iterations)
      .def_readwrite("reinit_error_px", &FitOptions::reinit_error_px)
      .def_readwrite("max_turn_from_3d_deg", &FitOptions::max_turn_from_3d_deg)
      .def_readwrite("max_limb_from_3d_m", &FitOptions::max_limb_from_3d_m)
      .def_readwrite("torso", &FitOptions::torso)
      .def_readwrite("reference_3d", &FitOptions::reference_3d)
      .def_readwrite("limbs", &FitOptions::limbs)
      .def_readwrite("left_side", &FitOptions::left_side)
      .def_readwrite("right_side", &FitOptions::right_side);
  m.def("fit_body_sequence", &FitSequence, py::arg("model"), py::arg("regressor"), py::arg("keypoints"),
        py::arg("intrinsics"), py::arg("keypoints3d"), py::arg("restart"), py::arg("times"), py::arg("options"),
        py::arg("pose_prior") = nullptr,
        R"doc(Fits the body to one track's frames in order, each warm-started from the previous one.

keypoints: (N, K, 3) u, v in pixels and confidence (0 = missing); intrinsics: (4,) or (N, 4) fx, fy, cx, cy;
keypoints3d: None or (N, K, 4) x, y, z in metres (camera axes, any origin) and confidence; restart: None or
(N,) bool, True where the frame starts cold. Returns a dict: transl (N, 3) camera frame metres, root_orient
(N, 3), body_pose (N, J-1, 3), betas (N, B), reprojection_error_px (N), keypoint_error_px (N, K),
num_keypoints, iterations, cost, warm_started (N) and status (list of N strings). pose_prior: None or a VPoser
(exported weights) whose latent norm options.vposer_weight weighs.)doc");
}

}  // namespace m3c::bindings
