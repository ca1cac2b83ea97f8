#include "motion/humor_term.h"

#include <algorithm>
#include <cmath>

#include "body/block_points.h"
#include "body/kinematics.h"
#include "body/rotation.h"
#include "nn/humor_state.h"
#include "util/check.h"

namespace m3c::motion {

using nn::humor::kNumBodyJoints;
using nn::humor::kNumStateJoints;
using nn::humor::kStateDim;
using body::RowMatrixXd;

struct HumorContext {
  const body::BodyModel* model;
  const nn::HumorPrior* prior;
  std::shared_ptr<const body::KeypointRegressor> joints;  // SMPL joints 0..23 (the state uses 0..21)
  double fps;
  Eigen::Matrix<double, 3, 3, Eigen::RowMajor> R;  // world -> ground frame
  Eigen::Vector3d t;
};

namespace {

constexpr int kJointValues = 3 * kNumStateJoints;  // 66
using TransRootJet = ceres::Jet<double, 18>;       // trans of frames a, b, c | root of a, b, c
using AxisJet = ceres::Jet<double, 3>;

void CheckModel(const body::BodyModel& model, double fps) {
  M3C_CHECK(model.num_joints() == 24) << "the HuMoR term needs SMPL's 24-joint layout";
  M3C_CHECK(fps > 0) << "fps must be > 0";
}

// Values per frame of the packed gradient: transl 3, root 3, body 3(J-1); betas follow the four frames.
int PerFrame(const body::BodyModel& model) { return 6 + 3 * (model.num_joints() - 1); }
int PackedSize(const body::BodyModel& model) { return 4 * PerFrame(model) + model.num_betas(); }

// A frame's SMPL joints 0..21 and, when wanted, d joints / d [transl | root | body | betas].
struct FrameJoints {
  double joints[kJointValues];
  RowMatrixXd jacobian;  // 66 x (3 + 3J + B)
};

void EvaluateFrame(const HumorContext& c, const double* transl, const double* root, const double* body,
                   const double* betas, bool with_jacobian, FrameJoints* out) {
  body::BlockPoints points;
  points.Evaluate(*c.model, *c.joints, {transl, root, body, betas}, with_jacobian);
  std::copy(points.data(), points.data() + kJointValues, out->joints);
  if (with_jacobian) {
    out->jacobian = Eigen::Map<const RowMatrixXd>(points.jacobian_row(0), kJointValues, body::NumJacobianColumns(*c.model));
  }
}

// The state of frames a, b, c (t-1, t, t+1) with the body pose of b, and its Jacobian in the pieces that are not
// constant: translations and root orientations (forward-mode Jets over those 18 inputs) and each body joint's
// rotation (block diagonal). Joints enter the state linearly (PullBack).
struct StateValue {
  double x[kStateDim];
  Eigen::MatrixXd trans_root;                          // 339 x 18
  Eigen::Matrix<double, 9, 3> pose[kNumBodyJoints];    // d rotation_j (row-major) / d axis-angle_j
};

void BuildStateAt(const HumorContext& c, const double* const trans[3], const double* const root[3],
                  const FrameJoints* const frames[3], const double* pose, bool with_jacobian, StateValue* out) {
  const double* joints[3] = {frames[0]->joints, frames[1]->joints, frames[2]->joints};
  if (!with_jacobian) {
    nn::humor::BuildState(trans, root, joints, pose, c.fps, c.R.data(), c.t.data(), out->x);
    return;
  }
  using Jet = TransRootJet;
  std::vector<Jet> in(18), jo(3 * kJointValues), pose_j(3 * kNumBodyJoints), R(9), t(3), x(kStateDim);
  for (int k = 0; k < 3; ++k) {
    for (int i = 0; i < 3; ++i) {
      in[3 * k + i] = Jet(trans[k][i], 3 * k + i);
      in[9 + 3 * k + i] = Jet(root[k][i], 9 + 3 * k + i);
    }
    for (int i = 0; i < kJointValues; ++i) jo[kJointValues * k + i] = Jet(joints[k][i]);
  }
  for (int i = 0; i < 3 * kNumBodyJoints; ++i) pose_j[i] = Jet(pose[i]);
  for (int i = 0; i < 9; ++i) R[i] = Jet(c.R.data()[i]);
  for (int i = 0; i < 3; ++i) t[i] = Jet(c.t[i]);
  const Jet* tr[3] = {&in[0], &in[3], &in[6]};
  const Jet* ro[3] = {&in[9], &in[12], &in[15]};
  const Jet* jp[3] = {&jo[0], &jo[kJointValues], &jo[2 * kJointValues]};
  nn::humor::BuildState(tr, ro, jp, pose_j.data(), c.fps, R.data(), t.data(), x.data());
  out->trans_root.resize(kStateDim, 18);
  for (int i = 0; i < kStateDim; ++i) {
    out->x[i] = x[i].a;
    out->trans_root.row(i) = x[i].v.transpose();
  }
  for (int j = 0; j < kNumBodyJoints; ++j) {
    const AxisJet aa[3] = {AxisJet(pose[3 * j], 0), AxisJet(pose[3 * j + 1], 1), AxisJet(pose[3 * j + 2], 2)};
    AxisJet rot[9];
    AxisAngleToRotation(aa, rot);
    for (int r = 0; r < 9; ++r) out->pose[j].row(r) = rot[r].v.transpose();
  }
}

// dL/d(inputs of a state) from g = dL/dx.
struct StateGradient {
  double trans[3][3], root[3][3], joints[3][kJointValues], pose[3 * kNumBodyJoints];
};

void PullBack(const HumorContext& c, const StateValue& s, const double* g, StateGradient* out) {
  using nn::humor::kJoints, nn::humor::kJointsVel, nn::humor::kPoseBody, nn::humor::kTrans, nn::humor::kTransVel;
  const Eigen::Map<const Eigen::VectorXd> gv(g, kStateDim);
  const Eigen::VectorXd tr = s.trans_root.transpose() * gv;
  for (int k = 0; k < 3; ++k) {
    for (int i = 0; i < 3; ++i) {
      out->trans[k][i] = tr[3 * k + i];
      out->root[k][i] = tr[9 + 3 * k + i];
    }
  }
  for (int j = 0; j < kNumBodyJoints; ++j) {
    Eigen::Map<Eigen::Vector3d>(out->pose + 3 * j) = s.pose[j].transpose() * gv.segment<9>(kPoseBody + 9 * j);
  }
  // The joints' paths (TransformSmpl, then central differences): joints_b' = R jo_b + t, joint velocities
  // R (jo_c - jo_a) fps / 2, and the translation trans' = trans + (R - I) pelvis of each frame.
  const Eigen::Matrix3d Rt = c.R.transpose();
  const Eigen::Matrix3d Pt = Rt - Eigen::Matrix3d::Identity();
  const double half_fps = 0.5 * c.fps;
  using V3 = Eigen::Map<Eigen::Vector3d>;
  using CV3 = Eigen::Map<const Eigen::Vector3d>;
  for (int j = 0; j < kNumStateJoints; ++j) {
    V3(out->joints[1] + 3 * j) = Rt * CV3(g + kJoints + 3 * j);
    const Eigen::Vector3d v = half_fps * (Rt * CV3(g + kJointsVel + 3 * j));
    V3(out->joints[2] + 3 * j) = v;
    V3(out->joints[0] + 3 * j) = -v;
  }
  V3(out->joints[1]) += Pt * CV3(g + kTrans);
  const Eigen::Vector3d v = half_fps * (Pt * CV3(g + kTransVel));
  V3(out->joints[2]) += v;
  V3(out->joints[0]) -= v;
}

// Adds state s's (window frames s..s+2) gradient to the transition's packed gradient, through each frame's joints.
void AddToBlocks(const body::BodyModel& model, const StateGradient& sg, int s, const FrameJoints* const window[4],
                 double* grad) {
  const int J = model.num_joints(), B = model.num_betas(), per_frame = PerFrame(model);
  for (int k = 0; k < 3; ++k) {
    const int f = s + k;
    double* gf = grad + f * per_frame;
    const Eigen::RowVectorXd via = Eigen::Map<const Eigen::RowVectorXd>(sg.joints[k], kJointValues) * window[f]->jacobian;
    for (int i = 0; i < 3; ++i) {
      gf[i] += sg.trans[k][i] + via[i];
      gf[3 + i] += sg.root[k][i] + via[3 + i];
    }
    for (int i = 0; i < 3 * (J - 1); ++i) gf[6 + i] += via[6 + i];
    if (k == 1) {
      for (int i = 0; i < 3 * kNumBodyJoints; ++i) gf[6 + i] += sg.pose[i];
    }
    for (int i = 0; i < B; ++i) grad[4 * per_frame + i] += via[3 + 3 * J + i];
  }
}

// The packed gradient of a transition's NLL from dNLL/dx of its two states.
void TransitionGradient(const HumorContext& c, const StateValue* const states[2], const double* const g[2],
                        const FrameJoints* const window[4], double* grad) {
  std::fill(grad, grad + PackedSize(*c.model), 0.0);
  StateGradient sg;
  for (int s = 0; s < 2; ++s) {
    PullBack(c, *states[s], g[s], &sg);
    AddToBlocks(*c.model, sg, s, window, grad);
  }
}

// One transition from its 13 parameter blocks: NLL and, if grad is not null, its packed gradient.
void ComputeTransition(const HumorContext& c, double const* const* p, double* nll, double* grad) {
  const bool with_gradient = grad != nullptr;
  FrameJoints frames[4];
  for (int f = 0; f < 4; ++f) EvaluateFrame(c, p[3 * f], p[3 * f + 1], p[3 * f + 2], p[12], with_gradient, &frames[f]);
  StateValue states[2];
  for (int s = 0; s < 2; ++s) {
    const double* trans[3] = {p[3 * s], p[3 * (s + 1)], p[3 * (s + 2)]};
    const double* root[3] = {p[3 * s + 1], p[3 * (s + 1) + 1], p[3 * (s + 2) + 1]};
    const FrameJoints* window[3] = {&frames[s], &frames[s + 1], &frames[s + 2]};
    BuildStateAt(c, trans, root, window, p[3 * (s + 1) + 2], with_gradient, &states[s]);
  }
  double g0[kStateDim], g1[kStateDim];
  c.prior->TransitionNll(1, states[0].x, states[1].x, nll, with_gradient ? g0 : nullptr, with_gradient ? g1 : nullptr);
  if (!with_gradient) return;
  const StateValue* pair[2] = {&states[0], &states[1]};
  const double* g[2] = {g0, g1};
  const FrameJoints* window[4] = {&frames[0], &frames[1], &frames[2], &frames[3]};
  TransitionGradient(c, pair, g, window, grad);
}

std::shared_ptr<const HumorContext> MakeContext(const body::BodyModel* model, const nn::HumorPrior* prior,
                                                std::shared_ptr<const body::KeypointRegressor> joints, double fps,
                                                const Eigen::Matrix3d& R, const Eigen::Vector3d& t) {
  CheckModel(*model, fps);
  M3C_CHECK(R.allFinite() && t.allFinite()) << "the ground frame must be finite";
  auto c = std::make_shared<HumorContext>();
  c->model = model;
  c->prior = prior;
  c->joints = std::move(joints);
  c->fps = fps;
  c->R = R;
  c->t = t;
  return c;
}

void SetBlockSizes(const body::BodyModel& model, std::vector<int32_t>* sizes) {
  for (int k = 0; k < 4; ++k) sizes->insert(sizes->end(), {3, 3, 3 * (model.num_joints() - 1)});
  sizes->push_back(model.num_betas());
}

}  // namespace

void GroundFrame(const Eigen::Vector3d& normal, double offset, Eigen::Matrix3d* R, Eigen::Vector3d* t) {
  const Eigen::Vector3d n = normal.normalized();
  const Eigen::Vector3d seed = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  const Eigen::Vector3d e1 = (seed - seed.dot(n) * n).normalized();
  const Eigen::Vector3d e2 = n.cross(e1);
  R->row(0) = e1.transpose();
  R->row(1) = e2.transpose();
  R->row(2) = n.transpose();
  *t = Eigen::Vector3d(0.0, 0.0, offset / normal.norm());
}

// --- HumorTransitionCost ---

HumorTransitionCost::HumorTransitionCost(const body::BodyModel* model, const nn::HumorPrior* prior, double fps,
                                         const Eigen::Matrix3d& ground_R, const Eigen::Vector3d& ground_t,
                                         double weight, double level)
    : context_(MakeContext(model, prior, std::make_shared<body::KeypointRegressor>(body::IdentityJointRegressor(*model)),
                           fps, ground_R, ground_t)),
      weight_(weight),
      level_(level) {
  M3C_CHECK(weight >= 0) << "weight must be >= 0";
  set_num_residuals(1);
  SetBlockSizes(*model, mutable_parameter_block_sizes());
}

HumorTransitionCost::HumorTransitionCost(const HumorTransitionBatch* batch, int index, double weight, double level)
    : batch_(batch), index_(index), weight_(weight), level_(level) {
  M3C_CHECK(batch != nullptr && index >= 0 && index < batch->num_transitions())
      << "transition " << index << " is not in the batch";
  M3C_CHECK(weight >= 0) << "weight must be >= 0";
  context_ = batch->Context(index);
  set_num_residuals(1);
  SetBlockSizes(*context_->model, mutable_parameter_block_sizes());
}

HumorTransitionCost::~HumorTransitionCost() = default;

double HumorTransitionCost::Nll(double const* const* parameters) const {
  double value = 0.0;
  ComputeTransition(*context_, parameters, &value, nullptr);
  return value;
}

bool HumorTransitionCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  double nll = 0.0;
  std::vector<double> grad(jacobians ? PackedSize(*context_->model) : 0);
  double* g = jacobians ? grad.data() : nullptr;
  if (batch_ == nullptr || !batch_->Lookup(index_, parameters, &nll, g)) ComputeTransition(*context_, parameters, &nll, g);
  if (!std::isfinite(nll)) return false;
  const double r = std::sqrt(std::max(weight_ * (nll - level_), 0.0));
  residuals[0] = r;
  if (!jacobians) return true;
  // d sqrt(w (nll - c)) = w / (2 r) d nll; below the level the term is flat.
  const double scale = r < 1e-9 ? 0.0 : weight_ / (2.0 * r);
  int offset = 0;
  for (int blk = 0; blk < 13; ++blk) {
    const int size = parameter_block_sizes()[blk];
    if (jacobians[blk]) {
      for (int i = 0; i < size; ++i) jacobians[blk][i] = scale * grad[offset + i];
    }
    offset += size;
  }
  return true;
}

