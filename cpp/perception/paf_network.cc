#include "perception/paf_network.h"

#include <stdexcept>

namespace m3c::perception {

PafNetwork::PafNetwork(const std::string& graph_path) {
  try {
    net_ = cv::dnn::readNetFromTensorflow(graph_path);
  } catch (const cv::Exception& e) {
    throw std::runtime_error("cannot read the pose network graph " + graph_path + ": " + e.what());
  }
  if (net_.empty()) throw std::runtime_error("cannot read the pose network graph " + graph_path);
  net_.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
  net_.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);
}

cv::Mat PafNetwork::Forward(const cv::Mat& rgb, int input_width, int input_height) {
  if (rgb.empty() || rgb.type() != CV_8UC3) throw std::invalid_argument("the image must be 8-bit RGB (H, W, 3)");
  if (input_width < 8 || input_height < 8 || input_width % 8 || input_height % 8) {
    throw std::invalid_argument("the network's input size must be positive multiples of 8, got " +
                                std::to_string(input_width) + " x " + std::to_string(input_height));
  }
  // swapRB: the graph was trained on OpenCV's BGR images.
  const cv::Mat blob = cv::dnn::blobFromImage(rgb, 1.0, cv::Size(input_width, input_height), cv::Scalar(),
                                              /*swapRB=*/true, /*crop=*/false);
  net_.setInput(blob);
  return net_.forward().clone();
}

}  // namespace m3c::perception
