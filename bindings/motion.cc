// Bindings for cpp/motion: the staged world-frame optimizer. The Python package (m3c.motion) owns the public
// API and converts its dataclasses to these structs.
#include <pybind11/eigen.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "body/body_model.h"
#include "motion/world_optimizer.h"
#include "nn/humor.h"
#include "nn/vposer.h"

namespace m3c::bindings {

namespace py = pybind11;
using namespace m3c::motion;

void BindMotion(py::module_& m) {
  py::class_<StageConfig>(m, "StageConfig")
      .def(py::init<>())
      .def_readwrite("name", &StageConfig::name)
      .def_readwrite("transl", &StageConfig::transl)
      .def_readwrite("root", &StageConfig::root)
      .def_readwrite("body", &StageConfig::body)
      .def_readwrite("betas", &StageConfig::betas)
      .def_readwrite("scale", &StageConfig::scale)
      .def_readwrite("offset", &StageConfig::offset)
      .def_readwrite("weights", &StageConfig::weights)
      .def_readwrite("max_iterations", &StageConfig::max_iterations);
  py::class_<OptimizerConfig>(m, "OptimizerConfig")
      .def(py::init<>())
      .def_readwrite("robust_sigma", &OptimizerConfig::robust_sigma)
      .def_readwrite("min_confidence", &OptimizerConfig::min_confidence)
      .def_readwrite("contact_threshold", &OptimizerConfig::contact_threshold)
      .def_readwrite("contact_height_tolerance", &OptimizerConfig::contact_height_tolerance)
      .def_readwrite("contact_velocity_sigma", &OptimizerConfig::contact_velocity_sigma)
      .def_readwrite("upright_sigma", &OptimizerConfig::upright_sigma)
      .def_readwrite("min_depth", &OptimizerConfig::min_depth)
      .def_readwrite("well_seen_keypoints", &OptimizerConfig::well_seen_keypoints)
      .def_readwrite("optimize_offset", &OptimizerConfig::optimize_offset)
      .def_readwrite("world_check", &OptimizerConfig::world_check)
      .def_readwrite("max_world_increase", &OptimizerConfig::max_world_increase)
      .def_readwrite("latent_pose", &OptimizerConfig::latent_pose)
      .def_readwrite("num_threads", &OptimizerConfig::num_threads)
      .def_readwrite("minimizer", &OptimizerConfig::minimizer)
      .def_readwrite("stages", &OptimizerConfig::stages);
  m.def("default_optimizer_config", &DefaultOptimizerConfig,
        "The thesis's staged recipe with SLAHMR's weights (REFERENCE.md B).");
  m.def("builtin_optimizer_terms", &WorldOptimizer::BuiltinTerms, "Terms that are always available.");
  m.def("learned_optimizer_terms", &WorldOptimizer::LearnedTerms,
        "Terms that need network weights: pose_prior, latent_smoothness (VPoser), motion_prior (HuMoR).");

  py::class_<TrackInput>(m, "TrackInput")
      .def(py::init<>())
      .def_readwrite("first_frame", &TrackInput::first_frame)
      .def_readwrite("keypoints", &TrackInput::keypoints)
      .def_readwrite("transl", &TrackInput::transl)
      .def_readwrite("root", &TrackInput::root)
      .def_readwrite("body", &TrackInput::body)
      .def_readwrite("betas", &TrackInput::betas)
      .def_readwrite("ground_normal", &TrackInput::ground_normal)
      .def_readwrite("ground_offset", &TrackInput::ground_offset)
      .def_readwrite("contacts", &TrackInput::contacts)
      .def_readwrite("ground_contacts", &TrackInput::ground_contacts)
      .def_readwrite("contact_heights", &TrackInput::contact_heights);
  py::class_<CameraInput>(m, "CameraInput")
      .def(py::init<>())
      .def_readwrite("world_from_cam", &CameraInput::world_from_cam)
      .def_readwrite("intrinsics", &CameraInput::intrinsics)
      .def_readwrite("static_camera", &CameraInput::static_camera)
      .def_readwrite("initial_scale", &CameraInput::initial_scale)
      .def_readwrite("scale_sigma", &CameraInput::scale_sigma)
      .def_readwrite("times", &CameraInput::times);

  py::class_<TermCost>(m, "TermCost")
      .def_readonly("term", &TermCost::term)
      .def_readonly("before", &TermCost::before)
      .def_readonly("after", &TermCost::after);
  py::class_<StageReport>(m, "StageReport")
      .def_readonly("name", &StageReport::name)
      .def_readonly("status", &StageReport::status)
      .def_readonly("message", &StageReport::message)
      .def_readonly("iterations", &StageReport::iterations)
      .def_readonly("parts", &StageReport::parts)
      .def_readonly("seconds", &StageReport::seconds)
      .def_readonly("objective_before", &StageReport::objective_before)
      .def_readonly("world_before", &StageReport::world_before)
      .def_readonly("world_after", &StageReport::world_after)
      .def_readonly("objective_after", &StageReport::objective_after)
      .def_readonly("scale", &StageReport::scale)
      .def_readonly("terms", &StageReport::terms);
  py::class_<TrackResult>(m, "TrackResult")
      .def_readonly("transl", &TrackResult::transl)
      .def_readonly("root", &TrackResult::root)
      .def_readonly("body", &TrackResult::body)
      .def_readonly("betas", &TrackResult::betas)
      .def_readonly("latent", &TrackResult::latent);
  py::class_<OptimizerResult>(m, "OptimizerResult")
      .def_readonly("tracks", &OptimizerResult::tracks)
      .def_readonly("scale", &OptimizerResult::scale)
      .def_readonly("offset", &OptimizerResult::offset)
      .def_readonly("stages", &OptimizerResult::stages)
      .def_readonly("stopped_early", &OptimizerResult::stopped_early);

  m.def(
      "optimize_world",
      [](const body::BodyModel& model, const body::KeypointRegressor& keypoints,
         const body::KeypointRegressor* contacts, const std::vector<TrackInput>& tracks, const CameraInput& cameras,
         const OptimizerConfig& config, const nn::HumorPrior* motion_prior, double fps, const nn::VPoser* pose_prior) {
        WorldOptimizer optimizer(&model, &keypoints, contacts, config);
        if (motion_prior) optimizer.SetMotionPrior(motion_prior, fps);
        if (pose_prior) optimizer.SetPosePrior(pose_prior);
        py::gil_scoped_release release;
        return optimizer.Optimize(tracks, cameras);
      },
      py::arg("model"), py::arg("keypoint_regressor"), py::arg("contact_regressor"), py::arg("tracks"),
      py::arg("cameras"), py::arg("config"), py::arg("motion_prior") = nullptr, py::arg("fps") = 30.0,
      py::arg("pose_prior") = nullptr,
      "Runs the staged world-frame optimization; see m3c.motion.optimize for the public API.");
}

}  // namespace m3c::bindings
