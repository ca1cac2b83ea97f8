"""The C++ optimizer's stage objective against an independent torch implementation (m3c.testing.torch_objective):
each term's cost at perturbed states, the HuMoR term with its levels after Ceres steps, and the torch L-BFGS
baseline of the benchmark."""

import dataclasses

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from m3c.body import BodyModel  # noqa: E402
from m3c.body.reference import lbs  # noqa: E402
from m3c.body.synthetic import make_synthetic_model  # noqa: E402
from m3c.eval.scenes import make_scene  # noqa: E402
from m3c.motion import Cameras, OptimizerConfig, StageSpec, optimize  # noqa: E402
from m3c.testing.torch_objective import StageObjective, TorchPoser, TorchState, run_lbfgs  # noqa: E402

RTOL = 1e-10


@pytest.fixture(scope="module")
def model():
    return BodyModel(make_synthetic_model())


@pytest.fixture(scope="module")
def scene(model):
    return make_scene(model, num_people=2, num_frames=10, seed=3)


def perturbed(tracks, seed, ground_scale=1.0):
    """Tracks moved to a random state around the scene's start; ground planes optionally given with non-unit
    normals (the same planes)."""
    rng = np.random.default_rng(seed)
    out = []
    for t in tracks:
        out.append(dataclasses.replace(
            t, transl=t.transl + 0.05 * rng.normal(size=t.transl.shape),
            root_orient=t.root_orient + 0.05 * rng.normal(size=t.root_orient.shape),
            body_pose=t.body_pose + 0.1 * rng.normal(size=t.body_pose.shape),
            betas=t.betas + 0.2 * rng.normal(size=t.betas.shape),
            ground_normal=ground_scale * t.ground_normal, ground_offset=ground_scale * t.ground_offset))
    return out


def single_stage(spec: StageSpec, iterations: int, **settings) -> OptimizerConfig:
    config = OptimizerConfig.default()
    for key, value in settings.items():
        setattr(config, key, value)
    # The scale stays fixed (the default recipe frees it nowhere; test_scale_prior_after_ceres_steps frees it).
    config.stages = [StageSpec(spec.name, [g for g in spec.free if g != "scale"], dict(spec.weights), iterations)]
    return config


def torch_terms(objective, tracks, scale):
    with torch.no_grad():
        return {k: float(v) for k, v in objective.terms(TorchState.from_tracks(tracks, scale)).items()}


def test_poser_matches_numpy_lbs(model):
    rng = np.random.default_rng(0)
    pose = 0.4 * rng.normal(size=(3, model.num_joints, 3))
    betas = rng.normal(size=(3, model.num_betas))
    transl = rng.normal(size=(3, 3))
    ids = [0, 17, 100, model.num_vertices - 1]
    verts, joints = lbs(model.data, pose, betas, transl)
    poser = TorchPoser(model, ids)
    j, v = poser(*(torch.as_tensor(a) for a in (pose, betas, transl)))
    np.testing.assert_allclose(j.numpy(), joints, rtol=0, atol=1e-12)
    np.testing.assert_allclose(v.numpy(), verts[:, ids], rtol=0, atol=1e-12)


@pytest.mark.parametrize("stage_name", [s.name for s in OptimizerConfig.default().stages])
def test_default_stage_terms_match_torch(model, scene, stage_name):
    spec = next(s for s in OptimizerConfig.default().stages if s.name == stage_name)
    config = single_stage(spec, 0)
    tracks = perturbed(scene.init, seed=len(stage_name))
    cameras = dataclasses.replace(scene.cameras_vo, initial_scale=1.7)
    stage = optimize(model, tracks, cameras, config).stages[0]
    assert stage.status == "ok" and stage.iterations == 0, stage.message
    expected = torch_terms(StageObjective(model, tracks, cameras, config, config.stages[0]), tracks, 1.7)
    # The motion prior has no weights here: both leave it out.
    assert sorted(stage.terms) == sorted(expected)
    for term, (before, _) in stage.terms.items():
        assert before == pytest.approx(expected[term], rel=RTOL, abs=1e-12), term
        # Every term is active at this state, so the comparison says something; the anchors are zero at the start
        # (their centres are the tracks' own) and are compared after Ceres steps below.
        assert before > 0 or term in ("pose_anchor", "end_motion_anchor"), term
    assert stage.objective_before == pytest.approx(sum(expected.values()), rel=RTOL)


