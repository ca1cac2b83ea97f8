#include "motion/world_optimizer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <sstream>
#include <thread>
#ifdef __GLIBC__
#include <malloc.h>
#endif
#include <unordered_map>
#include <unordered_set>

#include "body/kinematics.h"
#include "motion/humor_term.h"
#include "motion/joint_blocks.h"
#include "motion/lm_solver.h"
#include "motion/vposer_term.h"
#include "util/blas_threads.h"
#include "util/check.h"
#include "util/openmp_levels.h"

namespace m3c::motion {

namespace {

enum class Group { kTransl, kRoot, kBody, kLatent, kBetas, kScale, kOffset };

bool AllFinite(const RowMatrixXd& m) { return m.allFinite(); }

// Parameter storage: one row per frame, so a row is a Ceres parameter block.
struct State {
  std::vector<RowMatrixXd> transl, root, body, latent;  // latent: empty unless poses are VPoser latents
  std::vector<Eigen::VectorXd> betas;
  double scale = 1.0;
  Eigen::Vector3d offset = Eigen::Vector3d::Zero();
  bool AllFinite() const {
    for (size_t i = 0; i < transl.size(); ++i) {
      if (!transl[i].allFinite() || !root[i].allFinite() || !body[i].allFinite() || !betas[i].allFinite()) return false;
      if (!latent.empty() && !latent[i].allFinite()) return false;
    }
    return std::isfinite(scale) && offset.allFinite();
  }
};

// A problem's evaluation callback: decodes latent poses first (the motion prior reads the decoded body blocks),
// then evaluates the shared joints and the motion prior's batch. Ceres calls it on the thread that solves, where
// OpenMP is off for CHOLMOD (SolveSerial): these loops get this thread's parallelism outside the solve back.
// As the solve's iteration callback it frees the shared joints' evaluation: Ceres runs it after an iteration's
// evaluations and before it factorizes the next step's normal equations, the stage's memory peak, and the next
// evaluation is at a new point.
class StageCallback : public ceres::EvaluationCallback, public ceres::IterationCallback {
 public:
  // levels: the OpenMP levels of the callback's loops (ScopedOpenMpLevels; 0 when its solve has one thread).
  StageCallback(LatentPoseDecoder* decoder, std::vector<SharedJoints*> joints, HumorTransitionBatch* humor,
                int levels)
      : decoder_(decoder), joints_(std::move(joints)), humor_(humor), levels_(levels) {}
  void PrepareForEvaluation(bool evaluate_jacobians, bool new_evaluation_point) override {
    const util::ScopedOpenMpLevels ours(levels_);
    if (decoder_) decoder_->DecodeAll(evaluate_jacobians);
    for (SharedJoints* joints : joints_) joints->PrepareForEvaluation(evaluate_jacobians, new_evaluation_point);
    if (humor_) humor_->PrepareForEvaluation(evaluate_jacobians, new_evaluation_point);
  }
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& /*summary*/) override {
    for (SharedJoints* joints : joints_) joints->Release();
    return ceres::SOLVER_CONTINUE;
  }

 private:
  LatentPoseDecoder* decoder_;
  std::vector<SharedJoints*> joints_;
  HumorTransitionBatch* humor_;
  int levels_;
};

// Ceres calls with OpenMP off on this thread (util/openmp_levels.h: CHOLMOD's teams of 4 per supernode).
bool EvaluateSerial(ceres::Problem* problem, const ceres::Problem::EvaluateOptions& options, double* cost,
                    std::vector<double>* residuals) {
  const util::ScopedOpenMpLevels serial(0);
  return problem->Evaluate(options, cost, residuals, nullptr, nullptr);
}
// The spine of "upright": SMPL's pelvis and neck (m3c.body.transform.spine_directions reads "up" the same way).
constexpr int kSmplJoints = 24, kPelvis = 0, kNeck = 12;

void SolveSerial(const ceres::Solver::Options& options, ceres::Problem* problem, ceres::Solver::Summary* summary) {
  const util::ScopedOpenMpLevels serial(0);
  ceres::Solve(options, problem, summary);
}

}  // namespace

