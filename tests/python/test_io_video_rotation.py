"""Phone videos: a portrait clip stored as landscape pixels plus a display-rotation flag is read upright by every
video reader and by the frames node. The rotated file is the same bitstream with the flag added (FFmpeg stream
copy), so its upright frames must equal np.rot90 of the plain file's frames exactly."""

import subprocess
from pathlib import Path

import cv2
import numpy as np
import pytest
from m3c.io.video import iter_frames, probe_video
from m3c.pipeline import PipelineConfig, Runner

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
SIZE = (320, 180)  # stored width, height


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> tuple[Path, Path]:
    imageio_ffmpeg = pytest.importorskip("imageio_ffmpeg", reason="needs imageio-ffmpeg (the 'test' extra)")
    folder = tmp_path_factory.mktemp("phone")
    plain, rotated = folder / "landscape.mp4", folder / "portrait.mp4"
    cap = cv2.VideoCapture(str(EXAMPLE))
    writer = cv2.VideoWriter(str(plain), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, SIZE)
    for _ in range(6):
        ok, frame = cap.read()
        assert ok
        writer.write(cv2.resize(frame, SIZE, interpolation=cv2.INTER_AREA))
    writer.release()
    cap.release()
    # -display_rotation: the display matrix phones write (degrees counter-clockwise), bitstream copied unchanged.
    subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error", "-display_rotation", "90",
                    "-i", str(plain), "-c", "copy", str(rotated)], check=True)
    return plain, rotated


def test_rotation_metadata_is_read_and_applied(clips):
    plain, rotated = clips
    assert probe_video(plain).rotation == 0
    info = probe_video(rotated)
    # 90 degrees counter-clockwise for display = 270 clockwise (OpenCV's convention), portrait size.
    assert (info.rotation, info.width, info.height) == (270, SIZE[1], SIZE[0])
    upright = [f for _, f in iter_frames(rotated)]
    stored = [f for _, f in iter_frames(plain)]
    assert len(upright) == len(stored) == 6
    for a, b in zip(upright, stored):
        np.testing.assert_array_equal(a, np.rot90(b, 1))


def test_every_reader_sees_the_same_upright_frames(clips):
    plain, rotated = clips
    bgr = [f for _, f in iter_frames(rotated)]
    rgb = [f for _, f in iter_frames(rotated, colour="rgb")]
    gray = [f for _, f in iter_frames(rotated, colour="gray")]
    assert len(bgr) == len(rgb) == len(gray) == 6
    for a, b, c in zip(bgr, rgb, gray):
        np.testing.assert_array_equal(a[..., ::-1], b)
        np.testing.assert_array_equal(cv2.cvtColor(a, cv2.COLOR_BGR2GRAY), c)


def test_frames_node_reports_the_portrait_size_and_rotation(clips, tmp_path):
    _, rotated = clips
    runner = Runner(PipelineConfig.default(), tmp_path / "out", {"video": rotated}, show_progress=False)
    runner.run(["camera"])
    keys = {name: key for name, key, _ in runner.plan(["camera"])}
    video = runner.cache.load("frames", keys["frames"])["video"]
    camera = runner.cache.load("camera", keys["camera"])["camera"]
    assert (video["width"], video["height"], video["rotation"], video["num_frames"]) == (180, 320, 270, 6)
    # The default principal point is the centre of the upright image.
    np.testing.assert_allclose(camera["intrinsics"][2:], [90.0, 160.0])
