"""The staged world optimizer on a synthetic scene with ground truth: two people walking (feet planted), a
handheld camera whose VO trajectory is off by an unknown scale, noisy keypoints with dropped frames and an
occlusion gap, and an initial lift with depth, orientation, pose and shape errors."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.joint_names import CONTACT_JOINTS
from m3c.body.synthetic import make_synthetic_model
from m3c.eval.scenes import make_scene
from m3c.motion import Cameras, OptimizerConfig, StageSpec, optimize, track_joints
from m3c.motion.scale import estimate_scale, rescaled
from m3c.perception.contacts import contact_rest_heights
from m3c.vo.scale import FEET_MODEL_SIGMA, PERSON_SIZE_SIGMA


@pytest.fixture(scope="module")
def model():
    return BodyModel(make_synthetic_model())


@pytest.fixture(scope="module")
def scene(model):
    return make_scene(model, num_people=2, num_frames=60, seed=3, vo_scale=2.0)


@pytest.fixture(scope="module")
def start(model, scene):
    """As the pipeline: M3C's scale estimator on the lift, then the optimizer from there."""
    return rescaled(scene.init, scene.cameras_vo, estimate_scale(model, scene.init, scene.cameras_vo))


@pytest.fixture(scope="module")
def result(model, start):
    return optimize(model, *start)


def world_mpjpe(model, tracks, truth):
    """Mean joint error in metres in the ground-truth world, no alignment."""
    return float(np.mean([np.linalg.norm(track_joints(model, a) - track_joints(model, b), axis=-1).mean()
                          for a, b in zip(tracks, truth)]))


def test_recovers_world_motion_and_camera_scale(model, scene, start, result):
    tracks, cameras = start
    # The lift's depth errors (15% per person) bias the planted feet; the stated uncertainty covers it, and
    # beyond the source's model error and the people's size error its sampling part is small.
    assert abs(np.log(cameras.initial_scale / scene.vo_scale)) < 2 * cameras.scale_sigma
    assert cameras.scale_sigma < np.hypot(FEET_MODEL_SIGMA, PERSON_SIZE_SIGMA) + 0.05
    before = world_mpjpe(model, tracks, scene.truth)  # the lift at the estimated scale
    after = world_mpjpe(model, result.tracks, scene.truth)
    assert after < 0.6 * before, (before, after)
    # 0.245 m at pose_anchor 1, 0.251 at the recipe's 0.2: this scene's lift poses are the truth plus small noise,
    # which a heavier anchor keeps (README, "A lighter pose anchor").
    assert after < 0.27  # metres
    assert result.camera_scale == cameras.initial_scale  # the recipe frees the scale nowhere
    # The optimised cameras are the true ones (up to the estimated scale).
    cams = result.world_cameras(cameras).world_from_cam()
    assert np.abs(cams[:, :3, 3] - scene.cameras_true.world_from_cam[:, :3, 3]).max() < 0.05 * 6.0


def test_bone_lengths_are_consistent_over_each_track(model, scene, result):
    """Bone-length consistency holds by construction (one betas per track; SMPL's posed joints move rigidly with
    their parents), so the optimizer has no residual for it: every bone keeps one length over the frames, while
    the shape itself was optimised."""
    parents = model.parents
    for track, init in zip(result.tracks, scene.init):
        joints = track_joints(model, track)
        bones = np.linalg.norm(joints[:, 1:] - joints[:, parents[1:]], axis=-1)  # n x (J-1)
        np.testing.assert_allclose(bones, np.broadcast_to(bones[0], bones.shape), rtol=0, atol=1e-9)
        assert np.abs(np.asarray(track.betas) - np.asarray(init.betas)).max() > 1e-6