OptimizerConfig DefaultOptimizerConfig() {
  // The thesis's stages (i)-(v) as Ceres solves, with SLAHMR's weights. Departures, each measured on the
  // synthetic scenes (m3c.eval.scenes) and the ground-truth benchmark (m3c eval benchmark):
  //  - the camera scale is M3C's one scale estimator's (m3c.vo.scale; CameraInput::initial_scale) and no stage
  //    frees it: with a camera that follows its subject any smoothness of world-frame joints is cheaper in a
  //    smaller world (freeing it with the motion prior moved a 600-frame scene's scale from 2.01 to 2.46 and its
  //    world error from 110 to 1683 mm, bench/motion_optimizer.py), and a stage that refined it from the
  //    contacts without smoothing made the world jitter (its world check doubled). A configuration that frees
  //    it gets "scale_prior", the estimator's log-normal uncertainty (CameraInput::scale_sigma);
  //  - the foot contacts ("contacts" stage, then every later stage) hold planted feet still and on the ground:
  //    each contact joint at its standing height (its height above the sole in the rest pose, the ankle's about
  //    7 cm) within contact_height_tolerance 3 cm, and "ground_penetration" (weight 100, with the contacts and
  //    in the world check) keeps every contact joint of every frame above it. Before (each joint held within
  //    8 cm of the sole's plane, nothing on the frames not labelled on the ground) a foot was more than 2 cm
  //    under the ground in 17% of a track's frames on average (video benchmark seed 0; 74% on the worst track)
  //    and in 58% of the bundled walking clip's frames; now in none of either, and seed 0's W-MPJPE100 went
  //    263 -> 257 mm. At 1000 the handheld sequence's speed error went -4.6 -> -14.1%. Measurements: README,
  //    "Feet on the floor".
  //  - the shape prior is 10x SLAHMR's: at 0.05 the shape stage traded the people's size against their depth
  //    and raised a 600-frame scene's world error by 6% (bench/motion_optimizer.py; 231 -> 157 mm at 0.5);
  //  - every stage is checked against the world (world_check: the images, jitter, planted feet, the ground at
  //    the recipe's weights) and reverted when it makes the world worse by more than 5%;
  //  - joints are smoothed by their acceleration, not their velocity: SLAHMR's first-order |J_{t+1} - J_t|^2
  //    pulls every person towards standing still, and with its weight it cost more PA-MPJPE than the
  //    keypoints could win back (starting from the truth: 0 -> 69 mm). The acceleration term is also active
  //    in the root stages (SLAHMR smooths there too): under keypoints alone the depth of a frame with few
  //    visible keypoints slides along its ray, and those jumps spoilt the stance-feet scale fit (a benchmark
  //    scale of 67 for a true 0.63). Its weight is 30, 3x SLAHMR's: on video the fitted bodies' depth along
  //    the camera ray swings by 5-17 cm at the gait's frequency (0.6-1 Hz), which the images barely see and
  //    which made people walk a third faster than they did (m3c eval video-benchmark, seeds 0, 1, 2: speed
  //    error 35, 33, 34% at 10 -> 21, 26, 25% at 30; W-MPJPE100 319, 401, 390 -> 312, 390, 387 mm). Heavier
  //    smoothing helps video further (300: 5, 13, 10%) but stiffens cleaner input: at 100 the 600-frame
  //    bench's shape stage raises its world error by half, at 300 the simulated benchmark goes 175 -> 198 mm.
  //    "root_acceleration" (the pelvis alone) is there for recipes that smooth the depth and not the limbs;
  //  - the body pose is held by "pose_anchor", a Gaussian around the regressed pose of each frame, whenever it
  //    is free, because an unregularised 69-dof pose under 17 keypoints wanders (the thesis's small Adam steps
  //    hid that); SLAHMR's VPoser prior is added when VPoser weights are given ("pose_prior", with "latent_
  //    smoothness" in its own stage). The old zero-mean L2 on axis-angle pulled every joint to the T-pose. Its
  //    weight is 0.2: the pipeline's camera-local poses are per-frame fits whose errors the keypoints of
  //    neighbouring frames and the smoothing correct. Video benchmark seeds 0-3 at 1 -> 0.2: W-MPJPE100 270 /
  //    368 / 332 / 435 -> 263 / 360 / 319 / 440 mm, PA-MPJPE -1 to -2 mm, jitter -24%, speed error 4.8 / 13.9 /
  //    12.8 / 6.6 -> 5.9 / 10.3 / 11.6 / 6.2%. At 0.1 further on seeds 0-2 (260 / 353 / 314 mm) but seed 3's
  //    orbit then ended worse than the lift. The simulated benchmark and the 600-frame bench, whose regressed
  //    poses are the truth plus small noise, mostly lose by it (simulated W-MPJPE100 seeds 0-3 173 / 113 / 96 /
  //    85 -> 185 / 111 / 100 / 84 mm; bench world error 171 -> 189 mm). Measurements: README, "A lighter pose
  //    anchor".
  //  - planted feet are held 10x SLAHMR's weight (contact_velocity 1000), robustly (contact_velocity_sigma 2 cm
  //    per frame step): the contacts are right in about 4 of 5 frames, and held by plain squares a swing
  //    labelled planted dragged the body (at 1000 W-MPJPE100 +25 / +13 mm on the video benchmark's seeds 0 / 1);
  //    bounded, the feet slide a fifth less on video and a quarter less on the simulated benchmark;
  //  - "upright" (weight 3, from the root_orientation stage on) holds the spine near the person's ground normal:
  //    camera-local fits leave people upright in the camera rather than the world (leaning away from it by 5-11
  //    degrees more than the truth, 17-20 on high cameras). Heavier (10) it turns them further but stiffens
  //    real leans: the simulated benchmark, whose people lean -10..+17 degrees, loses 12 mm W-MPJPE100.
  //    Measurements: README, "Planted feet held robustly, bodies upright".
  //  - "heading_anchor" (weight 1, with upright) holds which way each person faces, about the ground normal, to
  //    the camera-local fit's heading: under one side's keypoints alone (a person half hidden by another) the
  //    root_orientation stage turned a simulated person 30-37 degrees off (the fit was 8 off). Simulated
  //    benchmark seeds 0-3, W-MPJPE100 181 / 115 / 96.7 / 86.4 -> 173 / 113 / 96.4 / 85.4 mm; video benchmark
  //    seeds 0-2 unchanged within 0.3 mm (its people are rarely half hidden). At 10 the video's jitter rose 6-8%
  //    (the fits' headings jitter). Measurements: README, "Which way a person faces".
  //  - "ray_acceleration" (weight 1000, every stage, not the world check) smooths the pelvis along each frame's
  //    line of sight only, where a monocular fit's depth swings; across it the images hold the body. On the video
  //    benchmark (seeds 0, 1, 2) it cut the people's speed error 9.3 / 18.4 / 16.9% -> 4.8 / 13.9 / 12.7% and
  //    W-MPJPE100 272 / 369 / 338 -> 270 / 368 / 332 mm; at 3000 further (5.3 / 10.5 / 10.8%) but the simulated
  //    benchmark, whose simulated depths do not swing, lost 6% (2% at 1000) and the 600-frame bench's world
  //    error 9% (6%). Measurements: README, "Depth smoothed along the line of sight".
  //  - "end_motion_anchor" (weight 100, every stage, not the world check) holds the steps of a track's open ends
  //    (frames before its first and after its last frame with well_seen_keypoints = 12 keypoints) to the lift's,
  //    in proportion to the keypoints each frame lacks: the smoothing alone continued the well-seen frames' motion
  //    at constant velocity into them. The simulated benchmark's static sequence (a person half hidden for its
  //    first 40 frames, drifting 0.5 m towards the camera): W-MPJPE100 220 -> 160 mm (Local 172); its panning
  //    125 -> 130 mm, seeds 1-3 within 1 mm. Anchoring the positions instead pulled a lift that is off by a
  //    constant depth away from the well-seen frames (seed 1's panning 131 -> 194 mm); anchoring every frame
  //    that lacks keypoints, not only the ends, pulled gaps towards their camera-frame interpolation (the
  //    panning and orbiting sequences 125 / 435 -> 163 / 502 mm). Measurements: README, "Open track ends".
  OptimizerConfig config;
  const double reprojection = 1e-3, shape = 0.5, accel = 30.0, pose = 0.04, anchor = 0.2, upright = 3.0,
               ray_accel = 1000.0, heading = 1.0, end_anchor = 100.0;
  using W = std::map<std::string, double>;
  const W contacts = {{"contact_velocity", 1000.0}, {"contact_height", 10.0}, {"ground_penetration", 100.0}};
  const W root_fit = {{"reprojection", reprojection}, {"joint_acceleration", accel}};
  W oriented = root_fit;
  oriented.insert({{"upright", upright}, {"heading_anchor", heading}});
  W contact_fit = oriented, shaped;
  contact_fit.insert(contacts.begin(), contacts.end());
  contact_fit.insert({"shape_prior", shape});
  shaped = contact_fit;
  W smoothed = shaped;
  smoothed.insert({{"pose_anchor", anchor}, {"pose_prior", pose}});
  W posed = smoothed, motion = smoothed;
  posed.insert({"latent_smoothness", 1.0});
  motion.insert({"motion_prior", 0.075});
  config.world_check = root_fit;
  config.world_check.insert(contacts.begin(), contacts.end());
  W root_stage = root_fit;  // the world check's terms are those of the world, without the depth prior
  for (W* w : {&root_stage, &oriented, &contact_fit, &shaped, &smoothed, &posed, &motion}) {
    w->insert({{"ray_acceleration", ray_accel}, {"end_motion_anchor", end_anchor}});
  }
  // Groups freed: transl, root, body, betas, scale, offset. The scale is freed nowhere (see above); a
  // configuration that frees it gets "scale_prior" to keep it within the estimate's uncertainty.
  config.stages = {
      {"root_translation", true, false, false, false, false, false, root_stage, 10},
      {"root_orientation", true, true, false, false, false, true, oriented, 20},
      {"contacts", true, true, false, false, false, true, contact_fit, 20},
      {"shape", true, true, false, true, false, true, shaped, 20},
      {"joint_smoothness", true, true, true, true, false, true, smoothed, 30},
      {"pose_prior", true, true, true, true, false, true, posed, 20},
      {"motion_prior", true, true, true, true, false, true, motion, 30},
  };
  return config;
}

const std::vector<std::string>& WorldOptimizer::BuiltinTerms() {
  static const std::vector<std::string> names = {
      "reprojection", "shape_prior",     "joint_smoothness", "joint_acceleration", "root_acceleration",
      "pose_anchor",  "pose_smoothness", "contact_velocity", "contact_height",     "scale_prior",
      "upright",      "ray_acceleration", "heading_anchor", "end_motion_anchor", "ground_penetration"};
  return names;
}

const std::vector<std::string>& WorldOptimizer::LearnedTerms() {
  static const std::vector<std::string> names = {"pose_prior", "latent_smoothness", "motion_prior"};
  return names;
}