// --- HumorTransitionBatch ---

struct HumorTransitionBatch::TrackBlocks {
  std::shared_ptr<const HumorContext> context;
  std::vector<double*> transl, root, body;
  double* betas;
  int first_frame = 0, first_state = 0;  // offsets into the cache's frames and states
};

struct HumorTransitionBatch::Cache {
  bool valid = false, with_gradient = false;
  int per_frame = 0, num_betas = 0;
  std::vector<double> inputs;  // per frame: transl, root, body (per_frame values)
  std::vector<double> betas;   // per track

  // The values of frame k / track i's betas at the last evaluation: store and compare.
  void StoreFrame(size_t k, const double* transl, const double* root, const double* body) {
    double* in = inputs.data() + k * per_frame;
    std::copy(transl, transl + 3, in);
    std::copy(root, root + 3, in + 3);
    std::copy(body, body + per_frame - 6, in + 6);
  }
  bool FrameMatches(size_t k, const double* transl, const double* root, const double* body) const {
    const double* in = inputs.data() + k * per_frame;
    return std::equal(in, in + 3, transl) && std::equal(in + 3, in + 6, root) && std::equal(in + 6, in + per_frame, body);
  }
  bool BetasMatch(size_t i, const double* b) const {
    return std::equal(betas.begin() + i * num_betas, betas.begin() + (i + 1) * num_betas, b);
  }
  std::vector<double> nll, grad;  // per transition; grad packed (PackedSize values each)
};

