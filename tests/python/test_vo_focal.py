"""The focal length from the camera's motion (m3c.vo.focal, the focal node): a turning camera rendered at a known
focal length is found within a few percent; a camera that only translates is reported as uninformative (the
focal is unobservable then); bad input gets a clear error; the node re-expresses the bodies at the estimate."""

import logging

import numpy as np
import pytest

from m3c.io.video import VideoWriter
from m3c.nodes.focal import FocalNode
from m3c.pipeline import InputError
from m3c.pipeline.progress import Progress
from m3c.vo.focal import FocalSearchConfig, estimate_focal, focal_windows
from m3c.vo.synthetic import RoomRenderer, built_scene_edges, look_rotation

W, H = 192, 144
DIAGONAL = float(np.hypot(W, H))
# Small and fast: one window, a coarse grid of 5 candidates and 2 refinements.
FAST = {"windows": 1, "num_coarse": 5, "num_refine": 2, "keyframe_flow_px": 4.0}


def _room_frames(ratio: float, motion: str, T: int = 30) -> np.ndarray:
    """Gray frames of the textured room seen by a camera of focal `ratio` x the image diagonal that turns by
    34 degrees while moving a little ("turn") or slides sideways without turning ("translate")."""
    f = ratio * DIAGONAL
    renderer = RoomRenderer(W, H, np.array([f, f, W / 2, H / 2]), supersample=1, seed=0)
    frames = []
    for i in range(T):
        s = i / (T - 1)
        pose = np.eye(4)
        if motion == "turn":
            pose[:3, :3] = look_rotation(0.6 * s - 0.3, 0.1 * np.sin(3 * s), 0.0)
            pose[:3, 3] = [0.2 * s, 0.0, 0.3 * s]
        else:
            pose[:3, 3] = [s - 0.5, 0.05 * s, 0.3 * s]
        frames.append(renderer.render(pose)[0])
    return np.array(frames)


def test_turning_camera_focal_is_recovered():
    ratio = 1.3  # longer than the default (the node's test below renders a shorter one, 0.7)
    estimate = estimate_focal(_room_frames(ratio, "turn"), config=FocalSearchConfig(**FAST))
    assert estimate.informative, estimate.message
    assert estimate.default == pytest.approx(DIAGONAL)
    # Within 5% of the rendering's focal, and the truth within 2 reported widths of the estimate.
    assert estimate.focal == pytest.approx(ratio * DIAGONAL, rel=0.05)
    assert 0 < estimate.log_sigma < 0.25
    assert abs(np.log(estimate.ratio / ratio)) < 2 * estimate.log_sigma
    # The cost it minimised is lowest at the estimate's candidate and higher at the default.
    best = estimate.ratios[np.argmin(estimate.costs)]
    assert abs(np.log(best / ratio)) < 0.15
    assert estimate.costs[np.argmin(np.abs(estimate.ratios - 1.0))] > 1.1 * estimate.costs.min()


def test_search_goes_on_past_the_end_where_the_minimum_lies():
    """A focal shorter than the search range's low end, the cost rising towards the other: the search extends
    downwards and finds it (without the extension its least cost would lie at the end: uninformative)."""
    ratio = 0.55
    estimate = estimate_focal(_room_frames(ratio, "turn"), config=FocalSearchConfig(**FAST, low=0.7))
    assert estimate.informative, estimate.message
    assert estimate.ratios.min() < 0.7 < estimate.ratios.max()
    assert estimate.focal == pytest.approx(ratio * DIAGONAL, rel=0.05)

def test_translating_camera_is_uninformative():
    estimate = estimate_focal(_room_frames(0.8, "translate"), config=FocalSearchConfig(**FAST))
    assert not estimate.informative
    assert estimate.focal == estimate.default == pytest.approx(DIAGONAL)
    assert "not observable" in estimate.message and "flat" in estimate.message
    assert not estimate.still  # it moved: a translating camera is no still one
    assert np.ptp(estimate.costs) < 0.1 * estimate.costs.min()  # the cost barely changes with the focal


def test_still_camera_is_uninformative():
    frames = np.repeat(_room_frames(1.0, "turn", T=3)[:1], 12, axis=0)
    estimate = estimate_focal(frames, config=FocalSearchConfig(**FAST))
    assert not estimate.informative and estimate.focal == pytest.approx(DIAGONAL)
    assert "did not move" in estimate.message and estimate.still and estimate.summary()["still"]


def test_bad_input_is_named():
    frames = _room_frames(1.0, "turn", T=4)
    with pytest.raises(ValueError, match="at least 3 frames"):
        estimate_focal(frames[:2])
    with pytest.raises(ValueError, match="uint8"):
        estimate_focal(np.full(frames.shape, np.nan))
    with pytest.raises(ValueError, match="masks must be"):
        estimate_focal(frames, masks=np.zeros((4, 10, 10), bool))
    with pytest.raises(ValueError, match="low < 1 < high"):
        FocalSearchConfig(low=1.2)
    with pytest.raises(ValueError, match="num_coarse"):
        FocalSearchConfig(num_coarse=2)
    with pytest.raises(InputError, match="focal.search"):
        FocalNode("focal", FocalNode.Config(search={"windows": 0})).check(None)


