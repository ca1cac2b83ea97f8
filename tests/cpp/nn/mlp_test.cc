#include "nn/mlp.h"

#include <gtest/gtest.h>

#include "jet_gradient.h"
#include "test_files.h"

namespace m3c::nn {
namespace {

using testing::JetGradient;
using testing::MaxRelativeError;
using testing::RandomVector;
using testing::TempFile;

// widths {10, 8, 8, 5}, 2 groups, the last 3 inputs skip-connected to every later Linear.
GroupNormMlp MakeMlp(const TempFile& tmp) {
  const std::vector<int> widths = {10, 8, 8, 5};
  const int skip = 3;
  std::map<std::string, Tensor> tensors;
  unsigned seed = 1;
  auto random = [&](std::vector<int64_t> shape, double scale, double offset) {
    Tensor t{"F64", shape, {}};
    t.values = RandomVector(static_cast<int>(t.size()), scale, seed++);
    for (double& v : t.values) v += offset;
    return t;
  };
  for (int k = 0; k < 3; ++k) {
    const int in = widths[k] + (k ? skip : 0);
    tensors["mlp." + std::to_string(3 * k) + ".weight"] = random({widths[k + 1], in}, 0.5, 0.0);
    tensors["mlp." + std::to_string(3 * k) + ".bias"] = random({widths[k + 1]}, 0.1, 0.0);
    if (k < 2) {
      tensors["mlp." + std::to_string(3 * k + 1) + ".weight"] = random({widths[k + 1]}, 0.2, 1.0);
      tensors["mlp." + std::to_string(3 * k + 1) + ".bias"] = random({widths[k + 1]}, 0.1, 0.0);
    }
  }
  WriteSafetensors(tmp.path(), tensors, {});
  return GroupNormMlp(SafetensorsFile::Read(tmp.path()), "mlp", widths, skip, 2, 1e-5);
}

TEST(GroupNormMlp, BatchMatchesSingleSample) {
  TempFile tmp("mlp_batch.safetensors");
  const GroupNormMlp mlp = MakeMlp(tmp);
  const int n = 4;
  const std::vector<double> x = RandomVector(10 * n, 1.0, 7);
  Eigen::Map<const Eigen::MatrixXd> X(x.data(), 10, n);
  Eigen::MatrixXd Y;
  GroupNormMlp::Activations acts;
  mlp.ForwardBatch(X, &Y, &acts);
  for (int j = 0; j < n; ++j) {
    double y[5];
    mlp.Forward(x.data() + 10 * j, y);
    for (int i = 0; i < 5; ++i) EXPECT_NEAR(Y(i, j), y[i], 1e-13 * (1 + std::abs(y[i])));
  }
}

TEST(GroupNormMlp, BackwardMatchesJetJacobian) {
  TempFile tmp("mlp_backward.safetensors");
  const GroupNormMlp mlp = MakeMlp(tmp);
  const int n = 3;
  const std::vector<double> x = RandomVector(10 * n, 1.0, 8), seeds = RandomVector(5 * n, 1.0, 9);
  Eigen::Map<const Eigen::MatrixXd> X(x.data(), 10, n), dY(seeds.data(), 5, n);
  Eigen::MatrixXd Y, dX;
  GroupNormMlp::Activations acts;
  mlp.ForwardBatch(X, &Y, &acts);
  mlp.BackwardBatch(acts, dY, &dX);
  for (int j = 0; j < n; ++j) {
    // d (seed . y) / dx by forward mode, all 10 inputs in one pass.
    const std::vector<double> xj(x.begin() + 10 * j, x.begin() + 10 * (j + 1));
    const std::vector<double> expected = JetGradient<10>(xj, [&](const auto& in) {
      using Jet = typename std::decay_t<decltype(in)>::value_type;
      Jet y[5];
      mlp.Forward(in.data(), y);
      Jet dot(0.0);
      for (int i = 0; i < 5; ++i) dot += seeds[5 * j + i] * y[i];
      return dot;
    });
    const std::vector<double> got(dX.col(j).data(), dX.col(j).data() + 10);
    EXPECT_LT(MaxRelativeError(got, expected), 1e-12) << "sample " << j;
  }
}

TEST(GroupNormMlp, RejectsWrongShapes) {
  TempFile tmp("mlp_shapes.safetensors");
  MakeMlp(tmp);
  const SafetensorsFile file = SafetensorsFile::Read(tmp.path());
  try {
    GroupNormMlp(file, "mlp", {10, 8, 8, 5}, 0, 2, 1e-5);  // the file was written with skip 3
    FAIL();
  } catch (const std::invalid_argument& err) {
    EXPECT_NE(std::string(err.what()).find("'mlp.3.weight' must have shape (8, 8), got (8, 11)"), std::string::npos)
        << err.what();
  }
  EXPECT_THROW(GroupNormMlp(file, "mlp", {10, 8, 8, 5}, 3, 3, 1e-5), std::invalid_argument);  // 8 % 3 != 0
}

}  // namespace
}  // namespace m3c::nn