WorldOptimizer::WorldOptimizer(const body::BodyModel* model, const body::KeypointRegressor* keypoint_regressor,
                               const body::KeypointRegressor* contact_regressor, OptimizerConfig config)
    : model_(model),
      keypoint_regressor_(keypoint_regressor),
      contact_regressor_(contact_regressor),
      joint_regressor_(std::make_unique<body::KeypointRegressor>(body::IdentityJointRegressor(*model))),
      config_(std::move(config)) {
  M3C_CHECK(config_.robust_sigma > 0 && config_.min_depth > 0 && config_.upright_sigma > 0)
      << "robust_sigma, min_depth and upright_sigma must be > 0";
  M3C_CHECK(config_.max_world_increase >= 0) << "max_world_increase must be >= 0";
  M3C_CHECK(config_.contact_velocity_sigma >= 0) << "contact_velocity_sigma must be >= 0";
  M3C_CHECK(config_.well_seen_keypoints >= 1)
      << "well_seen_keypoints must be >= 1, got " << config_.well_seen_keypoints;
  for (const auto& [term, weight] : config_.world_check) {
    M3C_CHECK(weight >= 0 && std::isfinite(weight)) << "world_check: weight of " << term << " must be finite and >= 0";
  }
  // Ceres aborts the process on num_threads < 1, so it is refused here.
  M3C_CHECK(config_.num_threads >= 1) << "num_threads must be >= 1, got " << config_.num_threads;
  M3C_CHECK(config_.minimizer == "m3c" || config_.minimizer == "ceres")
      << "minimizer must be \"m3c\" or \"ceres\", got \"" << config_.minimizer << "\"";
  for (const auto& stage : config_.stages) {
    M3C_CHECK(stage.max_iterations >= 0) << "stage " << stage.name << ": max_iterations must be >= 0";
    for (const auto& [term, weight] : stage.weights) {
      M3C_CHECK(weight >= 0 && std::isfinite(weight)) << "stage " << stage.name << ": weight of " << term
                                                      << " must be finite and >= 0";
    }
  }
}

void WorldOptimizer::AddTerm(const std::string& name, TermBuilder builder) {
  terms_.emplace_back(name, std::move(builder));
}

void WorldOptimizer::SetPosePrior(const nn::VPoser* vposer) {
  M3C_CHECK(vposer == nullptr || 3 * (model_->num_joints() - 1) >= 3 * vposer->num_joints())
      << "the VPoser prior covers " << vposer->num_joints() << " body joints; the body model has only "
      << model_->num_joints() - 1;
  pose_prior_ = vposer;
}

void WorldOptimizer::SetMotionPrior(const nn::HumorPrior* prior, double fps) {
  M3C_CHECK(fps > 0) << "fps must be > 0";
  motion_prior_ = prior;
  fps_ = fps;
}