def test_every_stage_lowers_its_objective_and_reports_terms(result):
    assert [s.name for s in result.stages] == [s.name for s in OptimizerConfig.default().stages]
    assert not result.stopped_early
    for stage in result.stages:
        if stage.name in ("pose_prior", "motion_prior"):
            # Without network weights these stages would repeat joint_smoothness's objective: skipped, and said.
            assert stage.status == "skipped" and "the same objective as stage joint_smoothness" in stage.message
            continue
        assert stage.status == "ok", (stage.name, stage.message)
        assert stage.objective_after <= stage.objective_before + 1e-9, stage.name
        assert stage.terms and all(np.isfinite(v).all() for v in stage.terms.values())
        # The per-term costs add up to the stage's objective, before and after.
        assert sum(b for b, _ in stage.terms.values()) == pytest.approx(stage.objective_before, rel=1e-9)
        assert sum(a for _, a in stage.terms.values()) == pytest.approx(stage.objective_after, rel=1e-9)
        # No accepted stage makes the world check worse by more than max_world_increase.
        assert stage.world_after <= stage.world_before * 1.05, stage.name
    # The motion prior is not configured: reported, not silently dropped.
    assert "motion_prior unavailable" in result.stages[-1].message


def test_people_are_solved_apart_where_they_share_nothing(model, start, result):
    """With the camera scale held (the recipe), each person's problem is solved on its own, side by side: the
    people's results are those of optimising each person alone, and the stage reports the parts. A stage that
    frees the scale couples everyone: one problem."""
    tracks, cameras = start
    ran = [s for s in result.stages if s.status == "ok"]
    assert ran and all(s.parts == len(tracks) for s in ran)
    # One thread: the parts run one after the other, each as the one-person run does (same threads and
    # BLAS).
    config = dataclasses.replace(OptimizerConfig.default(), num_threads=1)
    config.stages = config.stages[:5]  # through joint_smoothness
    both = optimize(model, tracks, cameras, config)
    singles = [optimize(model, [track], cameras, config) for track in tracks]
    for i, alone in enumerate(singles):
        assert [s.status for s in alone.stages] == [s.status for s in both.stages] == ["ok"] * 5
        for name in ("transl", "root_orient", "body_pose", "betas"):
            np.testing.assert_array_equal(getattr(both.tracks[i], name), getattr(alone.tracks[0], name), name)
    # The stage objectives are the people's sums.
    for k, stage in enumerate(both.stages):
        people = sum(a.stages[k].objective_after for a in singles)
        assert stage.objective_after == pytest.approx(people, rel=1e-12)
        assert stage.iterations == max(a.stages[k].iterations for a in singles)
    # Threads change nothing but the time: two workers over the two parts.
    two = optimize(model, tracks, cameras, dataclasses.replace(config, num_threads=2))
    for a, b in zip(two.tracks, both.tracks):
        np.testing.assert_allclose(a.transl, b.transl, rtol=0, atol=1e-9)
    scaled = dataclasses.replace(config, stages=[StageSpec("scaled", ["transl", "scale"],
                                                           {"reprojection": 1e-3, "scale_prior": 1.0}, 5)])
    assert optimize(model, tracks, cameras, scaled).stages[0].parts == 1


def test_m3c_minimizer_takes_ceres_steps(model, start, result):
    """The default minimizer (Ceres's Levenberg-Marquardt iteration with M3C's assembly of the normal equations,
    motion/lm_solver.h) against ceres::Solve on the recipe: every stage the same iterations, objective and
    result (round-off apart: J^T J is summed in another order)."""
    tracks, cameras = start
    assert OptimizerConfig.default().minimizer == "m3c"
    reference = optimize(model, tracks, cameras, dataclasses.replace(OptimizerConfig.default(), minimizer="ceres"))
    assert [s.status for s in result.stages] == [s.status for s in reference.stages]
    for ours, theirs in zip(result.stages, reference.stages):
        assert ours.iterations == theirs.iterations, ours.name
        assert ours.objective_before == pytest.approx(theirs.objective_before, rel=1e-12), ours.name
        assert ours.objective_after == pytest.approx(theirs.objective_after, rel=1e-9), ours.name
    for a, b in zip(result.tracks, reference.tracks):
        for name in ("transl", "root_orient", "body_pose", "betas"):
            np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=0, atol=1e-6, err_msg=name)
    with pytest.raises(ValueError, match="minimizer must be one of"):
        optimize(model, tracks, cameras, dataclasses.replace(OptimizerConfig.default(), minimizer="lbfgs"))


