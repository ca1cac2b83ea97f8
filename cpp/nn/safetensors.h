// safetensors files (https://huggingface.co/docs/safetensors): an 8-byte little-endian header length, a JSON
// header {name: {dtype, shape, data_offsets}, "__metadata__": {string: string}}, then raw little-endian data.
// The reader converts every tensor to double; the writer stores float64 or float32.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace m3c::nn {

using RowMatrixXd = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

struct Tensor {
  std::string dtype;             // as stored: F64, F32, F16, BF16, I64, I32, I16, I8, U8, BOOL
  std::vector<int64_t> shape;    // empty for a scalar
  std::vector<double> values;    // C order

  int64_t size() const;
  std::string ShapeString() const;
};

class SafetensorsFile {
 public:
  // Reads and validates the whole file; throws std::invalid_argument naming the file and the problem.
  static SafetensorsFile Read(const std::string& path);
  // Parses the bytes of a file; `name` is used in messages.
  static SafetensorsFile Parse(const std::string& bytes, const std::string& name);

  const std::string& path() const { return path_; }
  bool Has(const std::string& name) const { return tensors_.count(name) > 0; }
  std::vector<std::string> Names() const;
  const std::map<std::string, std::string>& metadata() const { return metadata_; }
  // The metadata value under `key`; throws naming the file when it is absent.
  const std::string& Metadata(const std::string& key) const;

  // Throws naming the file, the tensor and (for the shaped getters) the expected shape.
  const Tensor& Get(const std::string& name) const;
  RowMatrixXd Matrix(const std::string& name, int64_t rows, int64_t cols) const;
  Eigen::VectorXd Vector(const std::string& name, int64_t size) const;

 private:
  std::string path_;
  std::map<std::string, Tensor> tensors_;
  std::map<std::string, std::string> metadata_;
};

// Writes a file atomically (temporary file + rename). dtype "F64" or "F32".
void WriteSafetensors(const std::string& path, const std::map<std::string, Tensor>& tensors,
                      const std::map<std::string, std::string>& metadata, const std::string& dtype = "F64");

}  // namespace m3c::nn