def test_contact_height_reads_the_ground_contacts(model, scene):
    """Given ground_contacts, contact_height pulls those points onto the ground and contact_velocity still holds
    the planted ones: both terms equal torch's, and contact_height differs from its value on the contacts."""
    weights = {"contact_velocity": 40.0, "contact_height": 30.0}
    config = single_stage(StageSpec("contacts", ["transl", "root"], weights), 0, contact_height_tolerance=0.0)
    tracks = perturbed(scene.init, seed=4)
    rng = np.random.default_rng(4)
    with_ground = [dataclasses.replace(t, ground_contacts=np.where(rng.uniform(size=t.contacts.shape) < 0.5,
                                                                   t.contacts, 0.0)) for t in tracks]
    terms = {}
    for label, tr in (("contacts", tracks), ("ground", with_ground)):
        stage = optimize(model, tr, scene.cameras_vo, config).stages[0]
        expected = torch_terms(StageObjective(model, tr, scene.cameras_vo, config, config.stages[0]), tr, 1.0)
        for term, (before, _) in stage.terms.items():
            assert before == pytest.approx(expected[term], rel=RTOL), (label, term)
        terms[label] = {term: before for term, (before, _) in stage.terms.items()}
    assert terms["ground"]["contact_velocity"] == terms["contacts"]["contact_velocity"] > 0
    assert 0 < terms["ground"]["contact_height"] < 0.9 * terms["contacts"]["contact_height"]
    with pytest.raises(ValueError, match="ground_contacts"):
        bad = [dataclasses.replace(t, ground_contacts=t.contacts[:-1]) for t in tracks]
        optimize(model, bad, scene.cameras_vo, config)

def test_every_term_with_other_weights_and_settings(model, scene):
    """All built-in terms with unequal weights, another robust scale and confidence cut, non-unit ground normals."""
    weights = {"reprojection": 3e-3, "shape_prior": 0.7, "pose_anchor": 0.3, "pose_smoothness": 2.0,
               "joint_smoothness": 5.0, "joint_acceleration": 7.0, "root_acceleration": 90.0, "contact_velocity": 40.0,
               "contact_height": 30.0, "upright": 4.0, "ray_acceleration": 300.0}
    config = single_stage(StageSpec("all", ["transl", "root", "body", "betas"], weights), 0, robust_sigma=20.0,
                          min_confidence=0.8, contact_threshold=0.3, contact_height_tolerance=0.02,
                          upright_sigma=0.05, contact_velocity_sigma=0.03)
    tracks = perturbed(scene.init, seed=11, ground_scale=2.5)
    cameras = dataclasses.replace(scene.cameras_vo, initial_scale=0.8)
    stage = optimize(model, tracks, cameras, config).stages[0]
    expected = torch_terms(StageObjective(model, tracks, cameras, config, config.stages[0]), tracks, 0.8)
    assert sorted(stage.terms) == sorted(weights)
    for term, (before, _) in stage.terms.items():
        assert before == pytest.approx(expected[term], rel=RTOL), term
    # The pelvis's acceleration along the lines of sight is a part of its whole acceleration.
    assert 0 < expected["ray_acceleration"] / 300.0 < expected["root_acceleration"] / 90.0
    # A change of a setting changes the torch value: the settings are read, not defaults.
    other = single_stage(config.stages[0], 0, robust_sigma=100.0)
    other_terms = torch_terms(StageObjective(model, tracks, cameras, other, other.stages[0]), tracks, 0.8)
    assert other_terms["reprojection"] > 1.5 * expected["reprojection"]
    other = single_stage(config.stages[0], 0, upright_sigma=0.5, contact_velocity_sigma=0.0)
    other_terms = torch_terms(StageObjective(model, tracks, cameras, other, other.stages[0]), tracks, 0.8)
    assert other_terms["upright"] > 1.5 * expected["upright"]
    assert other_terms["contact_velocity"] > 1.5 * expected["contact_velocity"]