def test_m3c_minimizer_with_learned_priors(model, tmp_path):
    """The same with the learned terms' evaluation callbacks: HuMoR's batched transitions and VPoser latents
    (random weights in the official layouts)."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel
    from m3c.models.vposer import VPoserV2

    torch.manual_seed(3)
    export_weights(tmp_path, humor=HumorModel().eval(), vposer=VPoserV2().double().eval(), dtype="float64")
    scene = make_scene(model, num_people=2, num_frames=10, seed=4)
    config = OptimizerConfig.default()
    for stage in config.stages:
        stage.max_iterations = min(stage.max_iterations, 6)
    runs = [optimize(model, scene.init, scene.cameras_vo, dataclasses.replace(config, minimizer=m), fps=scene.fps,
                     motion_prior=tmp_path / "humor.safetensors", pose_prior=tmp_path / "vposer.safetensors")
            for m in ("m3c", "ceres")]
    ours, theirs = runs
    assert [s.status for s in ours.stages] == [s.status for s in theirs.stages]
    assert {"pose_prior", "motion_prior"} <= {s.name for s in ours.stages if s.status == "ok"}
    for a, b in zip(ours.stages, theirs.stages):
        assert a.iterations == b.iterations, a.name
        assert a.objective_after == pytest.approx(b.objective_after, rel=1e-9), a.name
    for a, b in zip(ours.tracks, theirs.tracks):
        np.testing.assert_allclose(a.body_pose, b.body_pose, rtol=0, atol=1e-6)
        np.testing.assert_allclose(a.transl, b.transl, rtol=0, atol=1e-6)


def test_static_camera_keeps_the_scale(model, scene):
    cams = Cameras(scene.cameras_vo.world_from_cam, scene.cameras_vo.intrinsics, static=True, initial_scale=1.5)
    config = OptimizerConfig.default()
    config.stages = config.stages[:3]
    res = optimize(model, scene.init, cams, config)
    assert res.camera_scale == 1.5


def test_config_yaml_round_trip_and_validation(tmp_path):
    config = OptimizerConfig.default()
    path = tmp_path / "optimizer.yaml"
    path.write_text(config.to_yaml())
    assert OptimizerConfig.from_yaml(path) == config
    with pytest.raises(ValueError, match="unknown terms"):
        OptimizerConfig(stages=[StageSpec("x", ["transl"], {"reprojektion": 1.0})]).to_core()
    with pytest.raises(ValueError, match="unknown parameter groups"):
        OptimizerConfig(stages=[StageSpec("x", ["translation"], {"reprojection": 1.0})]).to_core()
    with pytest.raises(ValueError, match="unknown optimizer settings"):
        OptimizerConfig.from_yaml("robust_sigmaa: 3\n")
    for bad in ("0", "2.5", "true"):  # a keypoint count: an integer >= 1
        with pytest.raises(ValueError, match="well_seen_keypoints must be an integer"):
            OptimizerConfig.from_yaml(f"well_seen_keypoints: {bad}\n")
    assert OptimizerConfig.from_yaml("well_seen_keypoints: 8\n").to_core().well_seen_keypoints == 8


def test_bad_inputs_raise_clear_errors(model, scene):
    bad = scene.init[0]
    broken = type(bad)(**{**bad.__dict__, "transl": np.full_like(bad.transl, np.nan)})
    with pytest.raises(ValueError, match="NaN/Inf"):
        optimize(model, [broken], scene.cameras_vo)
    with pytest.raises(ValueError, match=r"intrinsics must have shape \(4,\) or \(T=60, 4\)"):
        optimize(model, scene.init, Cameras(scene.cameras_vo.world_from_cam, np.ones(3)))
    late = type(bad)(**{**bad.__dict__, "first_frame": 10})
    with pytest.raises(ValueError, match="outside the 60 camera frames"):
        optimize(model, [late], scene.cameras_vo)
    stuck = dataclasses.replace(scene.cameras_vo, times=np.r_[np.arange(30), np.arange(29, 59)] / 30.0)
    with pytest.raises(ValueError, match="increasing frame times"):
        optimize(model, scene.init, stuck)


def test_frame_times_reach_the_smoothness_terms(model, start):
    """Equally spaced times change nothing; doubling every other step changes the acceleration term by the
    finite differences at those times (its cost before the stage, as the C++ test checks in detail)."""
    tracks, cameras = start
    config = OptimizerConfig.default()
    config.stages = [dataclasses.replace(next(s for s in config.stages if s.name == "joint_smoothness"),
                                         max_iterations=0)]
    config.world_check = {}
    T = len(cameras.world_from_cam)

    def acceleration(times):
        res = optimize(model, tracks, dataclasses.replace(cameras, times=times), config)
        return res.stages[0].terms["joint_acceleration"][0]

    plain = acceleration(None)
    assert acceleration(np.arange(T) / 30.0) == pytest.approx(plain, rel=1e-12)
    uneven = np.cumsum(np.r_[0.0, np.where(np.arange(T - 1) % 2, 2.0, 1.0)]) / 30.0
    assert not acceleration(uneven) == pytest.approx(plain, rel=1e-3)


def test_motion_prior_stage_with_exported_humor(model, tmp_path):
    """HuMoR with random weights in the official layout, exported to safetensors, drives the motion-prior term."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel

    torch.manual_seed(0)
    export_weights(tmp_path, humor=HumorModel().eval(), dtype="float64")
    scene = make_scene(model, num_people=1, num_frames=12, seed=5)
    config = OptimizerConfig.default()
    motion = next(s for s in config.stages if s.name == "motion_prior")
    motion.max_iterations = 3
    config.stages = [config.stages[0], motion]
    res = optimize(model, scene.init, scene.cameras_vo, config, motion_prior=tmp_path / "humor.safetensors",
                   fps=scene.fps)
    stage = res.stages[-1]
    assert stage.status == "ok", stage.message
    assert "motion_prior unavailable" not in stage.message
    before, after = stage.terms["motion_prior"]
    assert np.isfinite(before) and np.isfinite(after)
    assert stage.objective_after <= stage.objective_before
    with pytest.raises(FileNotFoundError, match="missing.safetensors"):
        optimize(model, scene.init, scene.cameras_vo, config, motion_prior=tmp_path / "missing.safetensors")


