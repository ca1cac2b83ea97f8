#include "nn/vposer.h"

#include <nlohmann/json.hpp>

#include "util/check.h"

namespace m3c::nn {

VPoser::VPoser(const SafetensorsFile& file) {
  const auto it = file.metadata().find("m3c");
  M3C_CHECK(it != file.metadata().end())
      << file.path() << " has no M3C manifest entry (metadata 'm3c'); export VPoser with "
      << "python -m m3c.models.export --vposer PATH --out DIR";
  std::vector<std::string> ops;
  double bn_eps = 1e-5;
  try {
    const nlohmann::json entry = nlohmann::json::parse(it->second);
    M3C_CHECK(entry.at("architecture").get<std::string>() == "vposer")
        << file.path() << " holds a '" << entry.at("architecture").get<std::string>() << "' model, not VPoser";
    version_ = entry.at("version").get<std::string>();
    latent_dim_ = entry.at("latent_dim").get<int>();
    num_joints_ = entry.at("num_joints").get<int>();
    hidden_ = entry.at("hidden").get<int>();
    slope_ = entry.at("leaky_relu_slope").get<double>();
    bn_eps = entry.at("batch_norm_eps").get<double>();
    ops = entry.at("encoder_ops").get<std::vector<std::string>>();
  } catch (const nlohmann::json::exception& err) {
    M3C_CHECK(false) << file.path() << ": unreadable M3C manifest entry (" << err.what() << ")";
  }
  auto dense = [&](const std::string& name, int out, int in) {
    return Dense{file.Matrix(name + ".weight", out, in), file.Vector(name + ".bias", out)};
  };
  const int features = 3 * num_joints_;
  dec_fc1_ = dense("decoder.fc1", hidden_, latent_dim_);
  dec_fc2_ = dense("decoder.fc2", hidden_, hidden_);
  dec_out_ = dense("decoder.out", 6 * num_joints_, hidden_);
  enc_bn1_ = BatchNormEval(file, "encoder.bn1", features, bn_eps);
  enc_bn2_ = BatchNormEval(file, "encoder.bn2", hidden_, bn_eps);
  enc_fc1_ = dense("encoder.fc1", hidden_, features);
  enc_fc2_ = dense("encoder.fc2", hidden_, hidden_);
  enc_mu_ = dense("encoder.mu", latent_dim_, hidden_);
  enc_logvar_ = dense("encoder.logvar", latent_dim_, hidden_);
  for (const std::string& op : ops) {
    if (op == "bn1") {
      encoder_ops_.push_back(Op::kBatchNorm1);
    } else if (op == "bn2") {
      encoder_ops_.push_back(Op::kBatchNorm2);
    } else if (op == "fc1") {
      encoder_ops_.push_back(Op::kFc1);
    } else if (op == "fc2") {
      encoder_ops_.push_back(Op::kFc2);
    } else if (op == "fc3") {
      enc_fc3_ = dense("encoder.fc3", hidden_, hidden_);
      encoder_ops_.push_back(Op::kFc3);
    } else if (op == "leaky_relu") {
      encoder_ops_.push_back(Op::kLeakyRelu);
    } else {
      M3C_CHECK(false) << file.path() << ": unknown VPoser encoder op '" << op << "'";
    }
  }
}

}  // namespace m3c::nn