HumorTransitionBatch::HumorTransitionBatch(const body::BodyModel* model, const nn::HumorPrior* prior, double fps,
                                           int num_threads, int chunk)
    : model_(model),
      prior_(prior),
      joints_(std::make_shared<body::KeypointRegressor>(body::IdentityJointRegressor(*model))),
      fps_(fps),
      num_threads_(std::max(1, num_threads)),
      chunk_(chunk),
      cache_(std::make_unique<Cache>()) {
  CheckModel(*model, fps);
  M3C_CHECK(prior != nullptr) << "no HuMoR prior";
  M3C_CHECK(chunk > 0) << "chunk must be > 0, got " << chunk;
  cache_->per_frame = PerFrame(*model);
  cache_->num_betas = model->num_betas();
}

HumorTransitionBatch::~HumorTransitionBatch() = default;

void HumorTransitionBatch::AddTrack(const std::vector<double*>& transl, const std::vector<double*>& root,
                                    const std::vector<double*>& body, double* betas, const Eigen::Matrix3d& ground_R,
                                    const Eigen::Vector3d& ground_t) {
  const int n = static_cast<int>(transl.size());
  M3C_CHECK(n >= 4 && root.size() == transl.size() && body.size() == transl.size() && betas != nullptr)
      << "a HuMoR track needs >= 4 frames with transl, root and body blocks for each, and betas";
  TrackBlocks track;
  track.context = MakeContext(model_, prior_, joints_, fps_, ground_R, ground_t);
  track.transl = transl, track.root = root, track.body = body, track.betas = betas;
  if (!tracks_.empty()) {
    const TrackBlocks& last = tracks_.back();
    track.first_frame = last.first_frame + static_cast<int>(last.transl.size());
    track.first_state = last.first_state + static_cast<int>(last.transl.size()) - 2;
  }
  for (int f = 1; f + 2 < n; ++f) transitions_.push_back({static_cast<int>(tracks_.size()), f});
  tracks_.push_back(std::move(track));
  cache_->valid = false;
}

