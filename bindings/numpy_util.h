// The one conversion layer between numpy and the core: every array argument goes through AsArray (real numbers),
// AsIntegers (indices, ids, flags) or AsBytes (images, masks). They accept what numpy casts without loss, convert
// it the way numpy would, and otherwise raise ValueError naming the argument, its dtype and shape and what is
// expected; never a null array (numpy refuses a cast by returning NULL, which must not reach the core).
#pragma once

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
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

inline std::string DtypeString(const py::array& a) { return py::str(a.dtype()); }

[[noreturn]] inline void ShapeError(const std::string& name, const std::string& expected, const py::array& got) {
  throw py::value_error(name + " must have shape " + expected + ", got " + ShapeString(got) + " (dtype " +
                        DtypeString(got) + ")");
}

// How far AsArray may go to reach the core's element type.
enum class Cast {
  kSafe,      // numpy's casting="safe": no value changes (float16/32 -> float64, integers -> float64, bool)
  kSameKind,  // also rounding within real numbers (float64 -> float32, int32 -> float32): for data the core
              // keeps in float32 anyway, such as depth maps
};

// obj as an ndarray, or ValueError when numpy cannot make one (ragged lists, arbitrary objects).
inline py::array ToNumpy(const py::handle& obj, const std::string& name, const std::string& expected) {
  py::array raw = py::array::ensure(obj);
  if (!raw) {
    throw py::value_error(name + " must be " + expected + ", got a " + std::string(py::str(py::type::of(obj).attr(
                                                                           "__name__"))) +
                          " that numpy cannot turn into an array");
  }
  return raw;
}

inline bool CanCast(const py::array& from, const py::dtype& to, const char* casting) {
  if (from.dtype().is(to)) return true;  // the common case, without a call into numpy
  return py::module_::import("numpy").attr("can_cast")(from.dtype(), to, casting).cast<bool>();
}

inline std::string TypeName(const py::dtype& d) { return py::str(d); }

// The forced conversion after the cast was allowed; numpy refuses only for lack of memory here.
template <typename T>
py::array_t<T, py::array::c_style> Converted(const py::array& raw, const std::string& name) {
  auto a = py::array_t<T, py::array::c_style | py::array::forcecast>::ensure(raw);
  if (!a) {
    throw py::value_error(name + ": could not convert the " + DtypeString(raw) + " array of shape " +
                          ShapeString(raw) + " to " + TypeName(py::dtype::of<T>()) + " (out of memory?)");
  }
  return a;
}

// A C-contiguous view or copy of obj as T (float or double).
template <typename T>
py::array_t<T, py::array::c_style> AsArray(const py::handle& obj, const std::string& name, Cast cast = Cast::kSafe) {
  static_assert(std::is_floating_point_v<T>);
  py::array raw = ToNumpy(obj, name, "a float array");
  const char kind = raw.dtype().kind();
  const bool numeric = kind == 'f' || kind == 'i' || kind == 'u' || kind == 'b';
  const py::dtype target_dtype = py::dtype::of<T>();
  const bool ok = numeric && (CanCast(raw, target_dtype, "safe") ||
                              (cast == Cast::kSameKind && (kind != 'f' || CanCast(raw, target_dtype, "same_kind"))));
  if (!ok) {
    const std::string target = TypeName(target_dtype);
    throw py::value_error(name + " must be a float array (" +
                          (cast == Cast::kSafe ? "float16/32/64, integers or bool: what converts to " + target +
                                                     " without loss"
                                               : "floats, integers or bool") +
                          "), got dtype " + DtypeString(raw) + ", shape " + ShapeString(raw) +
                          "; convert it with .astype(np." + target + ")");
  }
  return Converted<T>(raw, name);
}

