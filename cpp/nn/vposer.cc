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

void VPoser::EncodeMean(const double* pose_body, double* mean, double* jacobian) const {
  // Forward, keeping each LeakyReLU's slopes (1 or slope_) for the reverse pass.
  Eigen::VectorXd h = Eigen::Map<const Eigen::VectorXd>(pose_body, 3 * num_joints_);
  std::vector<Eigen::VectorXd> slopes;
  auto dense = [](const Dense& d, const Eigen::VectorXd& x) -> Eigen::VectorXd { return d.weight * x + d.bias; };
  auto fc = [&](Op op) -> const Dense& { return op == Op::kFc1 ? enc_fc1_ : op == Op::kFc2 ? enc_fc2_ : enc_fc3_; };
  for (Op op : encoder_ops_) {
    switch (op) {
      case Op::kBatchNorm1:
        h = h.cwiseProduct(enc_bn1_.scale) + enc_bn1_.shift;
        break;
      case Op::kBatchNorm2:
        h = h.cwiseProduct(enc_bn2_.scale) + enc_bn2_.shift;
        break;
      case Op::kFc1:
      case Op::kFc2:
      case Op::kFc3:
        h = dense(fc(op), h);
        break;
      case Op::kLeakyRelu: {
        Eigen::VectorXd s = (h.array() > 0.0).select(Eigen::VectorXd::Ones(h.size()), slope_);
        h = h.cwiseProduct(s);
        slopes.push_back(std::move(s));
        break;
      }
    }
  }
  Eigen::Map<Eigen::VectorXd>(mean, latent_dim_) = dense(enc_mu_, h);
  if (jacobian == nullptr) return;
  // Reverse: G = d mean / d (current activations), latent_dim x width.
  RowMatrixXd G = enc_mu_.weight;
  for (auto it = encoder_ops_.rbegin(); it != encoder_ops_.rend(); ++it) {
    switch (*it) {
      case Op::kBatchNorm1:
        G = G * enc_bn1_.scale.asDiagonal();
        break;
      case Op::kBatchNorm2:
        G = G * enc_bn2_.scale.asDiagonal();
        break;
      case Op::kFc1:
      case Op::kFc2:
      case Op::kFc3:
        G = G * fc(*it).weight;
        break;
      case Op::kLeakyRelu:
        G = G * slopes.back().asDiagonal();
        slopes.pop_back();
        break;
    }
  }
  Eigen::Map<RowMatrixXd>(jacobian, latent_dim_, 3 * num_joints_) = G;
}

}  // namespace m3c::nn
