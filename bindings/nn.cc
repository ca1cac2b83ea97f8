// Bindings for cpp/nn: the safetensors reader and the network runtime that evaluates exported HuMoR and
// VPoser weights (python -m m3c.models.export). Arrays are float64 numpy; shapes are checked here.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include "bindings/numpy_util.h"
#include "nn/humor.h"
#include "nn/humor_state.h"
#include "nn/safetensors.h"
#include "nn/vposer.h"

namespace m3c::bindings {

namespace {

using nn::HumorPrior;
using nn::VPoser;
using nn::humor::kLatentDim;
using nn::humor::kStateDim;

using Array = py::array_t<double, py::array::c_style>;

// (N, dim) float64, C-contiguous; `what` names the argument in errors.
Array Rows(const py::handle& obj, const std::string& what, py::ssize_t dim, py::ssize_t n = -1) {
  Array a = AsArray<double>(obj, what);
  if (a.ndim() != 2 || a.shape(1) != dim || (n >= 0 && a.shape(0) != n)) {
    ShapeError(what, "(" + (n >= 0 ? std::to_string(n) : std::string("N")) + ", " + std::to_string(dim) + ")", a);
  }
  CountOf(a.shape(0), what);
  RequireFinite(a, what);
  return a;
}

Array Batch(const nn::GroupNormMlp& mlp, const py::handle& x, const std::string& what) {
  Array in = Rows(x, what, mlp.input_dim());
  const py::ssize_t n = in.shape(0);
  Array out({n, static_cast<py::ssize_t>(mlp.output_dim())});
  {
    const double* src = in.data();
    double* dst = out.mutable_data();
    py::gil_scoped_release release;
    Eigen::Map<const Eigen::MatrixXd> X(src, mlp.input_dim(), n);  // row-major (n, d) == column-major (d, n)
    Eigen::MatrixXd Y;
    nn::GroupNormMlp::Activations acts;
    mlp.ForwardBatch(X, &Y, &acts);
    Eigen::Map<Eigen::MatrixXd>(dst, mlp.output_dim(), n) = Y;
  }
  return out;
}

py::object TransitionNll(const HumorPrior& prior, const py::handle& x_prev, const py::handle& x_next,
                         bool with_gradient) {
  Array a = Rows(x_prev, "x_prev", kStateDim);
  const py::ssize_t n = a.shape(0);
  Array b = Rows(x_next, "x_next", kStateDim, n);
  Array values(n), grad_a, grad_b;
  if (with_gradient) {
    grad_a = Array({n, py::ssize_t{kStateDim}});
    grad_b = Array({n, py::ssize_t{kStateDim}});
  }
  {
    const double *pa = a.data(), *pb = b.data();
    double* v = values.mutable_data();
    double* ga = with_gradient ? grad_a.mutable_data() : nullptr;
    double* gb = with_gradient ? grad_b.mutable_data() : nullptr;
    py::gil_scoped_release release;
    prior.TransitionNll(static_cast<int>(n), pa, pb, v, ga, gb);
  }
  if (!with_gradient) return values;
  return py::make_tuple(values, grad_a, grad_b);
}

py::object LatentNll(const HumorPrior& prior, const py::handle& x_prev, const py::handle& z, bool with_gradient) {
  Array a = Rows(x_prev, "x_prev", kStateDim);
  const py::ssize_t n = a.shape(0);
  Array lat = Rows(z, "z", kLatentDim, n);
  Array values(n), grad_a, grad_z;
  if (with_gradient) {
    grad_a = Array({n, py::ssize_t{kStateDim}});
    grad_z = Array({n, py::ssize_t{kLatentDim}});
  }
  {
    const double *pa = a.data(), *pz = lat.data();
    double* v = values.mutable_data();
    double* ga = with_gradient ? grad_a.mutable_data() : nullptr;
    double* gz = with_gradient ? grad_z.mutable_data() : nullptr;
    py::gil_scoped_release release;
    prior.LatentNll(static_cast<int>(n), pa, pz, v, ga, gz);
  }
  if (!with_gradient) return values;
  return py::make_tuple(values, grad_a, grad_z);
}

py::tuple SequenceNll(const HumorPrior& prior, const py::handle& states) {
  Array s = Rows(states, "states", kStateDim);
  const py::ssize_t T = s.shape(0);
  if (T < 2) throw py::value_error("states must hold at least 2 states, got " + std::to_string(T));
  Array grad({T, py::ssize_t{kStateDim}});
  double value;
  {
    const double* ps = s.data();
    double* g = grad.mutable_data();
    py::gil_scoped_release release;
    value = prior.SequenceTransitionNll(static_cast<int>(T), ps, g);
  }
  return py::make_tuple(value, grad);
}

Array BuildStates(const py::handle& trans, const py::handle& root_orient, const py::handle& pose_body,
                  const py::handle& joints, double fps, const py::handle& ground_R, const py::handle& ground_t) {
  Array tr = AsArray<double>(trans, "trans");
  if (tr.ndim() != 2 || tr.shape(1) != 3 || tr.shape(0) < 3) ShapeError("trans", "(T >= 3, 3)", tr);
  RequireFinite(tr, "trans");
  const py::ssize_t T = tr.shape(0);
  const std::string t_str = std::to_string(T);
  Array ro = Rows(root_orient, "root_orient", 3, T);
  Array pb = AsArray<double>(pose_body, "pose_body");
  if (!((pb.ndim() == 2 && pb.shape(0) == T && pb.shape(1) == 63) ||
        (pb.ndim() == 3 && pb.shape(0) == T && pb.shape(1) == 21 && pb.shape(2) == 3))) {
    ShapeError("pose_body", "(T=" + t_str + ", 21, 3) or (T, 63)", pb);
  }
  RequireFinite(pb, "pose_body");
  Array jo = AsArray<double>(joints, "joints");
  if (jo.ndim() != 3 || jo.shape(0) != T || jo.shape(1) < 22 || jo.shape(2) != 3) {
    ShapeError("joints", "(T=" + t_str + ", J >= 22, 3)", jo);
  }
  RequireFinite(jo, "joints");
  if (!(fps > 0) || !std::isfinite(fps)) throw py::value_error("fps must be positive, got " + std::to_string(fps));
  Array gR, gt;
  bool per_frame = false;
  const bool has_ground = !ground_R.is_none();
  if (has_ground != !ground_t.is_none()) throw py::value_error("give both ground_R and ground_t, or neither");
  if (has_ground) {
    gR = AsArray<double>(ground_R, "ground_R");
    gt = AsArray<double>(ground_t, "ground_t");
    per_frame = gR.ndim() == 3;
    if (per_frame ? !(gR.shape(0) == T && gR.shape(1) == 3 && gR.shape(2) == 3)
                  : !(gR.ndim() == 2 && gR.shape(0) == 3 && gR.shape(1) == 3)) {
      ShapeError("ground_R", "(3, 3) or (T=" + t_str + ", 3, 3)", gR);
    }
    if (per_frame ? !(gt.ndim() == 2 && gt.shape(0) == T && gt.shape(1) == 3) : !(gt.ndim() == 1 && gt.shape(0) == 3)) {
      ShapeError("ground_t", per_frame ? "(T=" + t_str + ", 3)" : "(3,)", gt);
    }
    RequireFinite(gR, "ground_R");
    RequireFinite(gt, "ground_t");
  }
  Array out({T - 2, py::ssize_t{kStateDim}});
  {
    const double *ptr = tr.data(), *pro = ro.data(), *ppb = pb.data(), *pjo = jo.data();
    const double* pR = has_ground ? gR.data() : nullptr;
    const double* pt = has_ground ? gt.data() : nullptr;
    const py::ssize_t J = jo.shape(1);
    double* dst = out.mutable_data();
    py::gil_scoped_release release;
    for (py::ssize_t t = 1; t + 1 < T; ++t) {
      const double* trans3[3] = {ptr + 3 * (t - 1), ptr + 3 * t, ptr + 3 * (t + 1)};
      const double* root3[3] = {pro + 3 * (t - 1), pro + 3 * t, pro + 3 * (t + 1)};
      // Joints 0..21 of each frame are the first 66 values of its (J, 3) block.
      const double* joints3[3] = {pjo + 3 * J * (t - 1), pjo + 3 * J * t, pjo + 3 * J * (t + 1)};
      const double* R = pR ? pR + (per_frame ? 9 * t : 0) : nullptr;
      const double* tt = pt ? pt + (per_frame ? 3 * t : 0) : nullptr;
      nn::humor::BuildState(trans3, root3, joints3, ppb + 63 * t, fps, R, tt, dst + kStateDim * (t - 1));
    }
  }
  return out;
}

Array Canonicalize(const py::handle& x, const py::handle& frame_from) {
  Array states = Rows(x, "x", kStateDim);
  const py::ssize_t n = states.shape(0);
  Array frames = Rows(frame_from, "frame_from", kStateDim, n);
  Array out({n, py::ssize_t{kStateDim}});
  const double *ps = states.data(), *pf = frames.data();
  double* dst = out.mutable_data();
  py::gil_scoped_release release;
  for (py::ssize_t i = 0; i < n; ++i) {
    nn::humor::ToCanonical(nn::humor::ComputeCanonicalFrame(pf + kStateDim * i), ps + kStateDim * i,
                           dst + kStateDim * i);
  }
  return out;
}

}  // namespace

void BindNN(py::module_& m) {
  m.def(
      "read_safetensors",
      [](const std::string& path) {
        nn::SafetensorsFile file = nn::SafetensorsFile::Read(path);
        py::dict tensors;
        for (const std::string& name : file.Names()) {
          const nn::Tensor& t = file.Get(name);
          std::vector<py::ssize_t> shape(t.shape.begin(), t.shape.end());
          Array a(shape);
          std::copy(t.values.begin(), t.values.end(), a.mutable_data());
          tensors[py::str(name)] = a;
        }
        return py::make_tuple(tensors, file.metadata());
      },
      py::arg("path"),
      "The C++ safetensors reader: (dict name -> float64 array, metadata dict). Raises ValueError on a bad file.");

  py::class_<HumorPrior>(m, "HumorPrior", R"doc(
HuMoR's posterior encoder and conditional prior from an exported humor.safetensors. States are 339-d,
in the ground frame (z up, floor z = 0); the terms canonicalise them in the frame of x_prev.)doc")
      .def(py::init(&HumorPrior::FromFile), py::arg("path"))
      .def_property_readonly_static("state_dim", [](py::object) { return kStateDim; })
      .def_property_readonly_static("latent_dim", [](py::object) { return kLatentDim; })
      .def(
          "encoder_forward",
          [](const HumorPrior& p, const py::handle& x) { return Batch(p.encoder(), x, "x"); }, py::arg("x"),
          "Raw encoder output (N, 96) for canonical pairs (N, 678) = [x_prev | x_next].")
      .def(
          "prior_forward", [](const HumorPrior& p, const py::handle& x) { return Batch(p.prior(), x, "x"); },
          py::arg("x"), "Raw prior output (N, 96) for canonical states (N, 339).")
      .def("transition_nll", &TransitionNll, py::arg("x_prev"), py::arg("x_next"), py::arg("with_gradient") = false,
           R"doc(NLL of the posterior mean of each transition under the conditional prior.
x_prev, x_next: (N, 339). Returns values (N,), or with_gradient: (values, d/dx_prev (N, 339), d/dx_next (N, 339)).)doc")
      .def("latent_nll", &LatentNll, py::arg("x_prev"), py::arg("z"), py::arg("with_gradient") = false,
           R"doc(NLL of latents z (N, 48) under the conditional prior of x_prev (N, 339).
Returns values (N,), or with_gradient: (values, d/dx_prev (N, 339), d/dz (N, 48)).)doc")
      .def("sequence_transition_nll", &SequenceNll, py::arg("states"),
           "Sum of transition_nll over consecutive pairs of states (T, 339): (value, gradient (T, 339)).");

  py::class_<VPoser>(m, "VPoser", "VPoser v1/v2 from an exported vposer.safetensors (eval mode).")
      .def(py::init(&VPoser::FromFile), py::arg("path"))
      .def_property_readonly("version", &VPoser::version)
      .def_property_readonly("latent_dim", &VPoser::latent_dim)
      .def(
          "decode",
          [](const VPoser& v, const py::handle& z) {
            Array lat = Rows(z, "z", v.latent_dim());
            const py::ssize_t n = lat.shape(0), J = v.num_joints();
            Array out({n, J, py::ssize_t{3}, py::ssize_t{3}});
            const double* src = lat.data();
            double* dst = out.mutable_data();
            py::gil_scoped_release release;
            for (py::ssize_t i = 0; i < n; ++i) v.Decode(src + i * v.latent_dim(), dst + i * 9 * J);
            return out;
          },
          py::arg("z"), "Latents (N, latent_dim) -> body joint rotations (N, 21, 3, 3).")
      .def(
          "encode",
          [](const VPoser& v, const py::handle& pose) {
            Array p = AsArray<double>(pose, "pose_body");
            const py::ssize_t J = v.num_joints();
            if (!((p.ndim() == 2 && p.shape(1) == 3 * J) || (p.ndim() == 3 && p.shape(1) == J && p.shape(2) == 3))) {
              ShapeError("pose_body", "(N, 21, 3) or (N, 63)", p);
            }
            RequireFinite(p, "pose_body");
            const py::ssize_t n = p.shape(0), L = v.latent_dim();
            Array mean({n, L}), scale({n, L});
            const double* src = p.data();
            double *pm = mean.mutable_data(), *ps = scale.mutable_data();
            {
              py::gil_scoped_release release;
              for (py::ssize_t i = 0; i < n; ++i) v.Encode(src + i * 3 * J, pm + i * L, ps + i * L);
            }
            return py::make_tuple(mean, scale);
          },
          py::arg("pose_body"), "Axis-angle body pose (N, 21, 3) -> (mean (N, latent_dim), scale (N, latent_dim)).");

  m.def("humor_build_states", &BuildStates, py::arg("trans"), py::arg("root_orient"), py::arg("pose_body"),
        py::arg("joints"), py::arg("fps"), py::arg("ground_R") = py::none(), py::arg("ground_t") = py::none(),
        R"doc(HuMoR states (T-2, 339) of frames 1..T-2.
trans (T, 3) metres; root_orient (T, 3) axis-angle; pose_body (T, 21, 3) axis-angle; joints (T, J >= 22, 3);
fps > 0; ground_R (3, 3) | (T, 3, 3) and ground_t (3,) | (T, 3): p_ground = R p + t, or None if the inputs
are already in the ground frame.)doc");
  m.def("humor_canonicalize", &Canonicalize, py::arg("x"), py::arg("frame_from"),
        "States x (N, 339) expressed in the canonical frame of frame_from (N, 339).");
}

}  // namespace m3c::bindings
