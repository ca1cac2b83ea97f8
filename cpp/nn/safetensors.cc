#include "nn/safetensors.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <random>
#include <sstream>

#include "util/check.h"

#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ != __ORDER_LITTLE_ENDIAN__
#error "safetensors data is little-endian; this reader assumes a little-endian host"
#endif

namespace m3c::nn {

namespace {

using Json = nlohmann::json;

constexpr uint64_t kMaxHeader = 100ull << 20;

int ElementSize(const std::string& dtype) {
  if (dtype == "F64" || dtype == "I64") return 8;
  if (dtype == "F32" || dtype == "I32") return 4;
  if (dtype == "F16" || dtype == "BF16" || dtype == "I16") return 2;
  if (dtype == "I8" || dtype == "U8" || dtype == "BOOL") return 1;
  return 0;
}

double HalfToDouble(uint16_t h) {
  const int sign = (h >> 15) ? -1 : 1;
  const int exponent = (h >> 10) & 0x1f;
  const int mantissa = h & 0x3ff;
  if (exponent == 0) return sign * std::ldexp(mantissa, -24);
  if (exponent == 31) return mantissa ? std::numeric_limits<double>::quiet_NaN() : sign * HUGE_VAL;
  return sign * std::ldexp(1024 + mantissa, exponent - 25);
}

template <typename S>
void Convert(const char* data, int64_t count, double* out) {
  for (int64_t i = 0; i < count; ++i) {
    S v;
    std::memcpy(&v, data + i * sizeof(S), sizeof(S));
    out[i] = static_cast<double>(v);
  }
}

void Decode(const std::string& dtype, const char* data, int64_t count, double* out) {
  if (dtype == "F64") return Convert<double>(data, count, out);
  if (dtype == "F32") return Convert<float>(data, count, out);
  if (dtype == "I64") return Convert<int64_t>(data, count, out);
  if (dtype == "I32") return Convert<int32_t>(data, count, out);
  if (dtype == "I16") return Convert<int16_t>(data, count, out);
  if (dtype == "I8") return Convert<int8_t>(data, count, out);
  if (dtype == "U8" || dtype == "BOOL") return Convert<uint8_t>(data, count, out);
  for (int64_t i = 0; i < count; ++i) {
    uint16_t h;
    std::memcpy(&h, data + 2 * i, 2);
    if (dtype == "F16") {
      out[i] = HalfToDouble(h);
    } else {  // BF16: the upper half of a float32
      const uint32_t bits = static_cast<uint32_t>(h) << 16;
      float f;
      std::memcpy(&f, &bits, 4);
      out[i] = f;
    }
  }
}

std::string ShapeOf(const std::vector<int64_t>& shape) {
  std::ostringstream s;
  s << "(";
  for (size_t i = 0; i < shape.size(); ++i) s << (i ? ", " : "") << shape[i];
  s << (shape.size() == 1 ? ",)" : ")");
  return s.str();
}

}  // namespace

int64_t Tensor::size() const {
  int64_t n = 1;
  for (int64_t d : shape) n *= d;
  return n;
}

std::string Tensor::ShapeString() const { return ShapeOf(shape); }

SafetensorsFile SafetensorsFile::Read(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  M3C_CHECK(in.good()) << "cannot open safetensors file " << path;
  std::ostringstream buffer;
  buffer << in.rdbuf();
  return Parse(buffer.str(), path);
}

SafetensorsFile SafetensorsFile::Parse(const std::string& bytes, const std::string& name) {
  SafetensorsFile file;
  file.path_ = name;
  M3C_CHECK(bytes.size() >= 8) << name << ": too short for a safetensors file (" << bytes.size() << " bytes)";
  uint64_t header_size = 0;
  std::memcpy(&header_size, bytes.data(), 8);
  M3C_CHECK(header_size <= kMaxHeader && header_size <= bytes.size() - 8)
      << name << ": header length " << header_size << " exceeds the file (" << bytes.size() << " bytes)";
  Json header;
  try {
    header = Json::parse(bytes.begin() + 8, bytes.begin() + 8 + static_cast<std::ptrdiff_t>(header_size));
  } catch (const Json::exception& err) {
    M3C_CHECK(false) << name << ": header is not JSON (" << err.what() << ")";
  }
  M3C_CHECK(header.is_object()) << name << ": header is not a JSON object";
  const char* data = bytes.data() + 8 + header_size;
  const uint64_t data_size = bytes.size() - 8 - header_size;
  for (auto it = header.begin(); it != header.end(); ++it) {
    if (it.key() == "__metadata__") {
      M3C_CHECK(it->is_object()) << name << ": __metadata__ is not an object";
      for (auto m = it->begin(); m != it->end(); ++m) {
        M3C_CHECK(m->is_string()) << name << ": metadata '" << m.key() << "' is not a string";
        file.metadata_[m.key()] = m->get<std::string>();
      }
      continue;
    }
    const Json& info = *it;
    Tensor tensor;
    uint64_t begin = 0, end = 0;
    try {
      tensor.dtype = info.at("dtype").get<std::string>();
      tensor.shape = info.at("shape").get<std::vector<int64_t>>();
      const auto offsets = info.at("data_offsets").get<std::vector<uint64_t>>();
      M3C_CHECK(offsets.size() == 2) << name << ": tensor '" << it.key() << "' needs two data_offsets";
      begin = offsets[0];
      end = offsets[1];
    } catch (const Json::exception& err) {
      M3C_CHECK(false) << name << ": bad entry for tensor '" << it.key() << "' (" << err.what() << ")";
    }
    const int element = ElementSize(tensor.dtype);
    M3C_CHECK(element > 0) << name << ": tensor '" << it.key() << "' has unsupported dtype " << tensor.dtype;
    for (int64_t d : tensor.shape) M3C_CHECK(d >= 0) << name << ": tensor '" << it.key() << "' has a negative dim";
    const int64_t count = tensor.size();
    M3C_CHECK(begin <= end && end <= data_size && end - begin == static_cast<uint64_t>(count) * element)
        << name << ": tensor '" << it.key() << "' offsets " << begin << ".." << end << " do not fit shape "
        << ShapeOf(tensor.shape) << " " << tensor.dtype << " in a " << data_size << "-byte buffer";
    tensor.values.resize(count);
    Decode(tensor.dtype, data + begin, count, tensor.values.data());
    file.tensors_.emplace(it.key(), std::move(tensor));
  }
  return file;
}

std::vector<std::string> SafetensorsFile::Names() const {
  std::vector<std::string> names;
  for (const auto& kv : tensors_) names.push_back(kv.first);
  return names;
}

const std::string& SafetensorsFile::Metadata(const std::string& key) const {
  auto it = metadata_.find(key);
  M3C_CHECK(it != metadata_.end()) << path_ << ": no metadata '" << key << "'";
  return it->second;
}

const Tensor& SafetensorsFile::Get(const std::string& name) const {
  auto it = tensors_.find(name);
  if (it == tensors_.end()) {
    std::ostringstream known;
    int shown = 0;
    for (const auto& kv : tensors_) {
      if (shown++ == 8) {
        known << ", ...";
        break;
      }
      known << (shown > 1 ? ", " : "") << kv.first;
    }
    M3C_CHECK(false) << path_ << ": no tensor '" << name << "' (the file has " << tensors_.size() << ": "
                     << known.str() << ")";
  }
  return it->second;
}

RowMatrixXd SafetensorsFile::Matrix(const std::string& name, int64_t rows, int64_t cols) const {
  const Tensor& t = Get(name);
  M3C_CHECK(t.shape.size() == 2 && t.shape[0] == rows && t.shape[1] == cols)
      << path_ << ": tensor '" << name << "' must have shape " << ShapeOf({rows, cols}) << ", got "
      << t.ShapeString();
  return Eigen::Map<const RowMatrixXd>(t.values.data(), rows, cols);
}

Eigen::VectorXd SafetensorsFile::Vector(const std::string& name, int64_t size) const {
  const Tensor& t = Get(name);
  M3C_CHECK(t.shape.size() == 1 && t.shape[0] == size)
      << path_ << ": tensor '" << name << "' must have shape " << ShapeOf({size}) << ", got " << t.ShapeString();
  return Eigen::Map<const Eigen::VectorXd>(t.values.data(), size);
}

void WriteSafetensors(const std::string& path, const std::map<std::string, Tensor>& tensors,
                      const std::map<std::string, std::string>& metadata, const std::string& dtype) {
  M3C_CHECK(dtype == "F64" || dtype == "F32") << "WriteSafetensors stores F64 or F32, not " << dtype;
  const int element = ElementSize(dtype);
  Json header = Json::object();
  if (!metadata.empty()) header["__metadata__"] = metadata;
  std::string data;
  for (const auto& [name, tensor] : tensors) {
    M3C_CHECK(static_cast<int64_t>(tensor.values.size()) == tensor.size())
        << "tensor '" << name << "' holds " << tensor.values.size() << " values for shape " << tensor.ShapeString();
    const uint64_t begin = data.size();
    for (double v : tensor.values) {
      char bytes[8];
      if (element == 8) {
        std::memcpy(bytes, &v, 8);
      } else {
        const float f = static_cast<float>(v);
        std::memcpy(bytes, &f, 4);
      }
      data.append(bytes, element);
    }
    header[name] = {{"dtype", dtype}, {"shape", tensor.shape}, {"data_offsets", {begin, data.size()}}};
  }
  std::string text = header.dump();
  text.append((8 - text.size() % 8) % 8, ' ');
  const uint64_t size = text.size();
  char size_bytes[8];
  std::memcpy(size_bytes, &size, 8);

  namespace fs = std::filesystem;
  const fs::path target(path);
  std::random_device entropy;
  const fs::path tmp = target.parent_path() / ("." + target.filename().string() + "." +
                                               std::to_string(entropy()) + ".tmp");
  {
    std::ofstream out(tmp, std::ios::binary | std::ios::trunc);
    M3C_CHECK(out.good()) << "cannot write " << tmp.string();
    out.write(size_bytes, 8);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.write(data.data(), static_cast<std::streamsize>(data.size()));
    out.close();
    if (!out) {
      std::error_code ignored;
      fs::remove(tmp, ignored);
      M3C_CHECK(false) << "writing " << tmp.string() << " failed";
    }
  }
  std::error_code err;
  fs::rename(tmp, target, err);
  if (err) {
    std::error_code ignored;
    fs::remove(tmp, ignored);
    M3C_CHECK(false) << "cannot move " << tmp.string() << " to " << path << ": " << err.message();
  }
}

}  // namespace m3c::nn