def test_scale_prior_after_ceres_steps(model, scene):
    """The scale prior is zero at its centre (the start), so the terms are compared after Ceres moved the scale."""
    spec = StageSpec("scale", ["transl", "scale"], {"reprojection": 1e-3, "contact_height": 10.0,
                                                     "scale_prior": 0.01})
    config = OptimizerConfig.default()
    config.stages = [dataclasses.replace(spec, max_iterations=3)]
    config.world_check = {}
    tracks = perturbed(scene.init, seed=5)
    cameras = dataclasses.replace(scene.cameras_vo, initial_scale=1.7, scale_sigma=0.5)  # a weak prior: it moves
    res = optimize(model, tracks, cameras, config)
    stage = res.stages[0]
    assert stage.status == "ok" and abs(np.log(res.camera_scale / 1.7)) > 1e-3, (stage.message, res.camera_scale)
    objective = StageObjective(model, tracks, cameras, config, config.stages[0])
    expected = torch_terms(objective, res.tracks, res.camera_scale)
    assert expected["scale_prior"] > 0
    for term, (_, after) in stage.terms.items():
        assert after == pytest.approx(expected[term], rel=RTOL), term


@pytest.fixture(scope="module")
def humor(tmp_path_factory):
    from m3c.models.export import export_weights
    from m3c.models.humor import HumorModel

    torch.manual_seed(0)
    net = HumorModel().eval()
    folder = tmp_path_factory.mktemp("humor")
    export_weights(folder, humor=net, dtype="float64")
    return net.double(), folder / "humor.safetensors"


def test_motion_prior_stage_objective_after_ceres_steps(model, scene, humor):
    """The HuMoR term's reported cost at the start is its level offset only (weight * 100 / 2 per block), so it is
    compared where it says something: at the state Ceres reaches, against torch with the start's levels."""
    net, path = humor
    spec = next(s for s in OptimizerConfig.default().stages if s.name == "motion_prior")
    config = single_stage(spec, 10)
    tracks = perturbed(scene.init, seed=5, ground_scale=2.5)
    res = optimize(model, tracks, scene.cameras_vo, config, motion_prior=path, fps=scene.fps)
    stage = res.stages[0]
    assert stage.status == "ok", stage.message
    objective = StageObjective(model, tracks, scene.cameras_vo, config, config.stages[0], motion_prior=net,
                               fps=scene.fps)
    start = torch_terms(objective, tracks, 1.0)
    end = torch_terms(objective, res.tracks, 1.0)
    blocks = 2 * (10 - 3)
    assert start["motion_prior"] == pytest.approx(0.5 * spec.weights["motion_prior"] * 100.0 * blocks, rel=RTOL)
    assert stage.objective_before == pytest.approx(sum(start.values()), rel=RTOL)
    assert stage.objective_after < 0.7 * stage.objective_before  # Ceres moved: the check below is not at the start
    assert end["motion_prior"] != pytest.approx(start["motion_prior"], rel=1e-4)
    assert stage.objective_after == pytest.approx(sum(end.values()), rel=RTOL)
    # The report's per-term costs are those of the stage's own blocks (the start's levels), before and after.
    for term, (before, after) in stage.terms.items():
        assert before == pytest.approx(start[term], rel=RTOL, abs=1e-12), term
        assert after == pytest.approx(end[term], rel=1e-8, abs=1e-12), term


