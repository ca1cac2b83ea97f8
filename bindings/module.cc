// m3c._core: the C++ core, one Bind function per area.
#include <cstdlib>

#include <glog/logging.h>
#include <pybind11/pybind11.h>

namespace py = pybind11;

namespace m3c::bindings {
void BindBody(py::module_& m);
void BindMotion(py::module_& m);
void BindGround(py::module_& m);
void BindNN(py::module_& m);
void BindVO(py::module_& m);
void BindFit(py::module_& m);
void BindRender(py::module_& m);
void BindPerception(py::module_& m);
}  // namespace m3c::bindings

PYBIND11_MODULE(_core, m) {
  m.doc() = "M3C C++ core (Eigen, Ceres, OpenCV). Use the m3c package's public API rather than this module.";
  // Ceres reports trial steps it recovers from (a Cholesky factorisation that fails, which its trust region then
  // damps and retries) as glog warnings on stderr, which read like errors in a run's log; M3C reports what failed
  // itself. Only glog errors show, unless the environment's GLOG_minloglevel asks for more (0 = everything).
  if (std::getenv("GLOG_minloglevel") == nullptr) FLAGS_minloglevel = google::GLOG_ERROR;
  // Types before the functions whose signatures name them (the motion optimizer takes the networks), so the
  // docstrings and the .pyi stubs name Python types.
  m3c::bindings::BindBody(m);
  m3c::bindings::BindNN(m);
  m3c::bindings::BindMotion(m);
  m3c::bindings::BindGround(m);
  m3c::bindings::BindVO(m);
  m3c::bindings::BindFit(m);
  m3c::bindings::BindRender(m);
  m3c::bindings::BindPerception(m);
}
