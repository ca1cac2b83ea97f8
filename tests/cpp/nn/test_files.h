// Small random networks written in the exported layout (safetensors + "m3c" metadata) for the C++ tests.
#pragma once

#include <string>
#include <vector>

#include "nn/safetensors.h"

namespace m3c::nn::testing {

// A temporary path under the test's working directory, removed by the destructor.
class TempFile {
 public:
  explicit TempFile(const std::string& name);
  ~TempFile();
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

std::vector<double> RandomVector(int n, double scale, unsigned seed);

// HuMoR encoder + prior with hidden widths `hidden` (all layers), GroupNorm over `groups`.
void WriteRandomHumor(const std::string& path, int hidden, int groups, unsigned seed);
// VPoser "v1" or "v2" with the given hidden width and latent size (21 joints).
void WriteRandomVPoser(const std::string& path, const std::string& version, int hidden, int latent, unsigned seed);

// A random 339-d HuMoR state whose rotation blocks are proper rotations.
std::vector<double> RandomHumorState(unsigned seed);

}  // namespace m3c::nn::testing