@pytest.mark.parametrize("version", ["v1", "v2"])
def test_pose_terms_after_ceres_steps(model, scene, tmp_path, version):
    """pose_anchor and the VPoser terms (random weights in the official layout, exported) at the state Ceres
    reaches from a perturbed start: the anchor pulls towards the tracks' own pose, so it is zero at the start."""
    from m3c.models.export import export_weights
    from m3c.models.vposer import VPoserV1, VPoserV2

    torch.manual_seed(1)
    vposer = (VPoserV1 if version == "v1" else VPoserV2)().double().eval()
    export_weights(tmp_path, vposer=vposer, dtype="float64")
    # With a pose prior the body pose is one block per frame: the stencil terms take their unsplit path.
    weights = {"reprojection": 1e-3, "pose_anchor": 2.0, "pose_prior": 0.3, "latent_smoothness": 0.7,
               "joint_acceleration": 5.0, "root_acceleration": 40.0}
    config = single_stage(StageSpec("pose", ["transl", "body"], weights), 5, latent_pose=False)  # torch: axis-angle
    tracks = perturbed(scene.init, seed=2)
    res = optimize(model, tracks, scene.cameras_vo, config, pose_prior=tmp_path / "vposer.safetensors")
    stage = res.stages[0]
    assert stage.status == "ok" and stage.iterations > 0, stage.message
    objective = StageObjective(model, tracks, scene.cameras_vo, config, config.stages[0], pose_prior=vposer)
    start, end = torch_terms(objective, tracks, 1.0), torch_terms(objective, res.tracks, 1.0)
    assert sorted(stage.terms) == sorted(weights) and start["pose_anchor"] == 0.0 < end["pose_anchor"]
    for term, (before, after) in stage.terms.items():
        assert before == pytest.approx(start[term], rel=RTOL, abs=1e-12), term
        assert after == pytest.approx(end[term], rel=1e-8), term
    assert stage.objective_after == pytest.approx(sum(end.values()), rel=1e-8)


def test_heading_anchor_after_ceres_steps(model, scene):
    """heading_anchor holds each frame's facing direction about the ground normal to the tracks' own: zero at the
    start, so both sides are compared at the state Ceres reaches from perturbed tracks under the scene's keypoints."""
    weights = {"reprojection": 1e-3, "heading_anchor": 5.0, "upright": 3.0}
    config = single_stage(StageSpec("heading", ["transl", "root"], weights), 5)
    config.world_check = {}  # the stage is judged here by its terms, not reverted by the world check
    tracks = perturbed(scene.init, seed=6, ground_scale=2.5)
    res = optimize(model, tracks, scene.cameras_vo, config)
    stage = res.stages[0]
    assert stage.status == "ok" and stage.iterations > 0, stage.message
    objective = StageObjective(model, tracks, scene.cameras_vo, config, config.stages[0])
    start, end = torch_terms(objective, tracks, 1.0), torch_terms(objective, res.tracks, 1.0)
    assert sorted(stage.terms) == sorted(weights) and start["heading_anchor"] < 1e-20 < end["heading_anchor"]
    for term, (before, after) in stage.terms.items():
        assert before == pytest.approx(start[term], rel=RTOL, abs=1e-12), term
        assert after == pytest.approx(end[term], rel=1e-8), term
    # A larger weight holds the heading closer to the tracks' own.
    heavy = single_stage(StageSpec("heading", ["transl", "root"], dict(weights, heading_anchor=500.0)), 5)
    heavy.world_check = {}
    held = optimize(model, tracks, scene.cameras_vo, heavy)
    assert torch_terms(objective, held.tracks, 1.0)["heading_anchor"] < 0.5 * end["heading_anchor"]