def test_windows_spread_over_the_video():
    config = FocalSearchConfig(windows=3, window_frames=40)
    assert focal_windows(150, config) == [(0, 40), (55, 95), (110, 150)]
    assert focal_windows(70, config) == [(0, 40)]  # room for one window only
    assert focal_windows(20, config) == [(0, 20)]


class _Context:
    def __init__(self, video_path):
        self.log = logging.getLogger("test")
        self._video = str(video_path)

    def source(self, name):
        return self._video

    def progress(self, desc, total):
        return Progress(desc, total, self.log, enabled=False)


def _node_inputs(source, rng, n=5):
    transl = np.column_stack([rng.uniform(-1, 1, n), rng.uniform(-0.5, 0.5, n), rng.uniform(3, 8, n)])
    return {"video": {"num_frames": 30, "width": W, "height": H, "frame_ids": np.arange(30), "start": 0,
                      "stop": 30, "step": 1},
            "camera": {"intrinsics": np.array([DIAGONAL, DIAGONAL, W / 2, H / 2]), "source": source},
            "masks": None, "detections": None,
            "tracks": {"tracks": [{"track_id": 3, "frame": np.arange(n - 2), "pose": np.zeros((n - 2, 24, 3)),
                                   "transl": transl[:n - 2]},
                                  {"track_id": 4, "frame": np.arange(2), "pose": np.zeros((2, 24, 3)),
                                   "transl": transl[n - 2:]}]}}


def test_focal_node_estimates_and_moves_the_bodies(tmp_path, rng):
    path = tmp_path / "turn.mp4"
    with VideoWriter(path, 30.0, (W, H)) as writer:
        for gray in _room_frames(0.7, "turn"):
            writer.write(np.repeat(gray[..., None], 3, axis=2))
    inputs = _node_inputs("default", rng)
    out = FocalNode("focal", FocalNode.Config(search=FAST)).run(_Context(path), inputs)
    camera, tracks = out["camera"], out["tracks"]["tracks"]
    assert camera["source"] == "estimated" and camera["focal_estimate"]["informative"]
    new = camera["intrinsics"]
    assert new[0] == pytest.approx(0.7 * DIAGONAL, rel=0.06) and new[0] == new[1]
    np.testing.assert_allclose(new[2:], [W / 2, H / 2])
    # Every body root keeps its pixel: projected at the estimate as it was at the default.
    old = inputs["camera"]["intrinsics"]

    def pixels(k, x):
        return np.column_stack([k[0] * x[:, 0] / x[:, 2] + k[2], k[1] * x[:, 1] / x[:, 2] + k[3]])

    for track, given in zip(tracks, inputs["tracks"]["tracks"], strict=True):
        np.testing.assert_allclose(pixels(new, track["transl"]), pixels(old, given["transl"]), atol=1e-9)
        np.testing.assert_allclose(track["transl"][:, 2] / given["transl"][:, 2], new[0] / old[0])
        assert track["pose"] is given["pose"] and track["track_id"] == given["track_id"]


def test_focal_node_keeps_given_intrinsics_and_can_be_switched_off(rng):
    for source, config in (("given", FocalNode.Config(scene_lines=False)),
                           ("default", FocalNode.Config(enabled=False))):
        inputs = _node_inputs(source, rng)
        out = FocalNode("focal", config).run(None, inputs)  # reads no frames
        assert out["camera"]["source"] == source and out["camera"]["focal_estimate"] is None
        assert out["camera"]["scene"] is None
        np.testing.assert_array_equal(out["camera"]["intrinsics"], inputs["camera"]["intrinsics"])
        assert out["tracks"] is inputs["tracks"]


def _still_scene_video(path, focal, width=640, height=360, frames=12):
    """A still camera (pitched 11 degrees down) over a built scene's edges: its motion cannot tell the focal length,
    its lines can."""
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(0.2, -0.2, 0.03)
    image = built_scene_edges(width, height, [focal, focal, width / 2, height / 2], pose, seed=1)
    with VideoWriter(path, 30.0, (width, height)) as writer:
        for _ in range(frames):
            writer.write(np.repeat(image[..., None], 3, axis=2))
    return pose[:3, :3].T @ np.array([0.0, -1.0, 0.0])


