"""NaN/inf at node boundaries (m3c.pipeline.finite), tracks the optimizer cannot use, and results.json's nulls:
unit checks, and a degenerate track fed through the real track-level nodes on a small synthetic scene."""

import json
import logging

import numpy as np
import pytest
from pipeline_scene import scene_pipeline_yaml, write_scene_inputs

from m3c.body import default_body_model
from m3c.io.results import json_ready, load_results
from m3c.motion import OptimizerConfig, Track
from m3c.nodes.load import save_outputs
from m3c.nodes.optimize import unusable_reason
from m3c.pipeline import PipelineConfig, PipelineError, run_pipeline
from m3c.pipeline.cache import Cache, decode
from m3c.pipeline.finite import check_outputs, index_ranges

LOG = logging.getLogger("test")


def _track(track_id, first_frame, n):
    return {"track_id": track_id, "first_frame": first_frame, "num_frames": n, "transl": np.zeros((n, 3)),
            "visible": np.ones(n, bool)}


def test_index_ranges():
    assert index_ranges(np.array([3, 4, 5, 9, 12, 13])) == "3-5, 9, 12-13"
    assert index_ranges(np.arange(0, 20, 2), limit=2) == "0, 2 and 8 more run(s)"


def test_non_track_nan_stops_the_run_naming_node_array_and_rows():
    cams = np.tile(np.eye(4), (10, 1, 1))
    cams[[4, 5, 8], 0, 3] = np.nan
    with pytest.raises(PipelineError, match=r"node 'vo' \(load\).*cameras\.world_from_cam is not finite in rows "
                                            r"4-5, 8"):
        check_outputs("vo", "load", {"cameras": {"world_from_cam": cams, "static": False}}, (), LOG)
    with pytest.raises(PipelineError, match=r"scale\.value is not finite"):
        check_outputs("scale", "scale", {"scale": {"value": float("inf"), "source": "given"}}, (), LOG)


def test_declared_nonfinite_paths_pass_and_finite_outputs_are_unchanged():
    outputs = {"result": {"stages": [{"objective_before": float("nan"), "terms": {"a": [np.nan, 1.0]}}],
                          "camera_scale": 1.0, "keypoints": np.full((3, 2), np.inf, np.float32)}}
    with pytest.raises(PipelineError, match=r"result\.stages\[0\]\.objective_before"):
        check_outputs("optimize", "optimize", outputs, (), LOG)
    checked = check_outputs("optimize", "optimize", outputs, ("result.stages", "result.keypoints"), LOG)
    assert checked["result"]["stages"] is outputs["result"]["stages"]
    empty = {"box": np.zeros((0, 4), np.float32)}
    assert check_outputs("n", "t", {"d": empty}, (), LOG)["d"]["box"] is empty["box"]
    ints = {"frame": np.arange(4), "label": "x"}  # integer arrays and strings are not floats to check
    checked = check_outputs("n", "t", {"d": ints}, (), LOG)["d"]
    assert checked == {"frame": ints["frame"], "label": "x"} and checked["frame"] is ints["frame"]


def test_a_track_with_nan_is_dropped_with_a_warning_naming_it(caplog):
    tracks = [_track(3, 10, 6), _track(7, 20, 5)]
    tracks[1]["transl"][[1, 2], 2] = np.nan
    with caplog.at_level(logging.WARNING, logger="test"):
        out = check_outputs("local_tracks", "local_tracks", {"tracks": {"tracks": tracks, "num_frames": 30}}, (),
                            LOG)
    assert [t["track_id"] for t in out["tracks"]["tracks"]] == [3]
    assert "track 7 dropped: transl is not finite in frames 21-22" in caplog.text
    tracks[0]["betas"] = np.array([0.0, np.nan])  # not per frame: its rows are no frames
    with caplog.at_level(logging.WARNING, logger="test"):
        out = check_outputs("lift", "lift", {"world": {"tracks": tracks[:1] + [_track(9, 0, 3)]}}, (), LOG)
    assert [t["track_id"] for t in out["world"]["tracks"]] == [9]
    assert "track 3 dropped: betas is not finite in rows 1" in caplog.text
    tracks[0]["transl"][0] = np.inf
    del tracks[0]["betas"]
    with pytest.raises(PipelineError, match="every track in tracks.tracks"):
        check_outputs("local_tracks", "local_tracks", {"tracks": {"tracks": tracks}}, (), LOG)


def test_json_ready_writes_missing_values_as_null():
    summary = {"stages": [{"objective_before": float("nan"), "objective_after": np.float32(2.5),
                           "terms": {"reprojection": [np.inf, 1.0]}}], "name": "x", "count": 3, "ok": True}
    text = json.dumps(json_ready(summary), allow_nan=False)
    # A strict parser: NaN/Infinity literals would raise here.
    back = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
    assert back == {"stages": [{"objective_before": None, "objective_after": 2.5,
                                "terms": {"reprojection": [None, 1.0]}}], "name": "x", "count": 3, "ok": True}