OptimizerResult WorldOptimizer::Optimize(const std::vector<TrackInput>& tracks, const CameraInput& cameras) {
  const int J = model_->num_joints(), B = model_->num_betas(), K = keypoint_regressor_->num_keypoints();
  const int T = static_cast<int>(cameras.world_from_cam.size());
  M3C_CHECK(T > 0) << "no camera frames";
  M3C_CHECK(cameras.intrinsics.rows() == T && cameras.intrinsics.cols() == 4)
      << "intrinsics must be (T, 4) = (" << T << ", 4), got (" << cameras.intrinsics.rows() << ", "
      << cameras.intrinsics.cols() << ")";
  M3C_CHECK(cameras.intrinsics.allFinite() && (cameras.intrinsics.leftCols(2).array() > 0).all())
      << "intrinsics must be finite with positive focal lengths";
  for (const auto& pose : cameras.world_from_cam) M3C_CHECK(pose.allFinite()) << "world_from_cam contains NaN/Inf";
  M3C_CHECK(std::isfinite(cameras.initial_scale) && cameras.initial_scale > 0)
      << "initial camera scale must be finite and > 0, got " << cameras.initial_scale;
  M3C_CHECK(cameras.times.empty() || static_cast<int>(cameras.times.size()) == T)
      << "times must be empty or have one value per camera frame (" << T << "), got " << cameras.times.size();
  for (size_t t = 0; t < cameras.times.size(); ++t) {
    M3C_CHECK(std::isfinite(cameras.times[t]) && (t == 0 || cameras.times[t] > cameras.times[t - 1]))
        << "frame times must be finite and increasing (frame " << t << ")";
  }
  const util::ScopedBlasThreads blas_threads(config_.num_threads);  // results independent of the environment

  // Validate the tracks and copy their initial values into the parameter storage.
  State state;
  state.scale = cameras.initial_scale;
  for (size_t i = 0; i < tracks.size(); ++i) {
    const TrackInput& tr = tracks[i];
    const int n = static_cast<int>(tr.transl.rows());
    const std::string who = "track " + std::to_string(i) + ": ";
    M3C_CHECK(n >= 1) << who << "has no frames";
    M3C_CHECK(tr.first_frame >= 0 && tr.first_frame + n <= T)
        << who << "frames [" << tr.first_frame << ", " << tr.first_frame + n << ") outside the " << T
        << " camera frames";
    M3C_CHECK(tr.transl.cols() == 3 && tr.root.rows() == n && tr.root.cols() == 3 && tr.body.rows() == n &&
              tr.body.cols() == 3 * (J - 1))
        << who << "transl/root/body must be (n,3), (n,3), (n," << 3 * (J - 1) << ")";
    M3C_CHECK(tr.keypoints.rows() == n && tr.keypoints.cols() == 3 * K)
        << who << "keypoints must be (n, " << 3 * K << "), got (" << tr.keypoints.rows() << ", "
        << tr.keypoints.cols() << ")";
    M3C_CHECK(tr.betas.size() == B) << who << "betas must have " << B << " values";
    M3C_CHECK(AllFinite(tr.transl) && AllFinite(tr.root) && AllFinite(tr.body) && tr.betas.allFinite() &&
              AllFinite(tr.keypoints))
        << who << "inputs contain NaN/Inf (mark missing keypoints with confidence 0 instead)";
    const bool has_ground = tr.ground_normal.size() > 0;
    M3C_CHECK(!has_ground || (tr.ground_normal.rows() == n && tr.ground_normal.cols() == 3 &&
                              tr.ground_offset.size() == n && AllFinite(tr.ground_normal) &&
                              tr.ground_offset.allFinite()))
        << who << "ground_normal/ground_offset must be (n,3)/(n) and finite, or empty";
    M3C_CHECK(tr.contacts.size() == 0 ||
              (tr.contacts.rows() == n && contact_regressor_ &&
               tr.contacts.cols() == contact_regressor_->num_keypoints() && AllFinite(tr.contacts)))
        << who << "contacts must be (n, number of contact points) and finite, or empty";
    M3C_CHECK(tr.ground_contacts.size() == 0 ||
              (tr.contacts.size() > 0 && tr.ground_contacts.rows() == n &&
               tr.ground_contacts.cols() == tr.contacts.cols() && AllFinite(tr.ground_contacts)))
        << who << "ground_contacts must be empty or shaped as contacts (given too) and finite";
    M3C_CHECK(tr.contact_heights.size() == 0 ||
              (contact_regressor_ && tr.contact_heights.size() == contact_regressor_->num_keypoints() &&
               tr.contact_heights.allFinite()))
        << who << "contact_heights must be empty or one finite height per contact point";
    state.transl.push_back(tr.transl);
    state.root.push_back(tr.root);
    state.body.push_back(tr.body);
    state.betas.push_back(tr.betas);
  }

  Variables vars;
  std::unordered_map<const double*, Group> groups;
  for (size_t i = 0; i < tracks.size(); ++i) {
    const int n = static_cast<int>(state.transl[i].rows());
    vars.transl.emplace_back(), vars.root.emplace_back(), vars.body.emplace_back();
    for (int f = 0; f < n; ++f) {
      vars.transl[i].push_back(state.transl[i].row(f).data());
      vars.root[i].push_back(state.root[i].row(f).data());
      vars.body[i].push_back(state.body[i].row(f).data());
      groups[vars.transl[i][f]] = Group::kTransl;
      groups[vars.root[i][f]] = Group::kRoot;
      for (int k = 0; k + 1 < J; ++k) groups[vars.body[i][f] + 3 * k] = Group::kBody;  // per-joint blocks
    }
    vars.betas.push_back(state.betas[i].data());
    groups[vars.betas[i]] = Group::kBetas;
  }
  // Latent poses: z_t = the encoder mean of the initial pose, and the body blocks hold Decode(z_t) from here on.
  std::unique_ptr<LatentPoseDecoder> decoder;
  std::unordered_map<const double*, int> decoder_frame;  // body block -> decoder frame
  if (pose_prior_ != nullptr && config_.latent_pose) {
    decoder = std::make_unique<LatentPoseDecoder>(pose_prior_, 3 * (J - 1), config_.num_threads);
    const int L = LatentPoseDecoder::kLatentDim;
    std::vector<double> scale(L);
    state.latent.resize(tracks.size());  // sized once: the blocks point into it
    for (size_t i = 0; i < tracks.size(); ++i) {
      const int n = static_cast<int>(state.transl[i].rows());
      state.latent[i].resize(n, L);
      vars.latent.emplace_back();
      for (int f = 0; f < n; ++f) {
        double* z = state.latent[i].row(f).data();
        pose_prior_->Encode(state.body[i].row(f).data(), z, scale.data());
        vars.latent[i].push_back(z);
        groups[z] = Group::kLatent;
        decoder_frame[vars.body[i][f]] = decoder->AddFrame(z, vars.body[i][f]);
      }
    }
    decoder->DecodeAll(false);
  }
  // The body pose's parameter blocks in a problem: with latent poses the latents; else, in a stage that frees the
  // pose, one block of 3 per body joint (joint_blocks.h), so that a joint's terms touch only the joints that move
  // it; else (the pose constant, or only evaluated: the world check) the whole pose block. Set per problem before
  // its blocks are added.
  bool split_body = false;
  std::unordered_set<const double*> body_blocks;  // the whole body blocks
  for (const auto& track : vars.body) body_blocks.insert(track.begin(), track.end());
  // Adds a residual block whose cost takes whole body blocks (vars.body): with latent poses it is wrapped to
  // take the latents instead, with split_body to take the per-joint blocks of `movers` (MovingJoints; empty: all).
  auto add_moved_block = [&](ceres::Problem* problem, ceres::CostFunction* cost, std::vector<double*> blocks,
                             const std::vector<int>& movers) {
    std::vector<int> slots, frames;
    std::vector<double*> split;
    for (size_t k = 0; k < blocks.size(); ++k) {
      if (decoder) {
        const auto it = decoder_frame.find(blocks[k]);
        if (it == decoder_frame.end()) continue;
        slots.push_back(static_cast<int>(k));
        frames.push_back(it->second);
        blocks[k] = decoder->latent(it->second);
      } else if (split_body && body_blocks.count(blocks[k])) {
        slots.push_back(static_cast<int>(k));
      }
    }
    if (slots.empty()) return problem->AddResidualBlock(cost, nullptr, blocks);
    if (decoder) return problem->AddResidualBlock(new LatentBodyCost(cost, decoder.get(), std::move(slots), std::move(frames)), nullptr, blocks);
    auto* split_cost = new SplitBodyCost(cost, slots, movers);
    for (size_t k = 0; k < blocks.size(); ++k) {
      if (!body_blocks.count(blocks[k])) {
        split.push_back(blocks[k]);
        continue;
      }
      for (int j : split_cost->joints()) split.push_back(blocks[k] + 3 * (j - 1));
    }
    return problem->AddResidualBlock(split_cost, nullptr, split);
  };
  auto add_block = [&](ceres::Problem* problem, ceres::CostFunction* cost, std::vector<double*> blocks) {
    return add_moved_block(problem, cost, std::move(blocks), {});
  };
  vars.add_block = add_block;
  // The body joints that move the upright term's spine and the contact points: their terms' only body blocks. Not
  // for the keypoints: on their 15 moving joints (of 23) the 600-frame bench's joint_smoothness stage measured 2%
  // slower, though J^T J had fewer pairs (the reprojection on every joint keeps each frame's joints one dense
  // block for the sparse Cholesky; presumably its factorization is what lost).
  const std::vector<int> spine_movers =
      J == kSmplJoints ? MovingJoints(*model_, JointDifference(*model_, kPelvis, kNeck)) : std::vector<int>();
  const std::vector<int> contact_movers =
      contact_regressor_ ? MovingJoints(*model_, *contact_regressor_) : std::vector<int>();
  // The contact points as body joints (empty if the contact regressor is not a joint selection).
  const std::vector<int> contact_joints = contact_regressor_ ? SelectedJoints(*contact_regressor_) : std::vector<int>();
  // The world joints of every frame, evaluated once per evaluation point for the joint stencils; one set per
  // person, so that people whose problems are solved apart (below) evaluate their own side by side.
  std::vector<std::unique_ptr<SharedJoints>> shared_joints;  // [track], frame f of the track its frame f
  for (size_t i = 0; i < tracks.size(); ++i) {
    shared_joints.push_back(std::make_unique<SharedJoints>(model_, joint_regressor_.get(), config_.num_threads));
    for (size_t f = 0; f < vars.body[i].size(); ++f) {
      shared_joints[i]->AddFrame(vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.betas[i]);
    }
  }
  // The finite-difference stencil of a velocity (order 1: frames t, t+1) or acceleration (order 2: t..t+2) in
  // units of the median frame step: -1, 1 and 1, -2, 1 for equally spaced frames, else the differences at the
  // frames' times (CameraInput::times), so that a motion across a longer step is not smoothed as a faster one.
  double median_step = 0.0;
  if (!cameras.times.empty() && T > 1) {
    std::vector<double> steps(T - 1);
    for (int t = 0; t + 1 < T; ++t) steps[t] = cameras.times[t + 1] - cameras.times[t];
    std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
    median_step = steps[steps.size() / 2];
  }
  auto stencil_at = [&](int t, int order) -> std::vector<double> {
    if (median_step <= 0.0) return order == 1 ? std::vector<double>{-1.0, 1.0} : std::vector<double>{1.0, -2.0, 1.0};
    const double h = median_step, d1 = (cameras.times[t + 1] - cameras.times[t]) / h;
    if (order == 1) return {-1.0 / d1, 1.0 / d1};
    const double d2 = (cameras.times[t + 2] - cameras.times[t + 1]) / h;
    return {2.0 / (d1 * (d1 + d2)), -2.0 / (d1 * d2), 2.0 / (d2 * (d1 + d2))};
  };
  // A JointStencilCost over frames first..first+len(stencil)-1 of track i, on the per-joint blocks.
  auto add_joint_stencil = [&](ceres::Problem* problem, size_t i, int first, const std::vector<double>& stencil,
                               std::vector<int> joints, std::vector<double> weights, double sigma = 0.0) {
    const int F = static_cast<int>(stencil.size());
    std::vector<int> frames(F);
    for (int g = 0; g < F; ++g) frames[g] = first + g;
    auto* cost = new JointStencilCost(shared_joints[i].get(), std::move(frames), stencil, std::move(joints),
                                      std::move(weights), sigma);
    std::vector<double*> blocks;
    for (int g = first; g < first + F; ++g) {
      blocks.insert(blocks.end(), {vars.transl[i][g], vars.root[i][g]});
      for (int a : cost->ancestors()) blocks.push_back(vars.body[i][g] + 3 * (a - 1));
    }
    blocks.push_back(vars.betas[i]);
    problem->AddResidualBlock(cost, nullptr, blocks);
  };
  vars.scale = &state.scale;
  vars.offset = state.offset.data();
  groups[vars.scale] = Group::kScale;
  groups[vars.offset] = Group::kOffset;

  auto frame_camera = [&](int t) {
    FrameCamera cam;
    cam.cam_from_world_rotation = cameras.world_from_cam[t].topLeftCorner<3, 3>().transpose();
    cam.centre_in_world = cameras.world_from_cam[t].topRightCorner<3, 1>();
    cam.intrinsics = {cameras.intrinsics(t, 0), cameras.intrinsics(t, 1), cameras.intrinsics(t, 2),
                      cameras.intrinsics(t, 3)};
    return cam;
  };
  // The person's up direction at a track's frame f: its ground normal (camera coordinates) in the world.
  auto ground_up = [&](const TrackInput& tr, int f) -> Eigen::Vector3d {
    return frame_camera(tr.first_frame + f).cam_from_world_rotation.transpose() * tr.ground_normal.row(f).transpose();
  };

  // Per-point weights weight * p for contact probabilities p >= threshold at frame f; empty if none is in contact.
  auto contact_weights = [&](const RowMatrixXd& probabilities, int f, double weight) {
    std::vector<double> w(probabilities.cols());
    bool any = false;
    for (int c = 0; c < probabilities.cols(); ++c) {
      const double p = probabilities(f, c);
      w[c] = p >= config_.contact_threshold ? weight * p : 0.0;
      any = any || w[c] > 0;
    }
    return any ? w : std::vector<double>();
  };

  // The people whose blocks the builders add (a stage solved apart per person builds one problem per person).
  std::vector<char> in_part(tracks.size(), 1);
  // Builders of the built-in terms.
  auto add_builtin = [&](const std::string& term, double weight, ceres::Problem* problem) {
    for (size_t i = 0; i < tracks.size(); ++i) {
      if (!in_part[i]) continue;
      const TrackInput& tr = tracks[i];
      const int n = static_cast<int>(tr.transl.rows());
      if (term == "reprojection") {
        for (int f = 0; f < n; ++f) {
          Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> obs(K, 3);
          bool any = false;
          for (int k = 0; k < K; ++k) {
            obs.row(k) = tr.keypoints.block<1, 3>(f, 3 * k);
            if (obs(k, 2) < config_.min_confidence) obs(k, 2) = 0.0;
            any = any || obs(k, 2) > 0.0;
          }
          if (!any) continue;
          add_block(problem,
                    new ReprojectionCost(model_, keypoint_regressor_, frame_camera(tr.first_frame + f), obs, weight,
                                         config_.robust_sigma, config_.min_depth),
                    {vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.betas[i], vars.scale, vars.offset});
        }
      } else if (term == "scale_prior") {
        if (i > 0 || !(cameras.scale_sigma > 0) || !std::isfinite(cameras.scale_sigma)) continue;  // once
        problem->AddResidualBlock(new LogPriorCost(std::log(cameras.initial_scale), cameras.scale_sigma, weight),
                                  nullptr, vars.scale);
      } else if (term == "shape_prior") {
        problem->AddResidualBlock(new GaussianPriorCost(Eigen::VectorXd::Zero(B), weight * n), nullptr,
                                  vars.betas[i]);
      } else if (term == "pose_smoothness") {
        for (int f = 0; f + 1 < n; ++f) {
          add_block(problem, new BlockDifferenceCost(3 * (J - 1), weight), {vars.body[i][f], vars.body[i][f + 1]});
        }
      } else if (term == "heading_anchor" && tr.ground_normal.size() > 0) {
        for (int f = 0; f < n; ++f) {
          ceres::CostFunction* cost = HeadingAnchorCost::Create(ground_up(tr, f), tr.root.row(f).transpose(), weight);
          if (cost != nullptr) problem->AddResidualBlock(cost, nullptr, vars.root[i][f]);
        }
      } else if (term == "end_motion_anchor") {
        // A track's open ends: the frames before its first and after its last well-seen frame. Nothing holds
        // them but the smoothing, whose acceleration terms leave a straight line free: they would continue the
        // motion of the well-seen frames at constant velocity (a person half hidden for the first 40 frames
        // drifted 0.5 m along the line of sight). Each step there is held to the lift's, in proportion to the
        // keypoints the frame lacks; the step, not the position, so that a lift that is off by a constant depth
        // (which the well-seen frames correct) does not pull the end away from them.
        std::vector<int> seen(n, 0);
        int first_good = n, last_good = -1;
        for (int f = 0; f < n; ++f) {
          for (int k = 0; k < K; ++k) seen[f] += tr.keypoints(f, 3 * k + 2) >= config_.min_confidence;
          if (seen[f] >= config_.well_seen_keypoints) {
            first_good = std::min(first_good, f);
            last_good = f;
          }
        }
        for (int f = 0; f < n; ++f) {
          if (f >= first_good && f <= last_good) continue;  // outside, every frame lacks keypoints: lack > 0
          const double lack = 1.0 - static_cast<double>(seen[f]) / config_.well_seen_keypoints;
          // The neighbour towards the well-seen frames; past the last frame only where no frame is well seen.
          const int g = f < first_good ? f + 1 : f - 1;
          if (g >= n) continue;
          const Eigen::Vector3d step = (tr.transl.row(f) - tr.transl.row(g)).transpose();
          problem->AddResidualBlock(new BlockDifferenceCost(3, weight * lack, step), nullptr, vars.transl[i][g],
                                    vars.transl[i][f]);
        }
      } else if (term == "pose_anchor") {
        // A Gaussian around the initial (regressed) pose of each frame, not around the T-pose; per joint block
        // when the pose is (a Jacobian over all joints would be a 69 x 69 identity in J^T J).
        for (int f = 0; f < n; ++f) {
          if (!split_body) {
            add_block(problem, new GaussianPriorCost(tr.body.row(f).transpose(), weight), {vars.body[i][f]});
            continue;
          }
          for (int k = 0; k + 1 < J; ++k) {
            problem->AddResidualBlock(new GaussianPriorCost(tr.body.block<1, 3>(f, 3 * k).transpose(), weight),
                                      nullptr, vars.body[i][f] + 3 * k);
          }
        }
      } else if (term == "joint_smoothness" || term == "joint_acceleration" || term == "root_acceleration") {
        // root_acceleration: the pelvis joint alone (the whole body's depth along the camera ray, which the
        // images hold weakly, without stiffening the limbs).
        const bool pelvis_only = term == "root_acceleration";
        const int order = term == "joint_smoothness" ? 1 : 2, F = order + 1;
        std::vector<double> point_weights(J, pelvis_only ? 0.0 : weight);
        point_weights[0] = weight;
        for (int f = 0; split_body && f + F <= n; ++f) {  // a residual block per chain, on the shared joints
          const std::vector<double> stencil = stencil_at(tr.first_frame + f, order);
          if (pelvis_only) {
            add_joint_stencil(problem, i, f, stencil, {0}, {weight});
            continue;
          }
          for (const std::vector<int>& chain : shared_joints[i]->Chains()) {
            add_joint_stencil(problem, i, f, stencil, chain, std::vector<double>(chain.size(), weight));
          }
        }
        for (int f = 0; !split_body && f + F <= n; ++f) {  // whole pose blocks (or latents: every joint moves with them)
          std::vector<double*> blocks;
          for (int g = f; g < f + F; ++g) blocks.insert(blocks.end(), {vars.transl[i][g], vars.root[i][g], vars.body[i][g]});
          blocks.push_back(vars.betas[i]);
          add_block(problem, new PointStencilCost(model_, joint_regressor_.get(), stencil_at(tr.first_frame + f, order),
                                                  point_weights),
                    blocks);
        }
      } else if (term == "ray_acceleration") {
        // Each stencil's line of sight: from the middle frame's camera to the person's root at the stage's start.
        const Eigen::Vector3d offset = Eigen::Map<const Eigen::Vector3d>(vars.offset);
        for (int f = 0; f + 3 <= n; ++f) {
          const Eigen::Vector3d ray = Eigen::Map<const Eigen::Vector3d>(vars.transl[i][f + 1]) -
                                      (*vars.scale * frame_camera(tr.first_frame + f + 1).centre_in_world + offset);
          if (!(ray.norm() > 1e-9)) continue;
          problem->AddResidualBlock(new RayAccelerationCost(stencil_at(tr.first_frame + f, 2), ray.normalized(), weight),
                                    nullptr, vars.transl[i][f], vars.transl[i][f + 1], vars.transl[i][f + 2]);
        }
      } else if (term == "contact_velocity" && tr.contacts.size() > 0) {
        for (int f = 0; f + 1 < n; ++f) {
          const std::vector<double> w = contact_weights(tr.contacts, f, weight);
          if (w.empty()) continue;
          if (split_body && !contact_joints.empty()) {  // a residual block per planted joint, on the shared joints
            for (size_t c = 0; c < w.size(); ++c) {
              if (w[c] > 0) {
                add_joint_stencil(problem, i, f, stencil_at(tr.first_frame + f, 1), {contact_joints[c]}, {w[c]},
                                  config_.contact_velocity_sigma);
              }
            }
            continue;
          }
          add_block(problem, new PointStencilCost(model_, contact_regressor_, stencil_at(tr.first_frame + f, 1), w,
                                                  config_.contact_velocity_sigma),
                    {vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.transl[i][f + 1], vars.root[i][f + 1],
                     vars.body[i][f + 1], vars.betas[i]});
        }
      } else if (term == "upright" && tr.ground_normal.size() > 0 && J == kSmplJoints) {
        for (int f = 0; f < n; ++f) {
          add_moved_block(problem,
                          new UprightCost(model_, kPelvis, kNeck, ground_up(tr, f), weight, config_.upright_sigma),
                          {vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.betas[i]}, spine_movers);
        }
      } else if (term == "contact_height" && tr.contacts.size() > 0 && tr.ground_normal.size() > 0) {
        const RowMatrixXd& on_ground = tr.ground_contacts.size() > 0 ? tr.ground_contacts : tr.contacts;
        for (int f = 0; f < n; ++f) {
          const std::vector<double> w = contact_weights(on_ground, f, weight);
          if (w.empty()) continue;
          add_moved_block(problem,
                          new ContactHeightCost(model_, contact_regressor_, w, frame_camera(tr.first_frame + f),
                                                tr.ground_normal.row(f).transpose(), tr.ground_offset[f],
                                                config_.contact_height_tolerance, tr.contact_heights),
                          {vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.betas[i], vars.scale,
                           vars.offset},
                          contact_movers);
        }
      } else if (term == "ground_penetration" && contact_regressor_ && tr.ground_normal.size() > 0) {
        // Every frame, every contact point: none below its standing height (planted or not).
        const std::vector<double> w(contact_regressor_->num_keypoints(), weight);
        for (int f = 0; f < n; ++f) {
          add_moved_block(problem,
                          new ContactHeightCost(model_, contact_regressor_, w, frame_camera(tr.first_frame + f),
                                                tr.ground_normal.row(f).transpose(), tr.ground_offset[f], 0.0,
                                                tr.contact_heights, true),
                          {vars.transl[i][f], vars.root[i][f], vars.body[i][f], vars.betas[i], vars.scale,
                           vars.offset},
                          contact_movers);
        }
      }
    }
  };
  // HuMoR transitions over frames t-1..t+2 in each person's ground frame (its plane at the middle of the track,
  // moved to the world with the current camera scale), evaluated together by `batch` (the problem's evaluation
  // callback). The level c sits 100 nats below each block's start.
  auto add_motion_prior = [&](double weight, HumorTransitionBatch* batch, ceres::Problem* problem) {
    for (size_t i = 0; i < tracks.size(); ++i) {
      if (!in_part[i]) continue;
      const TrackInput& tr = tracks[i];
      const int n = static_cast<int>(tr.transl.rows());
      if (tr.ground_normal.size() == 0 || n < 4) continue;
      const int mid = n / 2;
      const FrameCamera cam = frame_camera(tr.first_frame + mid);
      const Eigen::Vector3d normal = cam.cam_from_world_rotation.transpose() * tr.ground_normal.row(mid).transpose();
      const double offset = tr.ground_offset[mid] / tr.ground_normal.row(mid).norm() -
                            normal.normalized().dot(state.scale * cam.centre_in_world + state.offset);
      Eigen::Matrix3d R;
      Eigen::Vector3d t;
      GroundFrame(normal.normalized(), offset, &R, &t);  // offset is already per unit normal
      batch->AddTrack(vars.transl[i], vars.root[i], vars.body[i], vars.betas[i], R, t);
    }
    const std::vector<double> nll = batch->Nll();
    for (int k = 0; k < batch->num_transitions(); ++k) {
      if (!std::isfinite(nll[k])) continue;
      add_block(problem, new HumorTransitionCost(batch, k, weight, nll[k] - 100.0), batch->Parameters(k));
    }
  };
  auto add_pose_prior = [&](const std::string& term, double weight, ceres::Problem* problem) {
    const std::vector<double> stencil = term == "pose_prior" ? std::vector<double>{1.0} : std::vector<double>{-1.0, 1.0};
    const int F = static_cast<int>(stencil.size());
    for (size_t i = 0; i < tracks.size(); ++i) {
      if (!in_part[i]) continue;
      for (int f = 0; f + F <= static_cast<int>(tracks[i].transl.rows()); ++f) {
        if (decoder) {  // the latents themselves: |z_t|^2 (a standard-normal prior) or |z_{t+1} - z_t|^2
          const int L = LatentPoseDecoder::kLatentDim;
          if (F == 1) {
            problem->AddResidualBlock(new GaussianPriorCost(Eigen::VectorXd::Zero(L), weight), nullptr, vars.latent[i][f]);
          } else {
            problem->AddResidualBlock(new BlockDifferenceCost(L, weight), nullptr, vars.latent[i][f], vars.latent[i][f + 1]);
          }
          continue;
        }
        add_block(problem, new VPoserLatentCost(pose_prior_, 3 * (J - 1), stencil, weight),
                  std::vector<double*>(vars.body[i].begin() + f, vars.body[i].begin() + f + F));
      }
    }
  };
  auto is_builtin = [](const std::string& term) {
    const auto& names = BuiltinTerms();
    return std::find(names.begin(), names.end(), term) != names.end();
  };
  auto find_extra = [&](const std::string& term) -> const TermBuilder* {
    for (const auto& [name, builder] : terms_)
      if (name == term) return &builder;
    return nullptr;
  };
  // Adds a term's blocks; false when the term is unknown here (e.g. a motion prior with no weights loaded).
  auto add_term = [&](const std::string& term, double weight, HumorTransitionBatch* humor_batch,
                      ceres::Problem* problem) {
    if (is_builtin(term)) {
      add_builtin(term, weight, problem);
      return true;
    }
    if ((term == "pose_prior" || term == "latent_smoothness") && pose_prior_ != nullptr) {
      add_pose_prior(term, weight, problem);
      return true;
    }
    if (term == "motion_prior" && humor_batch != nullptr) {
      add_motion_prior(weight, humor_batch, problem);
      return true;
    }
    if (const TermBuilder* builder = find_extra(term)) {
      (*builder)(problem, vars, weight);
      return true;
    }
    return false;
  };
  auto cost_of = [&](ceres::Problem* problem) {
    if (problem->NumResidualBlocks() == 0) return 0.0;
    double cost = 0.0;
    ceres::Problem::EvaluateOptions options;
    options.num_threads = config_.num_threads;
    if (!EvaluateSerial(problem, options, &cost, nullptr)) return std::nan("");
    return cost;
  };
  // The cost of each term's residual blocks within a stage's problem (its own levels and weights) and their sum,
  // from one evaluation of the residuals: a block without a loss function costs half its squared norm. (A term
  // at a time, the reports cost two evaluations per term and stage.)
  auto terms_cost = [&](ceres::Problem* problem, const std::vector<std::vector<ceres::ResidualBlockId>>& terms,
                        double* total) {
    std::vector<double> costs(terms.size(), 0.0);
    ceres::Problem::EvaluateOptions options;
    options.num_threads = config_.num_threads;
    for (const auto& ids : terms) options.residual_blocks.insert(options.residual_blocks.end(), ids.begin(), ids.end());
    *total = 0.0;
    if (options.residual_blocks.empty()) return costs;  // an empty list would mean every block to Ceres
    std::vector<double> residuals;
    if (!EvaluateSerial(problem, options, total, &residuals)) {
      *total = std::nan("");
      return std::vector<double>(terms.size(), std::nan(""));
    }
    size_t at = 0;
    for (size_t k = 0; k < terms.size(); ++k) {
      for (const ceres::ResidualBlockId id : terms[k]) {
        M3C_CHECK(problem->GetLossFunctionForResidualBlock(id) == nullptr)
            << "a residual block of the stage's term " << k + 1 << " has a Ceres loss function; the optimizer's "
            << "terms put robustness into their residuals instead (as ReprojectionCost does)";
        const int n = problem->GetCostFunctionForResidualBlock(id)->num_residuals();
        for (int r = 0; r < n; ++r) costs[k] += 0.5 * residuals[at + r] * residuals[at + r];
        at += n;
      }
    }
    return costs;
  };

  // The world check: every term of config_.world_check over all people and frames, built once over the state's
  // parameter memory and evaluated at the current state before the first stage and after each solve.
  StageCallback world_check_callback(decoder.get(), {}, nullptr, util::ScopedOpenMpLevels::Current());
  ceres::Problem::Options world_check_options;
  world_check_options.evaluation_callback = &world_check_callback;
  ceres::Problem world_check(world_check_options);
  split_body = false;
  for (const auto& [term, weight] : config_.world_check) {
    if (weight > 0 && is_builtin(term)) add_builtin(term, weight, &world_check);
  }
  double world_now = cost_of(&world_check);

  OptimizerResult result;
  // The objective of the last stage that ran (its terms with their weights, then its free groups) and its name: a
  // stage whose objective is the same would only go on iterating it. Without network weights the recipe's
  // pose_prior and motion_prior stages are such repeats of joint_smoothness (their learned terms unavailable).
  std::map<std::string, double> last_terms;
  std::vector<bool> last_free;
  std::string last_name;
  for (const StageConfig& stage : config_.stages) {
    StageReport report;
    report.name = stage.name;
    if (result.stopped_early) {
      report.status = "skipped";
      report.message = "an earlier stage failed";
      result.stages.push_back(report);
      continue;
    }
    const auto start = std::chrono::steady_clock::now();
    const bool with_humor =
        motion_prior_ != nullptr && stage.weights.count("motion_prior") && stage.weights.at("motion_prior") > 0;
    bool extra_terms = false;  // a term added by AddTerm: its builder sees every person
    for (const auto& [term, weight] : stage.weights) extra_terms = extra_terms || (weight > 0 && find_extra(term));
    const bool shared_free = (stage.scale && !cameras.static_camera) || (stage.offset && config_.optimize_offset);
    // People share nothing in a stage that holds the camera scale and offset: each person's problem is solved on
    // its own, side by side (a part's result is that of optimising the person alone). J^T J is formed and
    // factorized on one thread, and with one problem over everyone the 600-frame bench's joint-smoothness stage
    // took the same time on one thread as on two (27.4 / 26.3 s, Ceres's solver); as two parts, 12.8 s. Each part
    // stops on its own convergence and iteration cap. Not with VPoser latents (one decoder for everyone) nor with the HuMoR batch: split, its
    // stage ran 84 -> 59 s but the call's peak memory rose 934 -> 984 MiB (bench/optimizer_memory.py), the
    // parts' network batches overlapping the other's factorization.
    std::vector<std::vector<size_t>> part_people;
    if (!shared_free && !extra_terms && !decoder && !with_humor && tracks.size() > 1) {
      for (size_t i = 0; i < tracks.size(); ++i) part_people.push_back({i});
    } else {
      part_people.emplace_back();
      for (size_t i = 0; i < tracks.size(); ++i) part_people.back().push_back(i);
    }
    const int P = static_cast<int>(part_people.size());
    const int part_threads = std::max(1, config_.num_threads / P);
    split_body = !decoder && stage.body;
    // Per part: the motion prior's batch and the callback are declared before the problem, which must not
    // outlive them.
    struct Part {
      std::unique_ptr<HumorTransitionBatch> humor;
      std::unique_ptr<StageCallback> callback;
      std::unique_ptr<ceres::Problem> problem;
      std::vector<std::vector<ceres::ResidualBlockId>> term_blocks;  // per reported term, its residual blocks
      ceres::Solver::Summary summary;
    };
    std::vector<Part> parts(P);
    std::vector<std::string> missing;
    for (int p = 0; p < P; ++p) {
      Part& part = parts[p];
      std::fill(in_part.begin(), in_part.end(), 0);
      std::vector<SharedJoints*> joints;
      for (size_t i : part_people[p]) {
        in_part[i] = 1;
        if (split_body) joints.push_back(shared_joints[i].get());
      }
      if (with_humor) part.humor = std::make_unique<HumorTransitionBatch>(model_, motion_prior_, fps_, part_threads);
      part.callback = std::make_unique<StageCallback>(decoder.get(), std::move(joints), part.humor.get(),
                                                      part_threads > 1 ? util::ScopedOpenMpLevels::Current() : 0);
      ceres::Problem::Options problem_options;
      problem_options.evaluation_callback = part.callback.get();
      part.problem = std::make_unique<ceres::Problem>(problem_options);
      for (const auto& [term, weight] : stage.weights) {
        if (weight <= 0) continue;
        const int first = part.problem->NumResidualBlocks();
        if (!add_term(term, weight, part.humor.get(), part.problem.get())) {
          if (p == 0) missing.push_back(term);
          continue;
        }
        std::vector<ceres::ResidualBlockId> ids;
        part.problem->GetResidualBlocks(&ids);  // in the order they were added
        part.term_blocks.emplace_back(ids.begin() + first, ids.end());
        if (p == 0) report.terms.push_back({term, 0.0, 0.0});
      }
    }
    std::fill(in_part.begin(), in_part.end(), 1);
    for (const auto& term : missing) report.message += (report.message.empty() ? "" : "; ") + term + " unavailable";
    int residual_blocks = 0;
    for (const Part& part : parts) residual_blocks += part.problem->NumResidualBlocks();
    if (residual_blocks == 0) {
      report.status = "skipped";
      report.message += (report.message.empty() ? "" : "; ") + std::string("no active residuals");
      result.stages.push_back(report);
      continue;
    }
    std::map<std::string, double> terms;
    for (const auto& [term, weight] : stage.weights) {
      if (weight > 0 && std::find(missing.begin(), missing.end(), term) == missing.end()) terms[term] = weight;
    }
    const std::vector<bool> free = {stage.transl, stage.root, stage.body, stage.betas, stage.scale, stage.offset};
    if (!last_name.empty() && terms == last_terms && free == last_free) {
      report.status = "skipped";
      report.terms.clear();
      report.message += (report.message.empty() ? "" : "; ") + ("the same objective as stage " + last_name);
      result.stages.push_back(report);
      continue;
    }
    last_terms = terms;
    last_free = free;
    last_name = stage.name;
    for (Part& part : parts) {
      std::vector<double*> blocks;
      part.problem->GetParameterBlocks(&blocks);
      for (double* block : blocks) {
        const Group g = groups.at(block);
        const bool free = (g == Group::kTransl && stage.transl) || (g == Group::kRoot && stage.root) ||
                          (g == Group::kBody && stage.body && !decoder) || (g == Group::kLatent && stage.body) ||
                          (g == Group::kBetas && stage.betas) ||
                          (g == Group::kScale && stage.scale && !cameras.static_camera) ||
                          (g == Group::kOffset && stage.offset && config_.optimize_offset);
        if (!free) part.problem->SetParameterBlockConstant(block);
        if (g == Group::kScale && free) part.problem->SetParameterLowerBound(block, 0, 1e-3);
      }
    }
    // Each term's cost and the objective, summed over the parts.
    auto stage_costs = [&](double* total) {
      std::vector<double> costs(report.terms.size(), 0.0);
      *total = 0.0;
      for (Part& part : parts) {
        double part_total = 0.0;
        const std::vector<double> part_costs = terms_cost(part.problem.get(), part.term_blocks, &part_total);
        for (size_t k = 0; k < costs.size(); ++k) costs[k] += part_costs[k];
        *total += part_total;
      }
      return costs;
    };
    const State checkpoint = state;
    report.parts = P;  // set only for a stage that is solved
    report.world_before = world_now;
    std::vector<double> term_costs = stage_costs(&report.objective_before);
    for (size_t k = 0; k < report.terms.size(); ++k) report.terms[k].before = term_costs[k];

    std::string failure;
    if (!std::isfinite(report.objective_before)) {
      failure = "the objective is not finite at the stage's start";
    } else {
      auto solve = [&](Part& part) {
        if (part.problem->NumResidualBlocks() == 0) return;
        if (config_.minimizer == "m3c" && LmUnsupported(*part.problem).empty()) {
          LmOptions options;
          options.max_iterations = stage.max_iterations;
          options.num_threads = part_threads;
          options.evaluation_callback = part.callback.get();
          options.callbacks.push_back(part.callback.get());
          SolveLm(options, part.problem.get(), &part.summary);
          return;
        }
        ceres::Solver::Options options;
        options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
        options.max_num_iterations = stage.max_iterations;
        options.num_threads = part_threads;
        options.logging_type = ceres::SILENT;
        options.callbacks.push_back(part.callback.get());
        SolveSerial(options, part.problem.get(), &part.summary);
      };
      if (P == 1) {
        solve(parts[0]);
      } else {  // a pool of num_threads workers over the parts; the BLAS one thread per part
        const util::ScopedBlasThreads part_blas(part_threads);
        std::atomic<int> next{0};
        std::vector<std::exception_ptr> errors(P);
        auto work = [&]() {
          for (int p = next++; p < P; p = next++) {
            try {
              solve(parts[p]);
            } catch (...) {
              errors[p] = std::current_exception();
            }
          }
        };
        std::vector<std::thread> workers;
        for (int w = 1; w < std::min(P, config_.num_threads); ++w) workers.emplace_back(work);
        work();
        for (std::thread& worker : workers) worker.join();
#ifdef __GLIBC__
        // A worker's solve allocates its Jacobian, J^T J and factor in that thread's malloc arena, which keeps
        // them when freed; a later stage on this thread would not reuse that memory (without this trim the 600 x 2
        // bench's call with the HuMoR stage peaked at 1013 MiB instead of 934, bench/optimizer_memory.py).
        malloc_trim(0);
#endif
        for (const std::exception_ptr& error : errors) {
          if (error) std::rethrow_exception(error);
        }
      }
      report.objective_after = 0.0;
      for (const Part& part : parts) {
        if (part.problem->NumResidualBlocks() == 0) continue;
        report.iterations = std::max(report.iterations, static_cast<int>(part.summary.iterations.size()) - 1);
        report.objective_after += part.summary.final_cost;
        if (part.summary.termination_type == ceres::FAILURE && failure.empty()) {
          failure = "solver failure: " + part.summary.message;
        }
      }
      if (failure.empty() && (!state.AllFinite() || !std::isfinite(report.objective_after))) {
        failure = "non-finite values after the solve";
      } else if (failure.empty() && report.objective_after > report.objective_before * (1.0 + 1e-9) + 1e-12) {
        failure = "the objective increased";  // beyond round-off
      }
    }
    if (decoder) decoder->DecodeAll(false);  // the body blocks may hold a rejected trial point's pose
    report.world_after = failure.empty() ? cost_of(&world_check) : report.world_before;
    std::string worse;  // the stage's own objective fell, but the world got worse: revert it and go on
    if (failure.empty() && !(report.world_after <= report.world_before * (1.0 + config_.max_world_increase))) {
      std::ostringstream msg;
      msg << "reverted: the world check rose from " << report.world_before << " to " << report.world_after;
      worse = msg.str();
    }
    if (!failure.empty() || !worse.empty()) {
      state = checkpoint;
      if (decoder) decoder->DecodeAll(false);
      report.status = "reverted";
      report.message += (report.message.empty() ? "" : "; ") + (failure.empty() ? worse : failure);
      report.objective_after = report.objective_before;
      report.world_after = report.world_before;
      if (!failure.empty()) result.stopped_early = true;
    } else {
      report.status = "ok";
    }
    world_now = report.world_after;
    double unused_total;
    term_costs = stage_costs(&unused_total);
    for (size_t k = 0; k < report.terms.size(); ++k) report.terms[k].after = term_costs[k];
    report.scale = state.scale;
    report.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    result.stages.push_back(report);
  }

  for (size_t i = 0; i < tracks.size(); ++i) {
    result.tracks.push_back({state.transl[i], state.root[i], state.body[i], state.betas[i],
                             state.latent.empty() ? RowMatrixXd() : state.latent[i]});
  }
  result.scale = state.scale;
  result.offset = state.offset;
  return result;
}

}  // namespace m3c::motion