def _randomise_batch_norms(model, torch):
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.BatchNorm1d):
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.2, 0.2)
                m.running_mean.uniform_(-0.3, 0.3)
                m.running_var.uniform_(0.5, 2.0)
    return model.requires_grad_(False)


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_vposer_pose_prior_matches_torch(model, tmp_path, version):
    """Axis-angle poses under the VPoser prior (random weights in the official layout, exported to safetensors):
    the C++ terms' values equal the torch encoder's 1/2 w |z|^2 and 1/2 w |z_{t+1} - z_t|^2 before and after."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.vposer import VPoserV1, VPoserV2

    torch.manual_seed(4)
    vposer = _randomise_batch_norms((VPoserV1 if version == "v1" else VPoserV2)().double().eval(), torch)
    export_weights(tmp_path, vposer=vposer, dtype="float64")
    scene = make_scene(model, num_people=1, num_frames=8, seed=5)
    w_prior, w_smooth = 0.04, 0.5
    config = OptimizerConfig(stages=[StageSpec("vposer", ["body"], {"reprojection": 1e-3, "pose_prior": w_prior,
                                                                    "latent_smoothness": w_smooth}, 5),
                                     StageSpec("prior_alone", ["body"], {"pose_prior": w_prior}, 5)],
                             latent_pose=False)
    res = optimize(model, scene.init, scene.cameras_vo, config, pose_prior=tmp_path / "vposer.safetensors")
    stage = res.stages[0]
    assert all(s.status == "ok" and "unavailable" not in s.message for s in res.stages), stage.message

    def expected(body_pose):
        with torch.no_grad():
            z = vposer.encode(torch.as_tensor(np.asarray(body_pose)[:, :21]))[0].numpy()
        return 0.5 * w_prior * (z ** 2).sum(), 0.5 * w_smooth * (np.diff(z, axis=0) ** 2).sum()

    prior, smooth = expected(scene.init[0].body_pose)
    assert stage.terms["pose_prior"][0] == pytest.approx(prior, rel=1e-9)
    assert stage.terms["latent_smoothness"][0] == pytest.approx(smooth, rel=1e-9)
    prior, _ = expected(res.tracks[0].body_pose)  # after the last stage
    assert res.stages[1].terms["pose_prior"][1] == pytest.approx(prior, rel=1e-9)
    assert stage.objective_after < stage.objective_before
    # Alone, the prior's gradient drives the latents towards 0.
    before, after = res.stages[1].terms["pose_prior"]
    assert after < 0.5 * before


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_latent_pose_variables(model, tmp_path, version):
    """With VPoser weights the body pose is optimised as VPoser latents (SLAHMR): they start at the encoder mean
    of the initial pose, the returned pose is their decoding (torch's decode_axis_angle), the hand joints keep
    their values, and pose_prior / latent_smoothness are |z|^2 and |dz|^2 of the latents themselves."""
    torch = pytest.importorskip("torch")
    from m3c.models.export import export_weights
    from m3c.models.vposer import VPoserV1, VPoserV2

    torch.manual_seed(6)
    vposer = _randomise_batch_norms((VPoserV1 if version == "v1" else VPoserV2)().double().eval(), torch)
    export_weights(tmp_path, vposer=vposer, dtype="float64")
    scene = make_scene(model, num_people=1, num_frames=8, seed=5)
    w_prior, w_smooth = 0.04, 0.5
    config = OptimizerConfig(stages=[StageSpec("latent", ["body"], {"reprojection": 1e-3, "pose_prior": w_prior,
                                                                    "latent_smoothness": w_smooth}, 5)])
    assert config.latent_pose
    res = optimize(model, scene.init, scene.cameras_vo, config, pose_prior=tmp_path / "vposer.safetensors")
    stage = res.stages[0]
    assert stage.status == "ok" and stage.iterations > 0, stage.message
    assert stage.objective_after < stage.objective_before
    z = res.latent_poses[0]
    assert z.shape == (8, 32)
    init = np.asarray(scene.init[0].body_pose)
    with torch.no_grad():
        z0 = vposer.encode(torch.as_tensor(init[:, :21]))[0].numpy()
        decoded = vposer.decode_axis_angle(torch.as_tensor(z)).numpy()
    body = res.tracks[0].body_pose
    np.testing.assert_allclose(body[:, :21], decoded, atol=1e-9)
    np.testing.assert_array_equal(body[:, 21:], init[:, 21:])
    assert stage.terms["pose_prior"][0] == pytest.approx(0.5 * w_prior * (z0 ** 2).sum(), rel=1e-9)
    assert stage.terms["pose_prior"][1] == pytest.approx(0.5 * w_prior * (z ** 2).sum(), rel=1e-9)
    assert stage.terms["latent_smoothness"][1] == pytest.approx(0.5 * w_smooth * (np.diff(z, axis=0) ** 2).sum(),
                                                                rel=1e-9)
    # Axis-angle variables return no latents.
    config.latent_pose = False
    res = optimize(model, scene.init, scene.cameras_vo, config, pose_prior=tmp_path / "vposer.safetensors")
    assert res.latent_poses == [None]


def test_pose_anchor_holds_the_initial_pose_not_the_t_pose(model, scene):
    """Without VPoser the pose prior is unavailable (reported); the anchor's minimum is the initial pose."""
    config = OptimizerConfig(stages=[StageSpec("anchor", ["body"], {"pose_anchor": 1.0, "pose_prior": 0.04}, 5)])
    res = optimize(model, scene.init, scene.cameras_vo, config)
    stage = res.stages[0]
    assert "pose_prior unavailable" in stage.message
    assert stage.terms["pose_anchor"] == (0.0, 0.0)
    for a, b in zip(res.tracks, scene.init):
        np.testing.assert_array_equal(a.body_pose, b.body_pose)


def test_scale_of_a_camera_that_barely_translates_is_unmeasured(model, scene):
    """A camera that only turns (its VO centre still up to millimetre noise) gives the planted feet no
    baseline: the estimator measures nothing (or an uncertainty far above the walking camera's)."""
    rng = np.random.default_rng(0)
    world_from_cam = np.array(scene.cameras_vo.world_from_cam, copy=True)
    world_from_cam[:, :3, 3] = world_from_cam[0, :3, 3] + 1e-3 * rng.normal(size=(len(world_from_cam), 3))
    turning = estimate_scale(model, scene.init, Cameras(world_from_cam, scene.cameras_vo.intrinsics))
    walking = estimate_scale(model, scene.init, scene.cameras_vo)
    # Compared by the sampling error (the bootstrap): the planted-feet model error is the same for both.
    walking_sigma = walking.observations[0].detail["bootstrap_sigma"]
    assert walking_sigma < 0.2
    assert turning.sigma is None or turning.observations[0].detail["bootstrap_sigma"] > 5 * walking_sigma, turning


def spine_lean_degrees(model, track, up):
    """Angle (n,) between each frame's pelvis-to-neck vector and `up` (3,)."""
    joints = track_joints(model, track)
    spine = joints[:, 12] - joints[:, 0]
    return np.degrees(np.arccos(spine @ up / np.linalg.norm(spine, axis=1)))


def test_upright_turns_a_leaning_body_upright(model, scene):
    """The true walkers turned 12 degrees about their pelvis, across the camera's view (the lean a camera-local
    fit leaves): the upright term, against the ground normal each track carries in camera coordinates, turns them
    back upright, where the truth is within 5 degrees. A body bent over (its spine far off the vertical) pulls
    with a bounded force."""
    up = np.array([0.0, 1.0, 0.0])
    tilt = Rotation.from_rotvec(np.radians(12.0) * np.array([1.0, 0.0, 0.0]))
    leaned = []
    for truth, init in zip(scene.truth, scene.init):
        root = (tilt * Rotation.from_rotvec(truth.root_orient)).as_rotvec()
        leaned.append(dataclasses.replace(truth, keypoints=init.keypoints, root_orient=root,
                                          ground_normal=init.ground_normal, ground_offset=init.ground_offset))
        # The root turns about the pelvis joint: the pelvis stays where it was.
        np.testing.assert_allclose(track_joints(model, leaned[-1])[:, 0], track_joints(model, truth)[:, 0], atol=1e-9)
    truth_lean = np.concatenate([spine_lean_degrees(model, t, up) for t in scene.truth])
    start_lean = np.concatenate([spine_lean_degrees(model, t, up) for t in leaned])
    assert truth_lean.max() < 5.0 and start_lean.min() > 7.0, (truth_lean.max(), start_lean.min())
    config = OptimizerConfig(stages=[StageSpec("upright", ["root"], {"upright": 10.0}, 30)])
    res = optimize(model, leaned, scene.cameras_true, config)
    assert res.stages[0].status == "ok", res.stages[0].message
    # The term alone (it leaves the heading free): every spine along the ground normal, within the walking pose's
    # own lean of the truth.
    lean = np.concatenate([spine_lean_degrees(model, t, up) for t in res.tracks])
    assert lean.max() < 0.5, lean.max()
    # Robust: a spine bent 80 degrees costs at most weight * sigma^2 / 2 per frame, however far it leans.
    bowed = [dataclasses.replace(t, root_orient=(Rotation.from_rotvec(np.radians(80.0) * np.array([1.0, 0.0, 0.0]))
                                                 * Rotation.from_rotvec(t.root_orient)).as_rotvec()) for t in scene.truth]
    bowed = [dataclasses.replace(b, keypoints=i.keypoints, ground_normal=i.ground_normal,
                                 ground_offset=i.ground_offset) for b, i in zip(bowed, scene.init)]
    config = OptimizerConfig(upright_sigma=0.2, stages=[StageSpec("upright", ["root"], {"upright": 10.0}, 0)])
    cost = optimize(model, bowed, scene.cameras_true, config).stages[0].terms["upright"][0]
    frames = sum(t.num_frames for t in bowed)
    assert 0.8 * 0.5 * 10.0 * 0.2 ** 2 * frames < cost < 0.5 * 10.0 * 0.2 ** 2 * frames


def test_a_stage_repeating_the_objective_before_it_is_skipped(model, scene):
    """A stage whose objective (terms that can be built, their weights, the free groups) is the last run stage's
    would only go on iterating it: it is skipped. An unavailable learned term does not make a stage different; a
    changed weight or another free group does."""
    base = {"reprojection": 1e-3, "joint_acceleration": 30.0}
    stages = [StageSpec("a", ["transl", "root"], base, 3),
              StageSpec("again", ["transl", "root"], dict(base), 3),
              StageSpec("prior", ["transl", "root"], {**base, "motion_prior": 0.075}, 3),
              StageSpec("heavier", ["transl", "root"], {**base, "joint_acceleration": 60.0}, 3),
              StageSpec("posed", ["transl", "root", "body"], {**base, "joint_acceleration": 60.0}, 3)]
    res = optimize(model, scene.init, scene.cameras_vo, OptimizerConfig(stages=stages))
    status = {s.name: (s.status, s.message) for s in res.stages}
    assert status["again"] == ("skipped", "the same objective as stage a")
    assert status["prior"][0] == "skipped" and "motion_prior unavailable" in status["prior"][1]
    assert "the same objective as stage a" in status["prior"][1]
    assert status["heavier"][0] == "ok" and status["posed"][0] == "ok"
    assert not res.stopped_early and res.stages[1].terms == {}



def test_ray_acceleration_steadies_a_depth_the_images_swing(model, scene):
    """People moving steadily (the walkers' poses on straight constant-velocity paths) whose images swing in size
    as a stride does, as if each frame's body slid along its line of sight by 12 cm at 2 Hz (the keypoints are
    those of the swung bodies): under the keypoints and joint acceleration the depth keeps much of the swing;
    ray_acceleration takes out more of it, and the motion across the lines of sight stays where it was."""
    from m3c.camera import world_to_image

    rng = np.random.default_rng(5)
    cams, regressor = scene.cameras_true, model.coco17_regressor()
    steady, seen, rays = [], [], []
    for truth in scene.truth:
        n = truth.num_frames
        frames = truth.first_frame + np.arange(n)
        line = np.stack([np.arange(n), np.ones(n)], axis=1)
        truth = dataclasses.replace(truth, transl=line @ np.linalg.lstsq(line, truth.transl, rcond=None)[0])
        ray = truth.transl - cams.world_from_cam[frames, :3, 3]
        ray /= np.linalg.norm(ray, axis=1, keepdims=True)
        swung = truth.transl + 0.12 * np.sqrt(2) * np.sin(2 * np.pi * 2.0 * np.arange(n) / 30.0 + 1.0)[:, None] * ray
        points = model.keypoints(regressor, np.concatenate([truth.root_orient[:, None], truth.body_pose], axis=1),
                                 truth.betas, swung)
        keypoints = np.full((n, 17, 3), 0.9)
        for i, f in enumerate(frames):
            keypoints[i, :, :2] = world_to_image(points[i], cams.world_from_cam[f], cams.intrinsics)[0] + \
                rng.normal(size=(17, 2))
        steady.append(truth)
        seen.append(dataclasses.replace(truth, keypoints=keypoints, transl=swung))
        rays.append(ray)

    def errors(tracks):
        d = [t.transl - truth.transl for t, truth in zip(tracks, steady)]
        along = np.concatenate([(e * r).sum(axis=1) for e, r in zip(d, rays)])
        across = np.concatenate([np.linalg.norm(e - (e * r).sum(axis=1, keepdims=True) * r, axis=1) for e, r in zip(d, rays)])
        return np.sqrt(np.mean(along ** 2)), np.sqrt(np.mean(across ** 2))

    base = {"reprojection": 1e-3, "joint_acceleration": 30.0}
    runs = {}
    for name, weights in (("keypoints", base), ("ray", {**base, "ray_acceleration": 1000.0})):
        res = optimize(model, seen, cams, OptimizerConfig(stages=[StageSpec("depth", ["transl"], weights, 50)]))
        assert res.stages[0].status == "ok", res.stages[0].message
        runs[name] = errors(res.tracks)
    (plain_along, plain_across), (ray_along, ray_across) = runs["keypoints"], runs["ray"]
    assert plain_along > 0.04 and ray_along < 0.8 * plain_along, runs
    assert ray_across < plain_across + 0.001, runs


def test_end_motion_anchor_holds_a_hidden_track_start(model):
    """A person stands still, unseen, for 20 frames, then walks in view. The acceleration terms alone continue the
    walk backwards into the unseen frames at constant velocity; end_motion_anchor holds their steps to the lift's
    (here the truth's), so the hidden start stays where the person stood."""
    scene = make_scene(model, num_people=1, num_frames=60, seed=5, drop_rate=0.0, depth_error=0.0)
    truth, hidden = scene.truth[0], 20
    transl, body = truth.transl.copy(), truth.body_pose.copy()
    transl[:hidden], body[:hidden] = transl[hidden], body[hidden]
    keypoints = scene.init[0].keypoints.copy()
    keypoints[:hidden, :, 2] = 0.0
    still = dataclasses.replace(truth, keypoints=keypoints, transl=transl, body_pose=body)
    cameras = dataclasses.replace(scene.cameras_vo, initial_scale=scene.vo_scale)  # the lift is the metric truth
    errors = {}
    for weight in (0.0, 100.0):
        weights = {"reprojection": 1e-3, "joint_acceleration": 30.0, "ray_acceleration": 1000.0,
                   "end_motion_anchor": weight}
        config = OptimizerConfig.default()
        config.stages, config.world_check = [StageSpec("root", ["transl"], weights, 20)], {}
        res = optimize(model, [still], cameras, config)
        assert res.stages[0].status == "ok", res.stages[0].message
        error = np.linalg.norm(res.tracks[0].transl - transl, axis=1)
        errors[weight] = (error[:hidden].max(), error[hidden:].max())
    # Without it the hidden frames end 0.81 m off (the walk continued backwards), with it 0.12 m; the seen frames
    # (0.21 m off either way: the smoothing rounds the instant start of the walk) are not moved by it.
    assert errors[0.0][0] > 5 * errors[100.0][0] and errors[100.0][0] < 0.15, errors
    assert abs(errors[100.0][1] - errors[0.0][1]) < 0.01, errors



def test_feet_stand_on_the_floor_not_through_it(model, scene):
    """The scene's walkers stand with the lower foot's joint at its standing height above the ground (the sole on
    it). Sunk 8 cm, ground_penetration lifts each frame just enough that no contact joint is below its standing
    height; contact_height holds the planted feet at their standing heights (within its tolerance), not at the
    sole's plane."""
    def heights(tracks):  # (frames, 4) contact joints' heights above their standing heights, all tracks
        return np.concatenate([track_joints(model, t)[:, list(CONTACT_JOINTS), 1] - contact_rest_heights(model, t.betas)
                               for t in tracks])

    truth = [dataclasses.replace(t, ground_normal=i.ground_normal, ground_offset=i.ground_offset)
             for t, i in zip(scene.truth, scene.init)]  # planes in the cameras, as the optimizer takes them
    assert heights(truth)[:, 2:].min(axis=1) == pytest.approx(0.0, abs=1e-9)  # the lower foot on the floor
    sunk = [dataclasses.replace(t, transl=t.transl - [0.0, 0.08, 0.0]) for t in truth]
    for term in ("ground_penetration", "contact_height"):
        config = OptimizerConfig.default()
        config.contact_height_tolerance = 0.0
        config.stages, config.world_check = [StageSpec(term, ["transl"], {term: 100.0}, 30)], {}
        res = optimize(model, sunk, scene.cameras_true, config)
        assert res.stages[0].status == "ok", res.stages[0].message
        lift = np.concatenate([r.transl[:, 1] - s.transl[:, 1] for r, s in zip(res.tracks, sunk)])
        if term == "ground_penetration":
            # Nothing under the floor, and no frame lifted further than that takes (8 cm, or more where the
            # synthetic model's ankle dips under its standing height).
            assert heights(res.tracks).min() > -1e-3
            needed = np.maximum(0.0, -heights(sunk).min(axis=1))
            np.testing.assert_allclose(lift, needed, atol=2e-3)
            assert needed.min() >= 0.08 - 1e-9
        else:
            # The planted feet, sunk 3.5-8 cm under their standing heights, back at them (within 1 cm); nothing
            # pushes a body down.
            planted = np.concatenate([t.contacts for t in truth]) > 0.5
            assert heights(sunk)[planted].max() < -0.03
            assert np.abs(heights(res.tracks)[planted]).max() < 0.01 and lift.min() > -1e-6
