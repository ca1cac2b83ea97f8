#include "test_files.h"

#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <random>

#include "body/rotation.h"

namespace m3c::nn::testing {

TempFile::TempFile(const std::string& name) : path_("m3c_nn_test_" + name) {}
TempFile::~TempFile() { std::remove(path_.c_str()); }

std::vector<double> RandomVector(int n, double scale, unsigned seed) {
  std::mt19937 gen(seed);
  std::normal_distribution<double> normal(0.0, scale);
  std::vector<double> v(n);
  for (double& x : v) x = normal(gen);
  return v;
}

namespace {

Tensor Random(std::vector<int64_t> shape, double scale, unsigned seed, double offset = 0.0) {
  Tensor t;
  t.dtype = "F64";
  t.shape = shape;
  t.values = RandomVector(static_cast<int>(t.size()), scale, seed);
  for (double& v : t.values) v += offset;
  return t;
}

void AddMlp(std::map<std::string, Tensor>* tensors, const std::string& prefix, const std::vector<int>& widths,
            unsigned* seed) {
  for (size_t k = 0; k + 1 < widths.size(); ++k) {
    const std::string linear = prefix + "." + std::to_string(3 * k);
    const double scale = 1.0 / std::sqrt(static_cast<double>(widths[k]));
    (*tensors)[linear + ".weight"] = Random({widths[k + 1], widths[k]}, scale, (*seed)++);
    (*tensors)[linear + ".bias"] = Random({widths[k + 1]}, 0.1, (*seed)++);
    if (k + 2 < widths.size()) {
      const std::string norm = prefix + "." + std::to_string(3 * k + 1);
      (*tensors)[norm + ".weight"] = Random({widths[k + 1]}, 0.2, (*seed)++, 1.0);
      (*tensors)[norm + ".bias"] = Random({widths[k + 1]}, 0.1, (*seed)++);
    }
  }
}

}  // namespace

void WriteRandomHumor(const std::string& path, int hidden, int groups, unsigned seed) {
  const std::vector<int> encoder = {678, hidden, hidden, 96}, prior = {339, hidden, hidden, 96};
  std::map<std::string, Tensor> tensors;
  AddMlp(&tensors, "encoder.net", encoder, &seed);
  AddMlp(&tensors, "prior_net.net", prior, &seed);
  nlohmann::json entry = {{"architecture", "humor"}, {"state_dim", 339}, {"latent_dim", 48},
                          {"group_norm_groups", groups}, {"group_norm_eps", 1e-5}};
  entry["networks"] = {{"encoder", {{"layers", encoder}}}, {"prior", {{"layers", prior}}}};
  WriteSafetensors(path, tensors, {{"m3c", entry.dump()}});
}

void WriteRandomVPoser(const std::string& path, const std::string& version, int hidden, int latent,
                       unsigned seed) {
  std::map<std::string, Tensor> tensors;
  auto dense = [&](const std::string& name, int out, int in) {
    tensors[name + ".weight"] = Random({out, in}, 1.0 / std::sqrt(double(in)), seed++);
    tensors[name + ".bias"] = Random({out}, 0.1, seed++);
  };
  auto norm = [&](const std::string& name, int channels) {
    tensors[name + ".weight"] = Random({channels}, 0.2, seed++, 1.0);
    tensors[name + ".bias"] = Random({channels}, 0.1, seed++);
    tensors[name + ".running_mean"] = Random({channels}, 0.2, seed++);
    tensors[name + ".running_var"] = Random({channels}, 0.1, seed++, 1.0);
  };
  norm("encoder.bn1", 63);
  dense("encoder.fc1", hidden, 63);
  norm("encoder.bn2", hidden);
  dense("encoder.fc2", hidden, hidden);
  if (version == "v2") dense("encoder.fc3", hidden, hidden);
  dense("encoder.mu", latent, hidden);
  dense("encoder.logvar", latent, hidden);
  dense("decoder.fc1", hidden, latent);
  dense("decoder.fc2", hidden, hidden);
  dense("decoder.out", 126, hidden);
  const std::vector<std::string> ops =
      version == "v1" ? std::vector<std::string>{"bn1", "fc1", "leaky_relu", "bn2", "fc2", "leaky_relu"}
                      : std::vector<std::string>{"bn1", "fc1", "leaky_relu", "bn2", "fc2", "fc3"};
  const nlohmann::json entry = {{"architecture", "vposer"}, {"version", version}, {"latent_dim", latent},
                                {"num_joints", 21}, {"hidden", hidden},
                                {"leaky_relu_slope", version == "v1" ? 0.2 : 0.01}, {"batch_norm_eps", 1e-5},
                                {"encoder_ops", ops}};
  WriteSafetensors(path, tensors, {{"m3c", entry.dump()}});
}

std::vector<double> RandomHumorState(unsigned seed) {
  std::vector<double> x = RandomVector(339, 0.3, seed);
  const std::vector<double> angles = RandomVector(66, 0.8, seed + 1000);
  AxisAngleToRotation(angles.data(), x.data() + 6);
  for (int j = 0; j < 21; ++j) AxisAngleToRotation(angles.data() + 3 + 3 * j, x.data() + 18 + 9 * j);
  return x;
}

}  // namespace m3c::nn::testing
