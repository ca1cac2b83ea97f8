// Shape and dtype checks at the Python boundary: every message names the argument and the expected shape.
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <sstream>
#include <string>
#include <vector>

namespace m3c::bindings {

namespace py = pybind11;

inline std::string ShapeString(const py::array& a) {
  std::ostringstream s;
  s << "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s << (i ? ", " : "") << a.shape(i);
  s << (a.ndim() == 1 ? ",)" : ")");
  return s.str();
}

[[noreturn]] inline void ShapeError(const std::string& name, const std::string& expected, const py::array& got) {
  throw py::value_error(name + " must have shape " + expected + ", got " + ShapeString(got));
}

// A C-contiguous copy (or view) of `obj` as T; rejects non-numeric input with a clear message.
template <typename T>
py::array_t<T, py::array::c_style> AsArray(const py::handle& obj, const std::string& name) {
  py::array raw = py::array::ensure(obj);
  if (!raw) throw py::value_error(name + " must be a numeric array");
  const char kind = raw.dtype().kind();
  if (kind != 'f' && kind != 'i' && kind != 'u') {
    throw py::value_error(name + " must be a float array, got dtype " + std::string(py::str(raw.dtype())));
  }
  return py::array_t<T, py::array::c_style>::ensure(raw);
}

inline bool IsFloat32(const py::handle& obj) {
  py::array raw = py::array::ensure(obj);
  return raw && raw.dtype().is(py::dtype::of<float>());
}

template <typename T>
py::array_t<T> Empty(const std::vector<py::ssize_t>& shape) {
  return py::array_t<T>(shape);
}

}  // namespace m3c::bindings
