"""`m3c view`: the viewer's scene follows the results frame by frame, and headless Chromium draws it."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from export_scene import write_results
from m3c.body import default_body_model
from m3c.cli import main

viser = pytest.importorskip("viser", reason="the viewer needs viser (pip install m3c[viewer])")

from m3c.viz.browser import find_chromium, free_port, screenshot_page  # noqa: E402
from m3c.viz.viewer import ResultViewer, serve, track_table  # noqa: E402


@pytest.fixture(scope="module")
def model():
    return default_body_model()


@pytest.fixture(scope="module")
def results(tmp_path_factory, model):
    return write_results(tmp_path_factory.mktemp("viewer") / "out", model)


@pytest.fixture
def server():
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield server
    server.stop()


def test_viewer_follows_the_results(results, server, model):
    viewer = ResultViewer(server, results)
    source = viewer.source
    assert viewer.images is None  # no overlay.mp4 in this folder
    late = source.tracks[1]       # frames 3..9
    for frame in (0, 5):
        viewer.set_frame(frame)
        optimized, lift = viewer.meshes["optimized"], viewer.meshes["lift"]
        assert optimized[0].visible and not lift[0].visible
        k = frame - late.frames[0]
        assert optimized[1].visible == (0 <= k < len(late.frames))
        if optimized[1].visible:
            truth = model.forward(late.pose[k:k + 1], late.betas, late.transl[k:k + 1]).vertices[0]
            np.testing.assert_allclose(optimized[1].vertices, truth, atol=1e-5)
        pose = source.arrays["world_from_cam"][frame]
        np.testing.assert_allclose(viewer.frustum.position, pose[:3, 3], atol=1e-6)
    viewer.show["lift"].value = True
    viewer.show["optimized"].value = False
    viewer.set_frame(5)
    assert viewer.meshes["lift"][1].visible and not viewer.meshes["optimized"][1].visible
    arrays = source.arrays
    lift_root = arrays["lift_world_transl"][late.index, 5]
    pose = late.pose[2:3].copy()
    pose[0, 0] = arrays["lift_world_root_orient"][late.index, 5]
    if "lift_body_pose" in arrays:  # results that carry the lift's own body pose and shape
        pose[0, 1:] = arrays["lift_body_pose"][late.index, 5]
    betas = arrays["lift_betas"][late.index] if "lift_betas" in arrays else late.betas
    truth = model.forward(pose, betas, lift_root[None]).vertices[0]
    np.testing.assert_allclose(viewer.meshes["lift"][1].vertices, truth, atol=1e-5)
    viewer.set_frame(99)
    assert viewer.frame == source.num_frames - 1
    viewer.playing.value = True
    viewer.step()
    assert viewer.frame == 0  # wraps around at the end


def test_track_table_shows_figures_present():
    summary = {"tracks": [{"id": 3, "frames": 10, "visible_frames": 8, "mean_reprojection_error_px": 4.25,
                           "path_length_m": 2.0, "height_m": 1.7, "plausibility": {"foot_skate_m": 0.012}}]}
    table = track_table(summary, [3])
    assert "foot_skate_m" in table.splitlines()[0] and "| 3 | 10 | 8 | 4.25 | 2 | 1.7 | 0.012 |" in table
    assert track_table(summary, [4]) == "No per-track figures in results.json."


def test_view_rejects_a_folder_without_results(tmp_path, capsys):
    assert main(["view", str(tmp_path)]) == 2
    assert "holds no M3C results" in capsys.readouterr().err


def _body_pixels(png_bytes: bytes) -> int:
    """Pixels of the 3D canvas (left of viser's panel, below its notices) in track 4's colour, shaded."""
    import cv2

    from m3c.viz.scene import track_colour

    image = cv2.imdecode(np.frombuffer(png_bytes, np.uint8), cv2.IMREAD_COLOR)[..., ::-1].astype(int)
    canvas = image[200:, :850]
    direction = track_colour(4) / np.linalg.norm(track_colour(4))
    norms = np.linalg.norm(canvas, axis=-1)
    cosine = (canvas @ direction) / np.maximum(norms, 1)
    return int(((cosine > 0.98) & (norms > 60) & (canvas.max(-1) - canvas.min(-1) > 60)).sum())


@pytest.mark.slow
@pytest.mark.skipif(find_chromium() is None, reason="headless Chromium absent (Debian: apt-get install chromium)")
def test_chromium_draws_the_scene(results, tmp_path):
    import cv2

    port, stop, up = free_port(), threading.Event(), threading.Event()
    thread = threading.Thread(target=serve, args=(results,), kwargs=dict(port=port, stop=stop,
                                                                          ready=lambda _: up.set()))
    thread.start()
    try:
        assert up.wait(60)
        png = screenshot_page(f"http://127.0.0.1:{port}", tmp_path / "view.png", 1200, 700, wait_s=5.0,
                              done=lambda data: _body_pixels(data) > 300, timeout_s=60.0)
    finally:
        stop.set()
        thread.join(30)
    pixels = _body_pixels(png.read_bytes())
    assert pixels > 300, f"only {pixels} body-coloured pixels: the 3D canvas looks blank"
    canvas = cv2.imread(str(png))[200:, :850]
    assert canvas.std() > 10  # ground grid and bodies, not a flat colour


def test_viewer_shows_the_overlay_video(results, tmp_path, server):
    import shutil

    from m3c.io.video import VideoWriter

    folder = tmp_path / "out"
    shutil.copytree(results, folder)
    levels = 20 * np.arange(12) + 20
    with VideoWriter(folder / "overlay.mp4", 10.0, (160, 120)) as writer:
        for level in levels:
            writer.write(np.full((120, 160, 3), level, np.uint8))
    viewer = ResultViewer(server, folder)
    assert len(viewer.images) == 12
    for frame in (0, 7, 11):
        viewer.set_frame(frame)
        assert abs(float(viewer.image.image.mean()) - levels[frame]) < 6  # lossy video, one frame per step


def test_viewer_picks_the_processed_frames_of_the_source_video(results, tmp_path, server):
    from m3c.io.video import VideoWriter

    levels = 10 * np.arange(24) + 10   # the results processed every second frame (frame_ids 0, 2, ..., 22)
    with VideoWriter(tmp_path / "source.mp4", 20.0, (160, 120)) as writer:
        for level in levels:
            writer.write(np.full((120, 160, 3), level, np.uint8))
    viewer = ResultViewer(server, results, video=tmp_path / "source.mp4")
    for frame in (1, 6, 11):
        viewer.set_frame(frame)
        assert abs(float(viewer.image.image.mean()) - levels[2 * frame]) < 4
    with pytest.raises(FileNotFoundError, match="video not found"):
        ResultViewer(server, results, video=tmp_path / "missing.mp4")


def test_follow_camera_is_the_world_views_chase_camera(results, server, monkeypatch):
    """In "follow" mode every connected browser's camera sits where the world view's chase camera is."""
    import contextlib
    import types

    from m3c.viz.chase import ChaseView

    viewer = ResultViewer(server, results)
    client = types.SimpleNamespace(camera=types.SimpleNamespace(position=None, look_at=None),
                                   atomic=contextlib.nullcontext)
    monkeypatch.setattr(server, "get_clients", lambda: {0: client})
    viewer.set_frame(4)
    assert client.camera.position is None  # "free": the browser's camera is left alone
    viewer.camera_mode.value = "follow"
    viewer.set_frame(6)
    source = viewer.source
    people = [[] for _ in range(source.num_frames)]
    for track in source.tracks:
        for frame, joints in zip(track.frames, track.world_joints):
            people[int(frame)].append(joints[[1, 2]].mean(axis=0))
    chase = ChaseView([np.array(p).reshape(-1, 3) for p in people], source.arrays["world_from_cam"][:, :3, 3],
                      0.0 if source.ground_found else min(float(t.world_joints[..., 1].min()) for t in source.tracks),
                      float(source.fps))
    np.testing.assert_allclose(client.camera.position, chase.poses[6][:3, 3], atol=1e-9)
    np.testing.assert_allclose(client.camera.look_at, chase.targets[6], atol=1e-9)