std::shared_ptr<const HumorContext> HumorTransitionBatch::Context(int i) const {
  return tracks_[transitions_.at(i).track].context;
}

std::vector<double*> HumorTransitionBatch::Parameters(int i) const {
  const Transition& tr = transitions_.at(i);
  const TrackBlocks& t = tracks_[tr.track];
  std::vector<double*> blocks;
  for (int f = tr.frame - 1; f <= tr.frame + 2; ++f) blocks.insert(blocks.end(), {t.transl[f], t.root[f], t.body[f]});
  blocks.push_back(t.betas);
  return blocks;
}

std::vector<double> HumorTransitionBatch::Nll() {
  Evaluate(false);
  return cache_->nll;
}

void HumorTransitionBatch::PrepareForEvaluation(bool /*evaluate_jacobians*/, bool /*new_evaluation_point*/) {
  // Ceres also calls this for evaluations of other terms' blocks (Problem::Evaluate on a subset, with
  // new_evaluation_point = true although nothing moved): the cache is kept while the values are unchanged.
  // Every point is evaluated with its gradient, even when Ceres asks for values only: it evaluates a trial point's
  // values and, when it accepts the step (27 of 31 iterations of bench/motion_optimizer.py's motion-prior stage),
  // asks for the Jacobian at the same point next, which would run the batch's forward pass again. (ibid.: the
  // stage's evaluations took 35.2 s instead of 36.9 s, with the same steps.)
  const Cache& c = *cache_;
  if (c.valid && c.with_gradient && InputsUnchanged()) return;
  Evaluate(true);
}

