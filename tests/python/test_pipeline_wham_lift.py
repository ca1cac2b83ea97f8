"""The WHAM-style world lift: frame conversions between M3C's y-up world and WHAM's y-down one (checked with a
stand-in network whose trajectory is known), and the lift node loading a checkpoint in the official layout."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from m3c.models.rotations import matrix_to_rotation_6d_rows
from m3c.models.wham import WhamLifter
from m3c.motion.wham_lift import FLIP, wham_trajectory


class KnownTrajectory(torch.nn.Module):
    """Stands in for WhamLifter: returns a given world trajectory (in WHAM's y-down world) and records inputs."""

    def __init__(self, root_world, trans_world):
        super().__init__()
        self.weight = torch.nn.Parameter(torch.zeros(1, dtype=torch.float64))
        self.root_world, self.trans_world = root_world, trans_world

    def lift(self, x, mask, init_kp, init_root, cam_angvel):
        self.seen = {"x": x, "mask": mask, "init_kp": init_kp, "init_root": init_root, "cam_angvel": cam_angvel}
        return {"root_world": torch.as_tensor(self.root_world)[None], "trans_world": torch.as_tensor(self.trans_world)[None]}


def test_wham_trajectory_converts_frames(synthetic_body_model, rng):
    model = synthetic_body_model
    n = 6
    # M3C-world truth: a person turning and walking along +z; the camera lift put it at transl_world[0].
    R_true = Rotation.from_rotvec(np.outer(np.linspace(0, 0.5, n), [0, 1, 0])).as_matrix()
    path = np.stack([np.zeros(n), np.zeros(n), np.linspace(0, 1, n)], axis=1)
    start = np.array([0.3, 0.9, 4.0])
    network = KnownTrajectory(FLIP @ R_true, path @ FLIP.T + 7.0)  # WHAM's world, arbitrary origin
    track = {"first_frame": 2, "num_frames": n, "keypoints": np.concatenate(
                 [rng.uniform(100, 200, size=(n, 17, 2)), np.full((n, 17, 1), 0.9)], axis=2),
             "box": np.tile([100.0, 100.0, 300.0, 300.0], (n, 1)), "root_orient": rng.normal(size=(n, 3)) * 0.1,
             "body_pose": np.zeros((n, model.num_joints - 1, 3)), "betas": np.zeros(model.num_betas),
             "transl": rng.normal(size=(n, 3)) + [0, 0, 4]}
    world_from_cam = np.tile(np.eye(4), (n + 2, 1, 1))
    world_from_cam[:, :3, :3] = Rotation.from_rotvec(np.outer(np.linspace(0, 0.2, n + 2), [0, 1, 0])).as_matrix()
    root_lift = Rotation.from_matrix(R_true).as_rotvec()
    transl_lift = np.tile(start, (n, 1))
    root, transl = wham_trajectory(network, model, track, world_from_cam, root_lift, transl_lift,
                                   {"width": 960, "height": 540, "fps": 30.0}, [1000, 1000, 480, 270])
    np.testing.assert_allclose(Rotation.from_rotvec(root).as_matrix(), R_true, atol=1e-12)
    np.testing.assert_allclose(transl, start + path, atol=1e-12)
    seen = network.seen
    assert seen["x"].shape == (1, n, 37) and seen["mask"].shape == (1, n, 17) and not seen["mask"].any()
    assert seen["init_kp"].shape == (1, 1, 88) and seen["cam_angvel"].shape == (1, n, 6)
    expected_root = matrix_to_rotation_6d_rows(torch.as_tensor(FLIP @ R_true[0]))
    np.testing.assert_allclose(seen["init_root"][0, 0].numpy(), expected_root.numpy(), atol=1e-12)
    # The camera turns about world up (y): in WHAM's y-down world that is a turn about -y, and the angular
    # velocity input is 6D(R[t-1] R[t]^T) - 6D(I) of world-to-camera rotations.
    cam_from_world = np.transpose(FLIP @ world_from_cam[2:, :3, :3], (0, 2, 1))
    relative = cam_from_world[0] @ cam_from_world[1].T
    expected = (relative[:2].reshape(6) - [1, 0, 0, 0, 1, 0]) * 30.0
    np.testing.assert_allclose(seen["cam_angvel"][0, 1].numpy(), expected, atol=1e-9)


@pytest.mark.slow
def test_lift_node_with_a_checkpoint_in_the_official_layout(tmp_path, monkeypatch):
    from pipeline_scene import scene_pipeline_yaml, write_scene_inputs

    from m3c.body import default_body_model
    from m3c.nodes.lift import LiftNode
    from m3c.pipeline import PipelineConfig, run_pipeline
    from m3c.pipeline.cache import Cache

    torch.manual_seed(0)
    checkpoint = tmp_path / "wham_vit_w_3dpw.pth.tar"
    torch.save({"model": WhamLifter().state_dict()}, checkpoint)  # random weights, official key layout
    model = default_body_model()
    scene = write_scene_inputs(model, tmp_path, num_frames=12, seed=1)
    config = PipelineConfig.from_yaml(scene_pipeline_yaml(tmp_path, scene.cameras_true.intrinsics))
    config = config.with_overrides({"lift.method": "wham", "lift.checkpoint": str(checkpoint)})
    unloaded = []
    original = LiftNode.unload
    monkeypatch.setattr(LiftNode, "unload", lambda self: (unloaded.append(self._lifter is not None),
                                                          original(self)))
    report = run_pipeline(config, tmp_path / "out", {"video": tmp_path / "video.mp4"}, targets=["lift"],
                          show_progress=False)
    assert unloaded == [True]  # the network was loaded for the node and released after it
    key = dict((r.name, r.key) for r in report.records)["lift"]
    world = Cache(tmp_path / "out" / "cache").load("lift", key)["world"]
    assert world["method"] == "wham"
    for track in world["tracks"]:
        assert np.isfinite(track["transl"]).all() and np.isfinite(track["root_orient"]).all()
    # Without the file, method wham cannot run and says where the file comes from.
    from m3c.pipeline import PipelineUnavailable

    missing = config.with_overrides({"lift.checkpoint": str(tmp_path / "missing.pth.tar")})
    with pytest.raises(PipelineUnavailable, match="WHAM checkpoint not found"):
        run_pipeline(missing, tmp_path / "out2", {"video": tmp_path / "video.mp4"}, targets=["lift"],
                     show_progress=False)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["wham", "auto"])