def test_focal_node_takes_the_scene_where_the_motion_cannot_tell(tmp_path, rng):
    width, height, focal = 640, 360, 560.0
    up = _still_scene_video(tmp_path / "still.mp4", focal, width, height)
    inputs = _node_inputs("default", rng)
    inputs["video"] = {"num_frames": 12, "width": width, "height": height, "frame_ids": np.arange(12), "start": 0,
                       "stop": 12, "step": 1}
    inputs["camera"] = {"intrinsics": np.array([np.hypot(width, height)] * 2 + [width / 2, height / 2]),
                        "source": "default"}
    out = FocalNode("focal", FocalNode.Config(search=FAST)).run(_Context(tmp_path / "still.mp4"), inputs)
    camera = out["camera"]
    assert not camera["focal_estimate"]["informative"]  # a still camera: the motion search cannot tell
    assert camera["focal_estimate"]["still"]  # and says it stood still (the people's estimate may then run)
    assert camera["source"] == "scene" and camera["scene"]["informative"]
    assert camera["intrinsics"][0] == pytest.approx(focal, rel=0.03)
    factor = camera["intrinsics"][0] / inputs["camera"]["intrinsics"][0]
    for track, given in zip(out["tracks"]["tracks"], inputs["tracks"]["tracks"], strict=True):
        np.testing.assert_allclose(track["transl"][:, 2], given["transl"][:, 2] * factor)
    for frame in camera["scene"]["frames"]:  # each sampled frame's up direction, at the chosen focal length
        assert np.degrees(np.arccos(np.clip(np.dot(frame["up"], up), -1, 1))) < 1.0
    # Given intrinsics stay, and the scene's up direction is still measured at them.
    inputs["camera"] = {"intrinsics": np.array([500.0, 500.0, width / 2, height / 2]), "source": "given"}
    out = FocalNode("focal", FocalNode.Config()).run(_Context(tmp_path / "still.mp4"), inputs)
    assert out["camera"]["source"] == "given" and out["camera"]["intrinsics"][0] == 500.0
    assert out["camera"]["scene"]["frames"] and out["tracks"] is inputs["tracks"]


def test_textureless_video_is_uninformative_not_an_error():
    frames = np.full((6, H, W), 128, np.uint8)  # nothing for the odometry to track
    estimate = estimate_focal(frames, config=FocalSearchConfig(**FAST))
    assert not estimate.informative and estimate.focal == pytest.approx(DIAGONAL)
    assert "could not run" in estimate.message and "no texture" in estimate.message
    assert not estimate.still  # the odometry failed: whether the camera moved is not known


def test_recovered_solver_steps_leave_no_warnings_on_stderr():
    """The focal search on the bundled clip makes Ceres fail a Cholesky step it then damps and retries; glog's
    warnings about it are hidden (they read like errors in a run's log) unless GLOG_minloglevel asks for them."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    example = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
    script = ("from m3c.io.video import read_video\nfrom m3c.vo import estimate_focal\n"
              f"estimate_focal(read_video({str(example)!r}, colour='gray')[0])\n")
    env = {k: v for k, v in os.environ.items() if k != "GLOG_minloglevel"}
    quiet = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, timeout=300)
    loud = subprocess.run([sys.executable, "-c", script], env={**env, "GLOG_minloglevel": "0"},
                          capture_output=True, text=True, timeout=300)
    assert quiet.returncode == 0 and loud.returncode == 0, quiet.stderr[-2000:] + loud.stderr[-2000:]
    assert "Linear solver failure" in loud.stderr  # the steps do fail: the check below can fail
    assert "levenberg_marquardt" not in quiet.stderr and "InitGoogleLogging" not in quiet.stderr


def test_static_camera_skips_the_search_not_the_scene():
    """`m3c run --static-camera`: the odometry's focal search is skipped (a still camera's motion cannot tell the
    focal length), the scene's lines are still read."""
    from types import SimpleNamespace

    from m3c.cli.pipeline import pipeline_config

    config = pipeline_config(SimpleNamespace(config=None, static_camera=True))
    focal = config.nodes["focal"].config
    assert focal.get("motion") is False and focal.get("enabled", True) is True
    assert focal.get("scene_lines", True) is True and config.nodes["vo"].config.get("static") is True


def test_bad_scene_setting_is_named():
    with pytest.raises(InputError, match="focal.scene .*SceneLineConfig"):
        FocalNode("focal", FocalNode.Config(scene={"frames": 0})).check(None)
    with pytest.raises(InputError, match="focal.scene"):
        FocalNode("focal", FocalNode.Config(scene={"no_such_setting": 1})).check(None)


def test_camera_focal_log_sigma_per_source():
    """The focal length's uncertainty that the ground's scene prior widens by, read from the focal node's record."""
    from m3c.vo.focal import camera_focal_log_sigma

    assert camera_focal_log_sigma({"source": "given"}) == 0.0
    assert camera_focal_log_sigma({"source": "default"}) == 0.3
    assert camera_focal_log_sigma({"source": "estimated", "focal_estimate": {"log_sigma": 0.04}}) == 0.04
    assert camera_focal_log_sigma({"source": "scene", "scene": {"spread": 0.02, "log_sigma": 0.06}}) == 0.06
    assert camera_focal_log_sigma({"source": "scene", "scene": {"spread": 0.02}}) == pytest.approx(0.02 / 0.674)
    # The people's measurement (log-sigma 0.05) fused with the default (0.3) after adding the bias (0.1):
    fused = 1.0 / np.sqrt(1.0 / 0.3 ** 2 + 1.0 / (0.05 ** 2 + 0.1 ** 2))
    assert camera_focal_log_sigma({"source": "people", "feet_focal": {"log_sigma": 0.05}}) == pytest.approx(fused)
    assert camera_focal_log_sigma({"source": "estimated", "focal_estimate": None}) == 0.3  # no record: the default's
