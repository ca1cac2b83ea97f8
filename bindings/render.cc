// Bindings for cpp/render: the CPU rasteriser of the synthetic benchmark videos. Images come back as float32
// (H, W, 3) RGB in [0, 1], depth (H, W) float32 camera z (inf where empty) and ids (H, W) int32 (-1 where empty).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include <limits>
#include <memory>
#include <string>

#include "bindings/numpy_util.h"
#include "render/rasterizer.h"

namespace m3c::bindings {

namespace {

using render::Frame;
using render::Texture;

py::array_t<double, py::array::c_style> ParseRows(const py::handle& obj, const std::string& name, py::ssize_t cols,
                                                  py::ssize_t rows = -1) {
  auto a = AsArray<double>(obj, name);
  if (a.ndim() != 2 || a.shape(1) != cols || (rows >= 0 && a.shape(0) != rows)) {
    ShapeError(name, "(" + (rows >= 0 ? std::to_string(rows) : std::string("N")) + ", " + std::to_string(cols) + ")",
               a);
  }
  return a;
}

Intrinsics ParseIntrinsics(const py::handle& obj) {
  auto a = AsArray<double>(obj, "intrinsics");
  if (a.ndim() != 1 || a.shape(0) != 4) ShapeError("intrinsics", "(4,) fx, fy, cx, cy", a);
  RequireFinite(a, "intrinsics");
  return {a.at(0), a.at(1), a.at(2), a.at(3)};
}

std::shared_ptr<Texture> MakeTexture(const py::handle& obj) {
  auto a = AsArray<float>(obj, "texture", Cast::kSameKind);
  if (a.ndim() != 3 || a.shape(2) != 3) ShapeError("texture", "(H, W, 3) RGB", a);
  RequireFinite(a, "texture");
  return std::make_shared<Texture>(a.data(), static_cast<int>(a.shape(1)), static_cast<int>(a.shape(0)));
}

void Draw(Frame& frame, const py::handle& intrinsics, const py::handle& vertices, const py::handle& faces,
          const py::handle& light, double ambient, int id, bool cull, double near, const py::handle& normals,
          const std::shared_ptr<Texture>& texture, const py::handle& uv, const py::handle& face_rgb) {
  const Intrinsics K = ParseIntrinsics(intrinsics);
  auto v = ParseRows(vertices, "vertices", 3);
  // Face ids as int32 for the core; the core checks them against the vertex count.
  auto f64 = AsIntegers(faces, "faces");
  if (f64.ndim() != 2 || f64.shape(1) != 3) ShapeError("faces", "(F, 3)", f64);
  py::array_t<int32_t, py::array::c_style> f({f64.shape(0), py::ssize_t{3}});
  for (py::ssize_t i = 0; i < f64.size(); ++i) {
    const int64_t id = f64.data()[i];
    if (id < 0 || id > std::numeric_limits<int32_t>::max()) {
      throw py::value_error("faces hold vertex id " + std::to_string(id) + ", outside [0, " +
                            std::to_string(v.shape(0)) + ")");
    }
    f.mutable_data()[i] = static_cast<int32_t>(id);
  }
  auto l = AsArray<double>(light, "light");
  if (l.ndim() != 1 || l.shape(0) != 3) ShapeError("light", "(3,) direction", l);
  RequireFinite(l, "light");
  const Eigen::Vector3d light_dir(l.at(0), l.at(1), l.at(2));
  if (light_dir.norm() == 0.0) throw py::value_error("light must be a non-zero direction");
  render::Material m;
  m.light = light_dir.normalized();
  m.ambient = ambient;
  m.id = id;
  m.cull = cull;
  py::array_t<double, py::array::c_style> n, t;
  py::array_t<float, py::array::c_style> rgb;
  if (!normals.is_none()) {
    n = ParseRows(normals, "normals", 3, v.shape(0));
    RequireFinite(n, "normals");
    m.normals = n.data();
  }
  if (texture) {
    t = ParseRows(uv, "uv", 2, v.shape(0));
    RequireFinite(t, "uv");
    m.texture = texture;
    m.uv = t.data();
  } else {
    rgb = AsArray<float>(face_rgb, "face_rgb", Cast::kSameKind);
    if (rgb.ndim() != 2 || rgb.shape(0) != f.shape(0) || rgb.shape(1) != 3) {
      ShapeError("face_rgb", "(F=" + std::to_string(f.shape(0)) + ", 3)", rgb);
    }
    RequireFinite(rgb, "face_rgb");
    m.face_rgb = rgb.data();
  }
  py::gil_scoped_release release;
  const int num_vertices = CountOf(v.shape(0), "vertices"), num_faces = CountOf(f.shape(0), "faces");
  frame.Draw(K, near, v.data(), num_vertices, f.data(), num_faces, m);
}

void Resolve(Frame& frame) {
  py::gil_scoped_release release;
  frame.Resolve();
}

}  // namespace

void BindRender(py::module_& m) {
  py::class_<Texture, std::shared_ptr<Texture>>(
      m, "Texture", "A repeating RGB texture with its mip chain (trilinear lookups). texture: (H, W, 3) float, "
                    "H and W powers of two.")
      .def(py::init(&MakeTexture), py::arg("texture"))
      .def_property_readonly("width", &Texture::width)
      .def_property_readonly("height", &Texture::height)
      .def_property_readonly("num_levels", &Texture::num_levels)
      .def(
          "sample",
          [](const Texture& t, double u, double v, double footprint) {
            float out[3];
            t.Sample(u, v, footprint, out);
            return py::make_tuple(out[0], out[1], out[2]);
          },
          py::arg("u"), py::arg("v"), py::arg("footprint") = 1.0,
          "RGB at (u, v) level-0 texels (texel centres at +0.5) for a footprint of `footprint` texels.");

  py::class_<Frame>(m, "RenderFrame",
                    "Colour, depth and id buffers of one image; draw meshes into it, then read rgb/depth/ids.")
      .def(py::init([](int width, int height, const py::handle& background) {
             auto b = AsArray<float>(background, "background", Cast::kSameKind);
             if (b.ndim() != 1 || b.shape(0) != 3) ShapeError("background", "(3,) RGB", b);
             return std::make_unique<Frame>(width, height, b.data());
           }),
           py::arg("width"), py::arg("height"), py::arg("background"))
      .def(
          "draw_textured",
          [](Frame& frame, const py::handle& intrinsics, const py::handle& vertices, const py::handle& faces,
             const std::shared_ptr<Texture>& texture, const py::handle& uv, const py::handle& light,
             double ambient, int id, bool cull, double near, const py::handle& normals) {
            Draw(frame, intrinsics, vertices, faces, light, ambient, id, cull, near, normals, texture, uv,
                 py::none());
          },
          py::arg("intrinsics"), py::arg("vertices"), py::arg("faces"), py::arg("texture"), py::arg("uv"),
          py::arg("light"), py::arg("ambient") = 0.4, py::arg("id") = 0, py::arg("cull") = false,
          py::arg("near") = 0.05, py::arg("normals") = py::none(),
          "Draws a textured mesh: vertices (V, 3) camera frame, faces (F, 3), uv (V, 2) in level-0 texels, light "
          "(3,) camera-frame direction towards the light.")
      .def(
          "draw_coloured",
          [](Frame& frame, const py::handle& intrinsics, const py::handle& vertices, const py::handle& faces,
             const py::handle& face_rgb, const py::handle& light, double ambient, int id, bool cull, double near,
             const py::handle& normals) {
            Draw(frame, intrinsics, vertices, faces, light, ambient, id, cull, near, normals, nullptr, py::none(),
                 face_rgb);
          },
          py::arg("intrinsics"), py::arg("vertices"), py::arg("faces"), py::arg("face_rgb"), py::arg("light"),
          py::arg("ambient") = 0.4, py::arg("id") = 0, py::arg("cull") = false, py::arg("near") = 0.05,
          py::arg("normals") = py::none(),
          "Draws a mesh with one albedo per face (F, 3); normals (V, 3) give smooth shading.")
      .def("resolve", &Frame::Resolve, py::call_guard<py::gil_scoped_release>(),
           "Rasterises everything drawn so far (reading rgb, depth or ids does it too).")
      .def_property_readonly("rgb",
                             [](Frame& f) {
                               Resolve(f);
                               py::array_t<float> out({f.height(), f.width(), 3});
                               std::copy(f.rgb().begin(), f.rgb().end(), out.mutable_data());
                               return out;
                             })
      .def_property_readonly("depth",
                             [](Frame& f) {
                               Resolve(f);
                               py::array_t<float> out({f.height(), f.width()});
                               std::copy(f.depth().begin(), f.depth().end(), out.mutable_data());
                               return out;
                             })
      .def_property_readonly("ids", [](Frame& f) {
        Resolve(f);
        py::array_t<int32_t> out({f.height(), f.width()});
        std::copy(f.ids().begin(), f.ids().end(), out.mutable_data());
        return out;
      });
}

}  // namespace m3c::bindings