// True when numpy's result type of the arrays is float16/float32, so the core computes in float32 (float32 in,
// float32 out) and in float64 otherwise (float32 with float64 or int64 gives float64, as in numpy). Arguments
// that are None are skipped; ones numpy cannot combine leave the decision to AsArray's error.
inline bool PromotesToFloat32(std::initializer_list<py::handle> objs) {
  // Fast answers for the common cases (all float32; any float64) without a call into numpy.
  bool all_float32 = true;
  for (const py::handle& obj : objs) {
    if (obj.is_none()) continue;
    if (!py::isinstance<py::array>(obj)) {
      all_float32 = false;
      continue;
    }
    const py::dtype d = py::reinterpret_borrow<py::array>(obj).dtype();
    if (d.is(py::dtype::of<double>())) return false;
    all_float32 = all_float32 && d.is(py::dtype::of<float>());
  }
  if (all_float32) return true;
  py::list arrays;
  for (const py::handle& obj : objs) {
    if (obj.is_none()) continue;
    py::array a = py::array::ensure(obj);
    if (!a) return false;
    arrays.append(a);
  }
  if (arrays.empty()) return false;
  try {
    const py::dtype d = py::module_::import("numpy").attr("result_type")(*arrays);
    return d.kind() == 'f' && d.itemsize() <= 4;
  } catch (const py::error_already_set&) {
    return false;
  }
}

// An integer array as int64 (C-contiguous): any signed or unsigned integer dtype or bool; floats are refused so
// that 0.7 never silently becomes index 0, and uint64 values above int64's range are refused.
inline py::array_t<int64_t, py::array::c_style> AsIntegers(const py::handle& obj, const std::string& name) {
  py::array raw = ToNumpy(obj, name, "an integer array");
  const char kind = raw.dtype().kind();
  if (kind != 'i' && kind != 'u' && kind != 'b') {
    throw py::value_error(name + " must be an integer or boolean array (floats are not rounded to indices), got " +
                          "dtype " + DtypeString(raw) + ", shape " + ShapeString(raw));
  }
  if (kind == 'u' && raw.itemsize() == 8) {
    auto u = Converted<uint64_t>(raw, name);
    const uint64_t* p = u.data();
    for (py::ssize_t i = 0; i < u.size(); ++i) {
      if (p[i] > static_cast<uint64_t>(std::numeric_limits<int64_t>::max())) {
        throw py::value_error(name + " holds " + std::to_string(p[i]) +
                              ", beyond int64's range (an unsigned array cannot hold -1: use a signed integer type)");
      }
    }
  }
  return Converted<int64_t>(raw, name);
}

// A uint8/bool array (images, masks) as uint8, C-contiguous; other dtypes are refused because their value range
// would need a choice (0..1 or 0..255?) that the caller must make.
inline py::array_t<uint8_t, py::array::c_style> AsBytes(const py::handle& obj, const std::string& name,
                                                         const std::string& what) {
  py::array raw = ToNumpy(obj, name, what);
  const char kind = raw.dtype().kind();
  if (!((kind == 'u' || kind == 'b') && raw.itemsize() == 1)) {
    throw py::value_error(name + " must be " + what + ", got dtype " + DtypeString(raw) + ", shape " +
                          ShapeString(raw));
  }
  return Converted<uint8_t>(raw, name);
}

// ValueError unless every value of a is finite; names the first bad index.
template <typename T>
void RequireFinite(const py::array_t<T, py::array::c_style>& a, const std::string& name,
                   const std::string& hint = "") {
  const T* p = a.data();
  for (py::ssize_t i = 0; i < a.size(); ++i) {
    if (std::isfinite(p[i])) continue;
    std::ostringstream s;
    s << name << " holds " << p[i] << " at index (";
    py::ssize_t rest = i;
    std::vector<py::ssize_t> index(a.ndim());
    for (py::ssize_t d = a.ndim() - 1; d >= 0; --d) {
      index[d] = a.shape(d) ? rest % a.shape(d) : 0;
      rest = a.shape(d) ? rest / a.shape(d) : 0;
    }
    for (py::ssize_t d = 0; d < a.ndim(); ++d) s << (d ? ", " : "") << index[d];
    s << (a.ndim() == 1 ? ",)" : ")") << "; every value must be finite" << (hint.empty() ? "" : " (" + hint + ")");
    throw py::value_error(s.str());
  }
}

// An int count for the core (frames, points), refusing sizes beyond int's range.
inline int CountOf(py::ssize_t n, const std::string& what) {
  if (n > std::numeric_limits<int>::max()) {
    throw py::value_error(what + ": " + std::to_string(n) + " is more than the core handles (" +
                          std::to_string(std::numeric_limits<int>::max()) + ")");
  }
  return static_cast<int>(n);
}

}  // namespace m3c::bindings