bool HumorTransitionBatch::InputsUnchanged() const {
  const Cache& c = *cache_;
  for (size_t i = 0; i < tracks_.size(); ++i) {
    const TrackBlocks& t = tracks_[i];
    if (!c.BetasMatch(i, t.betas)) return false;
    for (size_t f = 0; f < t.transl.size(); ++f) {
      if (!c.FrameMatches(t.first_frame + f, t.transl[f], t.root[f], t.body[f])) return false;
    }
  }
  return true;
}

void HumorTransitionBatch::Evaluate(bool with_gradient) {
  Cache& c = *cache_;
  c.valid = false;
  const int per_frame = PerFrame(*model_), B = model_->num_betas(), packed = PackedSize(*model_);
  // Where each frame and state lives: (track, frame) pairs, in the order of the cache's frames and states.
  std::vector<std::pair<int, int>> frames, states;
  for (int i = 0; i < static_cast<int>(tracks_.size()); ++i) {
    const int n = static_cast<int>(tracks_[i].transl.size());
    for (int f = 0; f < n; ++f) frames.emplace_back(i, f);
    for (int f = 1; f + 1 < n; ++f) states.emplace_back(i, f);  // f: the middle frame
  }
  const int num_frames = static_cast<int>(frames.size());
  const int N = num_transitions();
  c.inputs.resize(static_cast<size_t>(num_frames) * per_frame);
  c.betas.resize(tracks_.size() * B);
  for (int k = 0; k < num_frames; ++k) {
    const TrackBlocks& t = tracks_[frames[k].first];
    const int f = frames[k].second;
    c.StoreFrame(k, t.transl[f], t.root[f], t.body[f]);
  }
  for (size_t i = 0; i < tracks_.size(); ++i) std::copy(tracks_[i].betas, tracks_[i].betas + B, c.betas.begin() + i * B);
  c.nll.assign(N, 0.0);
  if (with_gradient) c.grad.assign(static_cast<size_t>(N) * packed, 0.0);

  // A chunk of transitions at a time: the frames' joint Jacobians and the states' Jacobians (~100 KB per frame)
  // are held for one chunk only, not for the whole problem beside Ceres's normal equations (600 frames x 2
  // people: ~110 MB). Transition (t, f) reads frames f-1..f+2 of track t (cache frame first_frame + f - 1 on) and
  // the states of middle frames f and f + 1 (cache state first_state + f - 1 on), so a chunk's frames and states
  // are consecutive in the cache; frames and states at a chunk's edges are evaluated again for the next chunk.
  std::vector<FrameJoints> chunk_frames;
  std::vector<StateValue> chunk_states;
  RowMatrixXd x0, x1, g0, g1;
  for (int first = 0; first < N; first += chunk_) {
    const int count = std::min(chunk_, N - first);
    const Transition& head = transitions_[first];
    const Transition& tail = transitions_[first + count - 1];
    const int frame0 = tracks_[head.track].first_frame + head.frame - 1;
    const int state0 = tracks_[head.track].first_state + head.frame - 1;
    const int num_chunk_frames = tracks_[tail.track].first_frame + tail.frame + 3 - frame0;
    const int num_chunk_states = tracks_[tail.track].first_state + tail.frame + 1 - state0;
    // Their Jacobians are allocated here, on the calling thread, not by the loops' threads: freed, they then serve
    // this thread's next allocations (the solve's) instead of staying in the other threads' heaps.
    if (static_cast<int>(chunk_frames.size()) < num_chunk_frames) chunk_frames.resize(num_chunk_frames);
    if (static_cast<int>(chunk_states.size()) < num_chunk_states) chunk_states.resize(num_chunk_states);
    if (with_gradient) {
      for (FrameJoints& f : chunk_frames) f.jacobian.resize(kJointValues, body::NumJacobianColumns(*model_));
      for (StateValue& s : chunk_states) s.trans_root.resize(kStateDim, 18);
    }
#pragma omp parallel for num_threads(num_threads_) schedule(dynamic, 4)
    for (int k = 0; k < num_chunk_frames; ++k) {
      const TrackBlocks& t = tracks_[frames[frame0 + k].first];
      const int f = frames[frame0 + k].second;
      EvaluateFrame(*t.context, t.transl[f], t.root[f], t.body[f], t.betas, with_gradient, &chunk_frames[k]);
    }
#pragma omp parallel for num_threads(num_threads_) schedule(dynamic, 4)
    for (int k = 0; k < num_chunk_states; ++k) {
      const TrackBlocks& t = tracks_[states[state0 + k].first];
      const int f = states[state0 + k].second;
      const double* trans[3] = {t.transl[f - 1], t.transl[f], t.transl[f + 1]};
      const double* root[3] = {t.root[f - 1], t.root[f], t.root[f + 1]};
      const int at = t.first_frame + f - frame0;  // the chunk frame of frame f
      const FrameJoints* window[3] = {&chunk_frames[at - 1], &chunk_frames[at], &chunk_frames[at + 1]};
      BuildStateAt(*t.context, trans, root, window, t.body[f], with_gradient, &chunk_states[k]);
    }
    auto state_of = [&](const Transition& tr, int s) -> const StateValue& {
      return chunk_states[tracks_[tr.track].first_state + tr.frame - 1 + s - state0];
    };
    x0.resize(count, kStateDim), x1.resize(count, kStateDim);
    for (int i = 0; i < count; ++i) {
      x0.row(i) = Eigen::Map<const Eigen::RowVectorXd>(state_of(transitions_[first + i], 0).x, kStateDim);
      x1.row(i) = Eigen::Map<const Eigen::RowVectorXd>(state_of(transitions_[first + i], 1).x, kStateDim);
    }
    if (with_gradient) g0.resize(count, kStateDim), g1.resize(count, kStateDim);
    prior_->TransitionNll(count, x0.data(), x1.data(), c.nll.data() + first, with_gradient ? g0.data() : nullptr,
                          with_gradient ? g1.data() : nullptr);
    if (!with_gradient) continue;
#pragma omp parallel for num_threads(num_threads_) schedule(dynamic, 8)
    for (int i = 0; i < count; ++i) {
      const Transition& tr = transitions_[first + i];
      const TrackBlocks& t = tracks_[tr.track];
      const StateValue* pair[2] = {&state_of(tr, 0), &state_of(tr, 1)};
      const double* g[2] = {g0.row(i).data(), g1.row(i).data()};
      const FrameJoints* window[4];
      for (int k = 0; k < 4; ++k) window[k] = &chunk_frames[t.first_frame + tr.frame - 1 + k - frame0];
      TransitionGradient(*t.context, pair, g, window, c.grad.data() + static_cast<size_t>(first + i) * packed);
    }
  }
  c.with_gradient = with_gradient;
  c.valid = true;
}

bool HumorTransitionBatch::Lookup(int i, double const* const* parameters, double* nll, double* grad) const {
  const Cache& c = *cache_;
  if (!c.valid || (grad != nullptr && !c.with_gradient) || i < 0 || i >= num_transitions()) return false;
  const Transition& tr = transitions_[i];
  const TrackBlocks& t = tracks_[tr.track];
  for (int k = 0; k < 4; ++k) {
    if (!c.FrameMatches(t.first_frame + tr.frame - 1 + k, parameters[3 * k], parameters[3 * k + 1], parameters[3 * k + 2])) {
      return false;
    }
  }
  if (!c.BetasMatch(tr.track, parameters[12])) return false;
  *nll = c.nll[i];
  if (grad) {
    const int packed = PackedSize(*model_);
    std::copy(c.grad.begin() + static_cast<size_t>(i) * packed, c.grad.begin() + static_cast<size_t>(i + 1) * packed, grad);
  }
  return true;
}

}  // namespace m3c::motion