def test_optimizer_rejects_a_body_behind_the_camera_or_without_keypoints():
    model = default_body_model()
    n = 6
    keypoints = np.zeros((n, 17, 3))
    keypoints[..., 2] = 0.9
    transl = np.tile([0.0, 0.0, 4.0], (n, 1))
    transl[[2, 3], 2] = 0.02  # the body's centre at the camera: its keypoints lie around and behind it
    track = Track(5, keypoints, transl, np.tile([np.pi, 0.0, 0.0], (n, 1)), np.zeros((n, 23, 3)), np.zeros(10))
    cams = np.tile(np.eye(4), (20, 1, 1))
    config = OptimizerConfig.default()
    reason = unusable_reason(model, track, cams, config)
    assert reason is not None and "frames 7-8" in reason
    track.transl[[2, 3], 2] = 4.0
    assert unusable_reason(model, track, cams, config) is None
    track.keypoints[..., 2] = config.min_confidence / 2
    assert "confidence" in unusable_reason(model, track, cams, config)


def _saved(folder):
    structure = json.loads((folder / "outputs.json").read_text())
    with np.load(folder / "arrays.npz") as data:
        return decode(structure, {k: data[k] for k in data.files}, folder)


@pytest.fixture(scope="module")
def scene_inputs(tmp_path_factory):
    """A small synthetic two-person scene saved as the perception and odometry outputs of `load` nodes."""
    folder = tmp_path_factory.mktemp("degenerate")
    scene = write_scene_inputs(default_body_model(), folder, num_frames=12, seed=1)
    return folder, scene_pipeline_yaml(folder, scene.cameras_true.intrinsics)


def test_nan_in_a_detection_table_stops_the_run_at_that_node(scene_inputs):
    folder, _ = scene_inputs
    box = np.tile([10.0, 5.0, 30.0, 45.0], (4, 1)).astype(np.float32)
    box[[1, 2], 0] = np.nan
    save_outputs(folder / "detections_nan", {"detections": {"frame": np.arange(4), "box": box, "square": box,
                                                            "score": np.ones(4, np.float32)}})
    config = PipelineConfig.from_yaml(f"""
nodes:
  perception: {{type: load, config: {{path: {folder / 'detections_nan'}, outputs: [detections]}}}}
""")
    with pytest.raises(PipelineError, match=r"node 'perception' \(load\) produced NaN/inf: "
                                            r"detections\.box is not finite in rows 1-2"):
        run_pipeline(config, folder / "out_detections", sources={"video": folder / "video.mp4"},
                     show_progress=False)


def test_nan_in_a_perception_track_drops_that_track_at_that_node(scene_inputs, caplog):
    folder, yaml = scene_inputs
    saved = _saved(folder / "perception")
    saved["tracks"]["tracks"][1]["crop_cam"][[3, 4]] = np.nan
    save_outputs(folder / "perception_nan", saved)
    config = PipelineConfig.from_yaml(yaml.replace(str(folder / "perception"), str(folder / "perception_nan")))
    with caplog.at_level(logging.WARNING):
        report = run_pipeline(config, folder / "out_perception", sources={"video": folder / "video.mp4"},
                              targets=["local_tracks"], show_progress=False)
    assert "node 'perception' (load): track 1 dropped: crop_cam is not finite in rows 3-4" in caplog.text
    key = {r.name: r.key for r in report.records}["local_tracks"]
    tracks = Cache(folder / "out_perception" / "cache").load("local_tracks", key)["tracks"]["tracks"]
    assert [t["track_id"] for t in tracks] == [0]


def test_degenerate_track_is_dropped_and_the_run_finishes(scene_inputs, caplog):
    folder, yaml = scene_inputs
    source = {"video": folder / "video.mp4"}
    local = run_pipeline(PipelineConfig.from_yaml(yaml), folder / "out_local", sources=source,
                         targets=["local_tracks"], show_progress=False)
    key = {r.name: r.key for r in local.records}["local_tracks"]
    tracks = Cache(folder / "out_local" / "cache").load("local_tracks", key)
    assert [t["track_id"] for t in tracks["tracks"]["tracks"]] == [0, 1]
    tracks["tracks"]["tracks"][1]["transl"][[2, 3]] = np.nan  # person 1's camera-local body lost in two frames
    save_outputs(folder / "tracks_nan", tracks)
    start = yaml.index("  local_tracks:")
    stop = yaml.index("  scale:")
    degenerate = (yaml[:start] + f"  local_tracks:\n    type: load\n    config: {{path: {folder / 'tracks_nan'}, "
                  "outputs: [tracks]}\n" + yaml[stop:])
    first = int(tracks["tracks"]["tracks"][1]["first_frame"])
    with caplog.at_level(logging.WARNING):
        report = run_pipeline(PipelineConfig.from_yaml(degenerate), folder / "out", sources=source,
                              targets=["results"], show_progress=False)
    assert report.status()["results"] == "ran"
    assert f"track 1 dropped: transl is not finite in frames {first + 2}-{first + 3}" in caplog.text
    summary, arrays = load_results(folder / "out", check=False)
    assert [t["id"] for t in summary["tracks"]] == [0]
    assert np.isfinite(arrays["world_joints"][0][arrays["valid"][0]]).all()
    json.loads((folder / "out" / "results.json").read_text(),
               parse_constant=lambda c: pytest.fail(f"non-JSON constant {c}"))