def test_end_motion_anchor_after_ceres_steps(model):
    """end_motion_anchor holds the root's steps in each track's open ends (before the first and after the last
    frame with well_seen_keypoints keypoints) to the tracks' own, weighted by the keypoints a frame lacks: zero at
    the start, so both sides are compared at the state Ceres reaches from perturbed tracks."""
    scene = make_scene(model, num_people=2, num_frames=20, seed=3, drop_rate=0.0)  # its occlusion gap is inside
    tracks = perturbed(scene.init, seed=8)
    hidden = []
    for k, t in enumerate(tracks):
        kp = t.keypoints.copy()
        kp[:, :, 2] = np.where(kp[:, :, 2] > 0, np.maximum(kp[:, :, 2], 0.7), 0.0)  # dropped frames stay dropped
        kp[: 2 + k, :, 2] = 0.0         # no keypoints at the start
        kp[2 + k, 6:, 2] = 0.0          # then six
        kp[-2:, 3 * k:, 2] = 0.1        # few confident ones at the end
        hidden.append(dataclasses.replace(t, keypoints=kp))
    weights = {"reprojection": 1e-3, "joint_acceleration": 30.0, "end_motion_anchor": 7.0}
    config = single_stage(StageSpec("ends", ["transl", "root"], weights), 5, well_seen_keypoints=10)
    config.world_check = {}
    res = optimize(model, hidden, scene.cameras_vo, config)
    stage = res.stages[0]
    assert stage.status == "ok" and stage.iterations > 0, stage.message
    objective = StageObjective(model, hidden, scene.cameras_vo, config, config.stages[0])
    # Track 0: frames 0-1 none of 10, frame 2 six (lacks 0.4), the last two none; track 1: frames 0-2 none,
    # frame 3 six, the last two three (0.7).
    assert objective.end_weights.numpy().round(6).tolist() == [1.0, 1.0, 0.4, 1.0, 1.0, 1.0, 1.0, 1.0, 0.4, 0.7, 0.7]
    start, end = torch_terms(objective, hidden, 1.0), torch_terms(objective, res.tracks, 1.0)
    assert sorted(stage.terms) == sorted(weights) and start["end_motion_anchor"] < 1e-20 < end["end_motion_anchor"]
    for term, (before, after) in stage.terms.items():
        assert before == pytest.approx(start[term], rel=RTOL, abs=1e-12), term
        assert after == pytest.approx(end[term], rel=1e-8), term
    # Another threshold reads other frames: the setting is used on both sides.
    other = single_stage(config.stages[0], 0, well_seen_keypoints=17)
    np.testing.assert_allclose(StageObjective(model, hidden, scene.cameras_vo, other, other.stages[0]).end_weights,
                               [1, 1, 11 / 17, 1, 1, 1, 1, 1, 11 / 17, 14 / 17, 14 / 17], rtol=1e-12)


def test_lbfgs_baseline_lowers_the_stage_objective(model, scene):
    spec = next(s for s in OptimizerConfig.default().stages if s.name == "root_orientation")
    config = single_stage(spec, 0)
    objective = StageObjective(model, scene.init, scene.cameras_vo, config, config.stages[0])
    assert objective.free == ["transl", "root"]  # the offset is off by default
    start = TorchState.from_tracks(scene.init)
    with torch.no_grad():
        start_value = float(objective(start))
    run = run_lbfgs(objective, start, target=0.5 * start_value, time_limit=60.0, max_steps=5)
    assert run.final < 0.5 * start_value
    assert run.seconds_to_target is not None and run.seconds_to_target <= run.seconds
    assert run.stopped == "reached the target"
    # Variables the stage does not free stay where they were.
    assert torch.equal(run.state.body, start.body) and torch.equal(run.state.betas, start.betas)
    assert float(run.state.scale) == 1.0
    # Its result, handed to the C++ objective, has the same value there. ray_acceleration's lines of sight are
    # fixed at a stage's start, so both sides start from the handed-over state; they moved little. The heading
    # anchor's reference is the tracks' own heading: zero on the handed-over tracks, so it is left out.
    tracks = run.state.to_tracks(scene.init)
    stage = optimize(model, tracks, scene.cameras_vo, config).stages[0]
    restarted = StageObjective(model, tracks, scene.cameras_vo, config, config.stages[0])
    with torch.no_grad():
        value = float(restarted(TorchState.from_tracks(tracks)))
        anchored = float(objective.terms(run.state).get("heading_anchor", 0.0))
    assert stage.objective_before == pytest.approx(value, rel=RTOL)
    assert value == pytest.approx(run.final - anchored, rel=1e-4)


def test_unknown_terms_are_refused(model, scene):
    config = OptimizerConfig.default()
    with pytest.raises(ValueError, match=r"no torch counterpart for the terms \['vposer'\]"):
        StageObjective(model, scene.init, scene.cameras_vo, config, StageSpec("x", ["body"], {"vposer": 1.0}))


def test_static_camera_keeps_the_scale_fixed(model, scene):
    spec = StageSpec("scale", ["transl", "scale"], {"reprojection": 1e-3, "scale_prior": 1.0})
    cameras = Cameras(scene.cameras_vo.world_from_cam, scene.cameras_vo.intrinsics, static=True)
    objective = StageObjective(model, scene.init, cameras, OptimizerConfig.default(), spec)
    assert "scale" not in objective.free and "transl" in objective.free