def test_lift_node_without_the_official_file(method, tmp_path, monkeypatch):
    """method wham without WHAM's checkpoint runs M3C's shipped regressor (here a random one in its place);
    auto stays the camera lift."""
    from pipeline_scene import scene_pipeline_yaml, write_scene_inputs

    import m3c.models.weights as weights
    from m3c.body import default_body_model
    from m3c.nodes.lift import LiftNode
    from m3c.pipeline import PipelineConfig, run_pipeline
    from m3c.pipeline.cache import Cache
    from m3c.training.regressor import WorldRegressor, save_regressor

    torch.manual_seed(0)
    shipped = tmp_path / "weights"
    shipped.mkdir()
    net = WorldRegressor(16)
    for p in net.trajectory_decoder.regressor.declayer0.parameters():   # a moving root: zero velocity is the
        torch.nn.init.normal_(p, std=0.01)                               # camera lift's start held
    save_regressor(net, shipped / "regressor.pt")
    monkeypatch.setattr(weights, "weights_dir", lambda: shipped)
    monkeypatch.setenv("M3C_MODELS", str(tmp_path / "no_models"))
    (tmp_path / "no_models").mkdir()
    model = default_body_model()
    scene = write_scene_inputs(model, tmp_path, num_frames=12, seed=1)
    config = PipelineConfig.from_yaml(scene_pipeline_yaml(tmp_path, scene.cameras_true.intrinsics))
    config = config.with_overrides({"lift.method": method})
    loaded = []
    original = LiftNode.unload
    monkeypatch.setattr(LiftNode, "unload", lambda self: (loaded.append(type(self._lifter).__name__),
                                                          original(self)))
    report = run_pipeline(config, tmp_path / "out", {"video": tmp_path / "video.mp4"}, targets=["lift"],
                          show_progress=False)
    key = dict((r.name, r.key) for r in report.records)["lift"]
    world = Cache(tmp_path / "out" / "cache").load("lift", key)["world"]
    if method == "auto":
        assert loaded == ["NoneType"] and world["method"] == "camera"
        return
    assert loaded == ["WorldRegressor"] and world["method"] == "wham"
    for track in world["tracks"]:
        assert np.isfinite(track["transl"]).all() and np.isfinite(track["root_orient"]).all()
