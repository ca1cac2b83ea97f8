// Bindings for cpp/ground: DBSCAN, plane fitting and per-track ground planes. Points are (N, 3) float arrays in
// metres (converted to float64); labels and indices come back as int64, flags as bool.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <limits>
#include <string>
#include <type_traits>
#include <vector>

#include "bindings/numpy_util.h"
#include "ground/dbscan.h"
#include "ground/ground_planes.h"
#include "ground/plane_fit.h"

namespace m3c::bindings {

namespace {

using ground::GapFill;
using ground::GroundOptions;
using ground::Points3;
using PointsMap = Eigen::Map<const Points3>;

// (N, 3) float64, C-contiguous; the returned array owns (or views) the data the map points into.
py::array_t<double, py::array::c_style> ParsePoints(const py::handle& obj, const std::string& name) {
  auto a = AsArray<double>(obj, name);
  if (a.ndim() != 2 || a.shape(1) != 3) ShapeError(name, "(N, 3)", a);
  CountOf(a.shape(0), name);  // the core checks that the points are finite
  return a;
}

PointsMap MapPoints(const py::array_t<double, py::array::c_style>& a) {
  return PointsMap(a.data(), a.shape(0), 3);
}

Eigen::Vector3d ParseUp(const py::handle& obj) {
  auto a = AsArray<double>(obj, "up");
  if (a.ndim() != 1 || a.shape(0) != 3) ShapeError("up", "(3,)", a);
  RequireFinite(a, "up");
  return Eigen::Vector3d(a.at(0), a.at(1), a.at(2));
}

// An integer (or bool) array of shape (n,) as std::vector<T>, each value checked against T's range.
template <typename T>
std::vector<T> ParseIntegers(const py::handle& obj, const std::string& name, py::ssize_t n) {
  auto a = AsIntegers(obj, name);
  if (a.ndim() != 1 || (n >= 0 && a.shape(0) != n)) {
    ShapeError(name, n >= 0 ? "(N=" + std::to_string(n) + ",)" : std::string("(N,)"), a);
  }
  std::vector<T> out(a.shape(0));
  for (py::ssize_t i = 0; i < a.shape(0); ++i) {
    const int64_t v = a.at(i);
    if constexpr (std::is_same_v<T, uint8_t>) {
      out[i] = v != 0;
    } else {
      if (v < std::numeric_limits<T>::min() || v > std::numeric_limits<T>::max()) {
        throw py::value_error(name + "[" + std::to_string(i) + "] = " + std::to_string(v) + " is out of range");
      }
      out[i] = static_cast<T>(v);
    }
  }
  return out;
}

py::array_t<bool> ToBool(const std::vector<uint8_t>& v) {
  py::array_t<bool> out(static_cast<py::ssize_t>(v.size()));
  for (size_t i = 0; i < v.size(); ++i) out.mutable_at(i) = v[i] != 0;
  return out;
}

py::array_t<int64_t> ToInt64(const std::vector<int>& v) {
  py::array_t<int64_t> out(static_cast<py::ssize_t>(v.size()));
  for (size_t i = 0; i < v.size(); ++i) out.mutable_at(i) = v[i];
  return out;
}

py::tuple Dbscan(const py::handle& points, double eps, int min_samples) {
  auto xyz = ParsePoints(points, "points");
  ground::DbscanResult result;
  {
    py::gil_scoped_release release;
    result = ground::Dbscan(MapPoints(xyz), eps, min_samples);
  }
  return py::make_tuple(ToInt64(result.labels), ToBool(result.is_core));
}

py::tuple FitPlane(const py::handle& points, const py::handle& up, const ground::PlaneFitOptions& options) {
  auto xyz = ParsePoints(points, "points");
  const Eigen::Vector3d up_vector = ParseUp(up);
  ground::PlaneFit fit;
  {
    py::gil_scoped_release release;
    fit = ground::FitPlane(MapPoints(xyz), up_vector, options);
  }
  if (!fit.ok()) {
    throw py::value_error("fit_plane: no plane: " +
                          ground::DescribeFailure(fit, static_cast<int>(xyz.shape(0)), options));
  }
  return py::make_tuple(Eigen::Vector3d(fit.plane.normal), fit.plane.offset, ToBool(fit.inliers), fit.rms);
}

py::tuple FramePlanes(const py::handle& points, const py::handle& person, const py::handle& is_foot, int num_people,
                      const py::handle& up, const GroundOptions& options) {
  auto xyz = ParsePoints(points, "points");
  const py::ssize_t n = xyz.shape(0);
  const std::vector<int> person_v = ParseIntegers<int>(person, "person", n);
  const std::vector<uint8_t> foot_v = ParseIntegers<uint8_t>(is_foot, "is_foot", n);
  const Eigen::Vector3d up_vector = ParseUp(up);
  ground::FramePlanes out;
  {
    py::gil_scoped_release release;
    out = ground::EstimateFramePlanes(MapPoints(xyz), person_v, foot_v, num_people, up_vector, options);
  }
  const py::ssize_t K = out.clusters.num_clusters;
  py::array_t<double> normals({K, py::ssize_t{3}});
  py::array_t<double> offsets(K);
  for (py::ssize_t k = 0; k < K; ++k) {
    for (int c = 0; c < 3; ++c) normals.mutable_at(k, c) = out.planes[k].normal(c);
    offsets.mutable_at(k) = out.planes[k].offset;
  }
  return py::make_tuple(ToInt64(out.clusters.labels), normals, offsets, ToBool(out.plane_ok),
                        ToInt64(out.person_plane), ToBool(out.via_feet));
}

py::list TrackPlanes(const py::handle& points, const py::handle& point_track, const py::handle& point_step,
                     const py::handle& is_foot, const py::sequence& track_frames, const py::handle& up,
                     const GroundOptions& options) {
  auto xyz = ParsePoints(points, "points");
  const py::ssize_t n = xyz.shape(0);
  const std::vector<int> track_v = ParseIntegers<int>(point_track, "point_track", n);
  const std::vector<int> step_v = ParseIntegers<int>(point_step, "point_step", n);
  const std::vector<uint8_t> foot_v = ParseIntegers<uint8_t>(is_foot, "is_foot", n);
  std::vector<std::vector<int64_t>> frames;
  for (size_t p = 0; p < track_frames.size(); ++p) {
    frames.push_back(ParseIntegers<int64_t>(track_frames[p], "track_frames[" + std::to_string(p) + "]", -1));
  }
  const Eigen::Vector3d up_vector = ParseUp(up);
  std::vector<ground::TrackPlanes> tracks;
  {
    py::gil_scoped_release release;
    tracks = ground::EstimateTrackPlanes(MapPoints(xyz), track_v, step_v, foot_v, frames, up_vector, options);
  }
  py::list out;
  for (const auto& t : tracks) {
    out.append(py::make_tuple(ground::Points3(t.normal), Eigen::VectorXd(t.offset), ToBool(t.observed),
                              ToBool(t.valid)));
  }
  return out;
}

}  // namespace

void BindGround(py::module_& m) {
  py::class_<ground::PlaneFitOptions>(m, "PlaneFitOptions", "Plane fit settings (see m3c.ground.GroundParams).")
      .def(py::init<>())
      .def_readwrite("robust", &ground::PlaneFitOptions::robust)
      .def_readwrite("inlier_threshold", &ground::PlaneFitOptions::inlier_threshold)
      .def_readwrite("min_support", &ground::PlaneFitOptions::min_support)
      .def_readwrite("max_iterations", &ground::PlaneFitOptions::max_iterations)
      .def_readwrite("confidence", &ground::PlaneFitOptions::confidence)
      .def_readwrite("seed", &ground::PlaneFitOptions::seed);

  py::enum_<GapFill>(m, "GapFill")
      .value("hold", GapFill::kHold)
      .value("linear", GapFill::kLinear);

  py::class_<GroundOptions>(m, "GroundOptions", "Ground-plane settings (see m3c.ground.GroundParams).")
      .def(py::init<>())
      .def_readwrite("eps", &GroundOptions::eps)
      .def_readwrite("min_samples", &GroundOptions::min_samples)
      .def_readwrite("fit", &GroundOptions::fit)
      .def_readwrite("max_distance", &GroundOptions::max_distance)
      .def_readwrite("fill", &GroundOptions::fill);

  m.def("dbscan", &Dbscan, py::arg("points"), py::arg("eps"), py::arg("min_samples"),
        R"doc(DBSCAN of points (N, 3), eps in metres, min_samples counting the point itself.

Returns (labels (N,) int64, -1 = noise, ids numbered like scikit-learn; is_core (N,) bool).)doc");
  m.def("fit_plane", &FitPlane, py::arg("points"), py::arg("up"), py::arg("options"),
        R"doc(Plane through points (N, 3), metres; up (3,) orients the normal.

Returns (normal (3,), offset, inliers (N,) bool, rms metres) with normal . x + offset = 0 on the plane.
Raises ValueError when the support rule fails or the points are collinear.)doc");
  m.def("frame_planes", &FramePlanes, py::arg("points"), py::arg("person"), py::arg("is_foot"),
        py::arg("num_people"), py::arg("up"), py::arg("options"),
        R"doc(One frame: contact points (N, 3), person (N,) int in [0, num_people), is_foot (N,) bool, up (3,).

Returns (labels (N,), normals (K, 3), offsets (K,), plane_ok (K,), person_plane (P,) cluster id or -1,
via_feet (P,)).)doc");
  m.def("track_planes", &TrackPlanes, py::arg("points"), py::arg("point_track"), py::arg("point_step"),
        py::arg("is_foot"), py::arg("track_frames"), py::arg("up"), py::arg("options"),
        R"doc(All tracks: contact points (N, 3) with their track (N,), step within the track (N,) and foot flag (N,);
track_frames: one strictly increasing (T_p,) frame-id array per track; up (3,).

Returns one (normal (T_p, 3), offset (T_p,), observed (T_p,) bool, valid (T_p,) bool) per track.)doc");
}

}  // namespace m3c::bindings
