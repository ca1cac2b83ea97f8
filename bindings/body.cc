// Bindings for cpp/body: the SMPL-layout body model, batched skinning, joints-only kinematics, keypoint
// regressors and analytic Jacobians. Arrays in and out are numpy; float32 stays float32, anything else is float64.
#include <pybind11/eigen.h>
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <cmath>
#include <optional>
#include <sstream>

#include "bindings/numpy_util.h"
#include "body/body_model.h"
#include "body/kinematics.h"
#include "body/lbs.h"

namespace m3c::bindings {

namespace {

using body::BodyModel;
using body::KeypointRegressor;
using body::RowMatrixXd;
using body::RowMatrixXi;
using SparseRow = Eigen::SparseMatrix<double, Eigen::RowMajor>;

// A batch of frames validated against the model: pose (N,J,3)|(N,3J), betas (B,)|(N,B), transl None|(3,)|(N,3).
template <typename T>
struct Frames {
  py::array_t<T, py::array::c_style> pose, betas, transl;
  bool betas_shared = true;
  bool has_transl = false;
  int n = 0;
};

template <typename T>
Frames<T> ParseFrames(const BodyModel& model, const py::handle& pose, const py::handle& betas,
                      const py::handle& transl) {
  const int J = model.num_joints(), B = model.num_betas();
  Frames<T> fr;
  fr.pose = AsArray<T>(pose, "pose");
  const std::string pose_shape = "(N, " + std::to_string(J) + ", 3) or (N, " + std::to_string(3 * J) + ")";
  if (fr.pose.ndim() == 3 && fr.pose.shape(1) == J && fr.pose.shape(2) == 3) {
  } else if (fr.pose.ndim() == 2 && fr.pose.shape(1) == 3 * J) {
  } else {
    ShapeError("pose", pose_shape, fr.pose);
  }
  fr.n = CountOf(fr.pose.shape(0), "pose frames");
  RequireFinite(fr.pose, "pose");
  fr.betas = AsArray<T>(betas, "betas");
  const std::string beta_shape = "(" + std::to_string(B) + ",) or (N=" + std::to_string(fr.n) + ", " +
                                 std::to_string(B) + ")";
  if (fr.betas.ndim() == 1 && fr.betas.shape(0) == B) {
    fr.betas_shared = true;
  } else if (fr.betas.ndim() == 2 && fr.betas.shape(0) == fr.n && fr.betas.shape(1) == B) {
    fr.betas_shared = false;
  } else {
    ShapeError("betas", beta_shape, fr.betas);
  }
  RequireFinite(fr.betas, "betas");
  if (!transl.is_none()) {
    fr.transl = AsArray<T>(transl, "transl");
    if (fr.transl.ndim() == 1 && fr.transl.shape(0) == 3) {
      // One translation for every frame.
      py::array_t<T, py::array::c_style> tiled({static_cast<py::ssize_t>(fr.n), py::ssize_t{3}});
      for (int f = 0; f < fr.n; ++f)
        for (int c = 0; c < 3; ++c) tiled.mutable_at(f, c) = fr.transl.at(c);
      fr.transl = tiled;
    } else if (!(fr.transl.ndim() == 2 && fr.transl.shape(0) == fr.n && fr.transl.shape(1) == 3)) {
      ShapeError("transl", "(3,) or (N=" + std::to_string(fr.n) + ", 3)", fr.transl);
    }
    RequireFinite(fr.transl, "transl");
    fr.has_transl = true;
  }
  return fr;
}

template <typename T>
T MaxAbs(const py::array_t<T, py::array::c_style>& a) {
  T m = 0;
  for (py::ssize_t i = 0; i < a.size(); ++i) m = std::max(m, std::abs(a.data()[i]));
  return m;
}

// Finite inputs can still overflow (an angle of 1e30 rad, betas of 1e200): refuse instead of returning NaN/inf.
template <typename T>
void RequireFiniteResult(const Frames<T>& fr, const T* out, py::ssize_t size) {
  for (py::ssize_t i = 0; i < size; ++i) {
    if (std::isfinite(out[i])) continue;
    std::ostringstream s;
    s << "the result overflowed to " << out[i] << " in " << (sizeof(T) == 4 ? "float32" : "float64")
      << " arithmetic: the inputs are too large (largest |pose| " << MaxAbs(fr.pose) << " rad, |betas| "
      << MaxAbs(fr.betas) << ", |transl| " << (fr.has_transl ? MaxAbs(fr.transl) : T(0))
      << "); poses are axis-angle radians, where |angle| <= pi already describes every rotation";
    throw py::value_error(s.str());
  }
}

template <typename T>
py::tuple ForwardT(const BodyModel& model, const py::handle& pose, const py::handle& betas, const py::handle& transl,
                   bool with_vertices) {
  Frames<T> fr = ParseFrames<T>(model, pose, betas, transl);
  const py::ssize_t n = fr.n, V = model.num_vertices(), J = model.num_joints();
  py::array_t<T> joints({n, J, py::ssize_t{3}});
  py::array_t<T> vertices = with_vertices ? py::array_t<T>({n, V, py::ssize_t{3}}) : py::array_t<T>();
  {
    const T* p = fr.pose.data();
    const T* b = fr.betas.data();
    const T* t = fr.has_transl ? fr.transl.data() : nullptr;
    T* vout = with_vertices ? vertices.mutable_data() : nullptr;
    T* jout = joints.mutable_data();
    py::gil_scoped_release release;
    body::Forward<T>(model, fr.n, p, b, fr.betas_shared, t, vout, jout);
  }
  RequireFiniteResult(fr, joints.data(), joints.size());
  if (with_vertices) RequireFiniteResult(fr, vertices.data(), vertices.size());
  return py::make_tuple(vertices, joints);
}

template <typename T>
py::array_t<T> ForwardKinematicsT(const BodyModel& model, const py::handle& pose, const py::handle& betas,
                                  const py::handle& transl) {
  Frames<T> fr = ParseFrames<T>(model, pose, betas, transl);
  py::array_t<T> joints({static_cast<py::ssize_t>(fr.n), static_cast<py::ssize_t>(model.num_joints()), py::ssize_t{3}});
  const T* p = fr.pose.data();
  const T* b = fr.betas.data();
  const T* t = fr.has_transl ? fr.transl.data() : nullptr;
  T* out = joints.mutable_data();
  {
    py::gil_scoped_release release;
    body::ForwardKinematics<T>(model, fr.n, p, b, fr.betas_shared, t, out);
  }
  RequireFiniteResult(fr, joints.data(), joints.size());
  return joints;
}

template <typename T>
py::array_t<T> KeypointsT(const BodyModel& model, const KeypointRegressor& reg, const py::handle& pose,
                          const py::handle& betas, const py::handle& transl) {
  Frames<T> fr = ParseFrames<T>(model, pose, betas, transl);
  py::array_t<T> out({static_cast<py::ssize_t>(fr.n), static_cast<py::ssize_t>(reg.num_keypoints()), py::ssize_t{3}});
  const T* p = fr.pose.data();
  const T* b = fr.betas.data();
  const T* t = fr.has_transl ? fr.transl.data() : nullptr;
  T* o = out.mutable_data();
  {
    py::gil_scoped_release release;
    body::Keypoints<T>(model, reg, fr.n, p, b, fr.betas_shared, t, o);
  }
  RequireFiniteResult(fr, out.data(), out.size());
  return out;
}

py::tuple KeypointsJacobian(const BodyModel& model, const KeypointRegressor& reg, const py::handle& pose,
                            const py::handle& betas, const py::handle& transl) {
  Frames<double> fr = ParseFrames<double>(model, pose, betas, transl);
  const py::ssize_t n = fr.n, K = reg.num_keypoints(), D = body::NumJacobianColumns(model);
  const int J = model.num_joints(), B = model.num_betas();
  py::array_t<double> points({n, K, py::ssize_t{3}});
  py::array_t<double> jac({n, 3 * K, D});
  const double* p = fr.pose.data();
  const double* b = fr.betas.data();
  const double* t = fr.has_transl ? fr.transl.data() : nullptr;
  double* po = points.mutable_data();
  double* jo = jac.mutable_data();
  const bool shared = fr.betas_shared;
  {
    py::gil_scoped_release release;
    const double zero[3] = {0, 0, 0};
    for (py::ssize_t f = 0; f < n; ++f) {
      body::KeypointsWithJacobian(model, reg, p + f * 3 * J, b + (shared ? 0 : f * B), t ? t + 3 * f : zero,
                                  po + f * 3 * K, jo + f * 3 * K * D);
    }
  }
  RequireFiniteResult(fr, points.data(), points.size());
  RequireFiniteResult(fr, jac.data(), jac.size());
  return py::make_tuple(points, jac);
}

SparseRow DenseToSparse(const py::handle& obj, const std::string& name, py::ssize_t rows, py::ssize_t cols) {
  auto a = AsArray<double>(obj, name);
  if (a.ndim() != 2 || (rows >= 0 && a.shape(0) != rows) || (cols >= 0 && a.shape(1) != cols)) {
    ShapeError(name, "(" + (rows >= 0 ? std::to_string(rows) : std::string("K")) + ", " + std::to_string(cols) + ")",
               a);
  }
  RequireFinite(a, name);
  Eigen::Map<const RowMatrixXd> m(a.data(), a.shape(0), a.shape(1));
  return m.sparseView(0.0, 0.0);
}

std::unique_ptr<BodyModel> MakeBodyModel(const py::handle& v_template, const py::handle& shapedirs,
                                         const py::handle& posedirs, const py::handle& j_regressor,
                                         const py::handle& weights, const py::handle& parents,
                                         const py::handle& faces) {
  auto vt = AsArray<double>(v_template, "v_template");
  if (vt.ndim() != 2 || vt.shape(1) != 3 || vt.shape(0) < 1) ShapeError("v_template", "(V, 3)", vt);
  const py::ssize_t V = vt.shape(0);
  auto par = AsIntegers(parents, "parents");
  if (par.ndim() != 1 || par.shape(0) < 1) ShapeError("parents", "(J,)", par);
  const py::ssize_t J = par.shape(0);
  auto sd = AsArray<double>(shapedirs, "shapedirs");
  if (sd.ndim() != 3 || sd.shape(0) != V || sd.shape(1) != 3) ShapeError("shapedirs", "(V=" + std::to_string(V) + ", 3, B)", sd);
  auto pd = AsArray<double>(posedirs, "posedirs");
  if (pd.ndim() != 3 || pd.shape(0) != V || pd.shape(1) != 3 || pd.shape(2) != 9 * (J - 1)) {
    ShapeError("posedirs", "(V=" + std::to_string(V) + ", 3, 9(J-1)=" + std::to_string(9 * (J - 1)) + ")", pd);
  }
  auto w = AsArray<double>(weights, "weights");
  if (w.ndim() != 2 || w.shape(0) != V || w.shape(1) != J) {
    ShapeError("weights", "(V=" + std::to_string(V) + ", J=" + std::to_string(J) + ")", w);
  }
  auto fc = AsIntegers(faces, "faces");
  if (!(fc.ndim() == 2 && fc.shape(1) == 3) && fc.size() != 0) ShapeError("faces", "(F, 3)", fc);
  for (py::ssize_t i = 0; i < fc.size(); ++i) {
    if (fc.data()[i] < 0 || fc.data()[i] >= V) {
      throw py::value_error("faces hold vertex index " + std::to_string(fc.data()[i]) + ", outside [0, V=" +
                            std::to_string(V) + ")");
    }
  }
  std::vector<int> par_v(J);
  for (py::ssize_t j = 0; j < J; ++j) {
    const int64_t p = par.data()[j];
    if (p < -1 || p >= J) {
      throw py::value_error("parents[" + std::to_string(j) + "] = " + std::to_string(p) + " is outside [-1, J=" +
                            std::to_string(J) + ")");
    }
    par_v[j] = static_cast<int>(p);
  }

  RowMatrixXd vt_m = Eigen::Map<const RowMatrixXd>(vt.data(), V, 3);
  Eigen::MatrixXd sd_m = Eigen::Map<const RowMatrixXd>(sd.data(), 3 * V, sd.shape(2));
  Eigen::MatrixXd pd_m = Eigen::Map<const RowMatrixXd>(pd.data(), 3 * V, pd.shape(2));
  RowMatrixXd w_m = Eigen::Map<const RowMatrixXd>(w.data(), V, J);
  using Faces64 = Eigen::Matrix<int64_t, Eigen::Dynamic, 3, Eigen::RowMajor>;
  RowMatrixXi f_m = fc.size() ? RowMatrixXi(Eigen::Map<const Faces64>(fc.data(), fc.shape(0), 3).cast<int>())
                              : RowMatrixXi(0, 3);
  SparseRow jr = DenseToSparse(j_regressor, "J_regressor", J, V);
  return std::make_unique<BodyModel>(vt_m, sd_m, pd_m, jr, w_m, par_v, f_m);
}

}  // namespace

void BindBody(py::module_& m) {
  py::class_<BodyModel>(m, "BodyModel", R"doc(
SMPL-layout body model held by the C++ core. Any vertex count V, joint count J (parents before children)
and shape count B.

Args:
    v_template: (V, 3) rest mesh, metres.
    shapedirs: (V, 3, B) shape blend shapes.
    posedirs: (V, 3, 9(J-1)) pose blend shapes; column 9(j-1)+3r+c multiplies (R_j - I)[r, c].
    J_regressor: (J, V) dense joint regressor.
    weights: (V, J) skinning weights.
    parents: (J,) parent index per joint, parents[0] = -1.
    faces: (F, 3) triangle indices, may be empty.
)doc")
      .def(py::init(&MakeBodyModel), py::arg("v_template"), py::arg("shapedirs"), py::arg("posedirs"),
           py::arg("J_regressor"), py::arg("weights"), py::arg("parents"), py::arg("faces"))
      .def_property_readonly("num_vertices", &BodyModel::num_vertices)
      .def_property_readonly("num_joints", &BodyModel::num_joints)
      .def_property_readonly("num_betas", &BodyModel::num_betas)
      .def_property_readonly("parents", &BodyModel::parents)
      .def_property_readonly("faces", &BodyModel::faces);

  py::class_<KeypointRegressor>(m, "KeypointRegressor", R"doc(
Keypoints as fixed linear combinations of posed vertices and joints: k = A @ vertices + B @ joints.

Args:
    vertex_weights: (K, V) dense array (zeros are dropped).
    joint_weights: (K, J) dense array.
)doc")
      .def(py::init([](const BodyModel& model, const py::handle& vw, const py::handle& jw) {
             SparseRow a = DenseToSparse(vw, "vertex_weights", -1, model.num_vertices());
             SparseRow b = DenseToSparse(jw, "joint_weights", a.rows(), model.num_joints());
             return std::make_unique<KeypointRegressor>(a, b);
           }),
           py::arg("model"), py::arg("vertex_weights"), py::arg("joint_weights"))
      .def_property_readonly("num_keypoints", &KeypointRegressor::num_keypoints)
      .def_property_readonly("used_vertices", &KeypointRegressor::used_vertices);

  m.def(
      "forward",
      [](const BodyModel& model, const py::handle& pose, const py::handle& betas, const py::handle& transl) {
        return PromotesToFloat32({pose, betas, transl}) ? ForwardT<float>(model, pose, betas, transl, true)
                                                        : ForwardT<double>(model, pose, betas, transl, true);
      },
      py::arg("model"), py::arg("pose"), py::arg("betas"), py::arg("transl") = py::none(),
      R"doc(Linear blend skinning of N frames.

pose (N, J, 3) or (N, 3J) axis-angle, root first; betas (B,) shared or (N, B); transl None, (3,) or (N, 3), metres.
Returns (vertices (N, V, 3), joints (N, J, 3)): float32 when numpy's result type of the inputs is float32 (or
float16), else float64. Values must be finite.)doc");
  m.def(
      "forward_kinematics",
      [](const BodyModel& model, const py::handle& pose, const py::handle& betas, const py::handle& transl) {
        if (PromotesToFloat32({pose, betas, transl})) {
          return py::object(ForwardKinematicsT<float>(model, pose, betas, transl));
        }
        return py::object(ForwardKinematicsT<double>(model, pose, betas, transl));
      },
      py::arg("model"), py::arg("pose"), py::arg("betas"), py::arg("transl") = py::none(),
      "Posed joints (N, J, 3) without skinning the mesh; arguments as in forward().");
  m.def(
      "keypoints",
      [](const BodyModel& model, const KeypointRegressor& reg, const py::handle& pose, const py::handle& betas,
         const py::handle& transl) {
        if (PromotesToFloat32({pose, betas, transl})) {
          return py::object(KeypointsT<float>(model, reg, pose, betas, transl));
        }
        return py::object(KeypointsT<double>(model, reg, pose, betas, transl));
      },
      py::arg("model"), py::arg("regressor"), py::arg("pose"), py::arg("betas"), py::arg("transl") = py::none(),
      "Keypoints (N, K, 3) posing only the vertices the regressor uses; arguments as in forward().");
  m.def("keypoints_jacobian", &KeypointsJacobian, py::arg("model"), py::arg("regressor"), py::arg("pose"),
        py::arg("betas"), py::arg("transl") = py::none(),
        R"doc(Keypoints and their analytic Jacobians, float64.

Returns (keypoints (N, K, 3), jacobian (N, 3K, 3 + 3J + B)); Jacobian columns are [transl | pose | betas],
rows 3k..3k+2 belong to keypoint k.)doc");
  m.def(
      "joints_jacobian",
      [](const BodyModel& model, const py::handle& pose, const py::handle& betas, const py::handle& transl) {
        return KeypointsJacobian(model, body::IdentityJointRegressor(model), pose, betas, transl);
      },
      py::arg("model"), py::arg("pose"), py::arg("betas"), py::arg("transl") = py::none(),
      "Posed joints (N, J, 3) and d joints / d [transl | pose | betas] (N, 3J, 3 + 3J + B), float64.");
}

}  // namespace m3c::bindings
