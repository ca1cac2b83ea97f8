"""`m3c batch`: many videos, one pipeline; each video's results as `m3c run` writes them, failures reported while the
others go on, re-runs served from the caches. Sequential always; on Ray when it is installed (pip install
'm3c[batch]'), with a local Ray instance the test starts. The videos are 10-frame 480x270 cuts of the bundled
example, so the real default pipeline (MediaPipe perception) runs in a few seconds each."""

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import m3c
import pytest
from m3c.cli import main
from m3c.io.manifest import folder_state
from m3c.io.results import PUBLISHED_FILES
from m3c.nodes import register_builtin_nodes
from m3c.perception.mediapipe_pose import mediapipe_available
from m3c.pipeline import Needs, PipelineConfig, PipelineError, node_type
from m3c.pipeline.batch import SUMMARY, collect_videos, result_names, run_batch, start_local_ray, video_needs

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
# The subprocess imports the same m3c as this process (the source tree in development, the installed package in CI).
PYTHON_DIR = str(Path(m3c.__file__).resolve().parents[1])
needs_mediapipe = pytest.mark.skipif(not mediapipe_available(), reason="needs mediapipe (pip install "
                                                                       "'m3c[perception]')")


def cut_clip(path: Path, first: int, count: int = 10, size=(480, 270)) -> Path:
    cap = cv2.VideoCapture(str(EXAMPLE))
    cap.set(cv2.CAP_PROP_POS_FRAMES, first)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 24.0, size)
    for _ in range(count):
        ok, frame = cap.read()
        assert ok
        writer.write(cv2.resize(frame, size, interpolation=cv2.INTER_AREA))
    writer.release()
    cap.release()
    return path


@pytest.fixture(scope="module")
def videos(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("videos")
    cut_clip(folder / "walk_a.mp4", 0)
    cut_clip(folder / "walk_b.mp4", 60)
    # An MP4 header followed by garbage: OpenCV opens no stream.
    (folder / "broken.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(range(256)) * 20)
    return folder


@pytest.fixture(scope="module")
def reference(videos, tmp_path_factory) -> dict[str, Path]:
    """`m3c run` on each good video alone: what the batch must reproduce byte for byte."""
    out = tmp_path_factory.mktemp("reference")
    for stem in ("walk_a", "walk_b"):
        assert main(["run", str(videos / f"{stem}.mp4"), "--out", str(out / stem), "--no-progress", "-q"]) == 0
    return {stem: out / stem for stem in ("walk_a", "walk_b")}


def published_bytes(folder: Path) -> dict[str, bytes]:
    return {name: (folder / name).read_bytes() for name in sorted(PUBLISHED_FILES) if (folder / name).is_file()}


def check_batch(out: Path, reference: dict[str, Path], cached: bool) -> dict:
    summary = json.loads((out / SUMMARY).read_text())
    by_name = {v["name"]: v for v in summary["videos"]}
    assert (summary["done"], summary["failed"]) == (2, 1)
    assert by_name["broken"]["status"] == "failed"
    assert "cannot open" in by_name["broken"]["error"] and "broken.mp4" in by_name["broken"]["error"]
    assert not (out / "broken").exists()  # nothing partial of the failed video
    for stem, folder in reference.items():
        assert by_name[stem]["status"] == "done"
        assert folder_state(out / stem, PUBLISHED_FILES).complete
        expected = published_bytes(folder)
        assert {"results.npz", "results.json"} <= set(expected)
        assert published_bytes(out / stem) == expected, stem
        if cached:
            assert by_name[stem]["nodes_ran"] == 0 and by_name[stem]["nodes_cached"] > 0
        else:
            assert by_name[stem]["nodes_ran"] > 0
    assert not list(out.glob(f".{SUMMARY}.*"))  # the summary was written atomically
    return summary


def test_inputs_from_folders_lists_and_files(tmp_path):
    for rel in ("x/one.mp4", "x/sub/two.MOV", "x/notes.md", "y/three.mkv"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_bytes(b"")
    listing = tmp_path / "list.txt"
    listing.write_text("# my shoot\ny/three.mkv\n\nx   # and a folder, again\n")
    found = collect_videos([tmp_path / "x" / "one.mp4", listing])
    assert found == [(tmp_path / p).resolve() for p in ("x/one.mp4", "y/three.mkv", "x/sub/two.MOV")]
    with pytest.raises(ValueError, match="not found: .*missing.mp4 \\(listed in"):
        listing.write_text("missing.mp4\n")
        collect_videos([listing])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="holds no video files"):
        collect_videos([tmp_path / "empty"])


def test_colliding_stems_get_distinct_stable_names(tmp_path):
    paths = [tmp_path / p for p in ("shoot/a/clip.mp4", "shoot/b/clip.mp4", "shoot/c/take.mp4", "shoot/c/take.mov")]
    names = result_names(paths)
    assert names == {paths[0]: "a__clip", paths[1]: "b__clip", paths[2]: "take_mp4", paths[3]: "take_mov"}
    assert result_names([paths[0], tmp_path / "x.mp4"]) == {paths[0]: "clip", tmp_path / "x.mp4": "x"}
    with pytest.raises(ValueError, match="share the result folder 'a__clip'"):
        result_names(paths[:2] + [tmp_path / "a__clip.mp4"])


@needs_mediapipe
@pytest.mark.slow
def test_sequential_batch_reports_the_failure_and_reuses_the_cache(videos, reference, tmp_path, capsys):
    out = tmp_path / "batch"
    assert main(["batch", str(videos), "--out", str(out), "--sequential", "--no-progress", "-q"]) == 1
    printed = capsys.readouterr().out
    assert "2 of 3 video(s) done, 1 failed" in printed and "broken  failed" in printed
    assert check_batch(out, reference, cached=False)["engine"] == "sequential"
    assert main(["batch", str(videos), "--out", str(out), "--sequential", "--no-progress", "-q"]) == 1
    check_batch(out, reference, cached=True)


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray", reason="needs Ray (pip install 'm3c[batch]')")
    # address="local": a new instance of the test's own, even when another Ray runs on this machine.
    start_local_ray(num_cpus=2, logging_level="WARNING", log_to_driver=False)  # as m3c batch starts it
    yield ray
    ray.shutdown()


@needs_mediapipe
@pytest.mark.slow
def test_ray_batch_matches_m3c_run_and_reuses_the_cache(videos, reference, tmp_path, local_ray):
    out = tmp_path / "batch"
    config = PipelineConfig.default()
    report = run_batch(config, collect_videos([videos]), out, cpus_per_video=1, memory_per_video_gb=0.5,
                       show_progress=False, setup=register_builtin_nodes)
    assert report.engine.startswith("ray")
    assert [o.name for o in report.failed] == ["broken"]
    summary = check_batch(out, reference, cached=False)
    assert summary["engine"] == report.engine
    run_batch(config, collect_videos([videos]), out, cpus_per_video=1, memory_per_video_gb=0.5, show_progress=False,
              setup=register_builtin_nodes)
    check_batch(out, reference, cached=True)


def test_ray_request_no_node_can_hold_is_refused(videos, tmp_path, local_ray):
    with pytest.raises(ValueError, match="no Ray node .* can run one video.*Lower --cpus-per-video"):
        run_batch(PipelineConfig.default(), [videos / "broken.mp4"], tmp_path / "out", cpus_per_video=64,
                  show_progress=False, setup=register_builtin_nodes)


def start_batch(videos: Path, out: Path, *extra: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([PYTHON_DIR, os.environ.get("PYTHONPATH", "")]))
    return subprocess.Popen([sys.executable, "-m", "m3c", "batch", str(videos), "--out", str(out), "--no-progress",
                             "-q", *extra], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def descendants(pid: int) -> list[int]:
    """Every process started by `pid`, its children's children included (from /proc: Linux)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError):
            fields = stat.read_text().rsplit(")", 1)[1].split()
            parents[int(stat.parent.name)] = int(fields[1])
    found, frontier = [], [pid]
    while frontier:
        children = [p for p, parent in parents.items() if parent in frontier]
        found += children
        frontier = children
    return found


def wait_for(predicate, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert proc.poll() is None, "the batch ended before the moment to kill it"
        assert time.monotonic() < end, "timed out waiting for the moment to kill the batch"
        time.sleep(0.01)


@needs_mediapipe
@pytest.mark.slow
def test_batch_killed_mid_video_resumes_to_identical_results(videos, reference, tmp_path):
    out = tmp_path / "batch"
    proc = start_batch(videos, out, "--sequential")
    try:
        # Videos run in sorted order (broken, walk_a, walk_b): kill while walk_b is half done (a node entry
        # committed, later ones not).
        entries = out / "walk_b" / "cache" / "perception"
        wait_for(lambda: entries.is_dir() and any(p.name[0] != "." for p in entries.iterdir()), proc)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / SUMMARY).exists()
    assert not folder_state(out / "walk_b", PUBLISHED_FILES).complete

    assert main(["batch", str(videos), "--out", str(out), "--sequential", "--no-progress", "-q"]) == 1
    summary = json.loads((out / SUMMARY).read_text())
    by_name = {v["name"]: v for v in summary["videos"]}
    assert by_name["walk_a"]["nodes_ran"] == 0  # finished before the kill
    assert by_name["walk_b"]["nodes_cached"] > 0 and by_name["walk_b"]["nodes_ran"] > 0  # resumed
    for stem, folder in reference.items():
        assert published_bytes(out / stem) == published_bytes(folder), stem


def test_a_video_asks_for_the_most_any_node_needs():
    """One video's request is the largest cores and the largest memory among its nodes' needs (nodes run one after
    another), each node's from its config entry when it declares one, else from its type."""
    config = PipelineConfig.default()
    declared = [Needs.from_dict(entry.needs, name) if entry.needs else node_type(entry.type).needs
                for name, entry in config.nodes.items()]
    needs = video_needs(config)
    assert (needs.cpus, needs.memory_gb) == (max(n.cpus for n in declared), max(n.memory_gb for n in declared))
    assert any(entry.needs for entry in config.nodes.values())  # the default pipeline declares its needs
    raw = config.to_mapping()
    raw["nodes"]["camera"]["needs"] = {"cpus": 7, "memory_gb": 11.5}
    assert video_needs(PipelineConfig.from_mapping(raw)) == Needs(7.0, 11.5)
    assert PipelineConfig.from_mapping(raw).to_mapping()["nodes"]["camera"]["needs"] == {"cpus": 7, "memory_gb": 11.5}
    raw["nodes"]["camera"]["needs"] = {"cpus": 0}
    with pytest.raises(PipelineError, match="node 'camera'.*needs.cpus must be a number > 0"):
        PipelineConfig.from_mapping(raw)
    raw["nodes"]["camera"]["needs"] = {"gpus": 1}
    with pytest.raises(PipelineError, match="'needs' must be a mapping with cpus and/or memory_gb"):
        PipelineConfig.from_mapping(raw)


def test_ray_is_asked_for_the_nodes_needs(videos, tmp_path, local_ray):
    """Without --cpus-per-video / --memory-per-video the Ray request is the pipeline's: a node needing more cores
    than this 2-CPU instance has makes the batch refuse to start, naming that request."""
    raw = PipelineConfig.default().to_mapping()
    raw["nodes"]["optimize"]["needs"] = {"cpus": 3, "memory_gb": 9.5}
    config = PipelineConfig.from_mapping(raw)
    with pytest.raises(ValueError, match=r"each asks for 3 CPU\(s\), 9.5 GB"):
        run_batch(config, [videos / "broken.mp4"], tmp_path / "out", show_progress=False)


@needs_mediapipe
@pytest.mark.slow
def test_ray_batch_killed_mid_video_resumes_to_identical_results(videos, reference, tmp_path):
    """`m3c batch` on Ray (its own local instance) killed, with Ray's processes, while a video is half done; re-running the batch resumes it from its cache, and every result file is
    byte-identical to an uninterrupted run's. (batch_summary.json is not compared: it records each run's times and
    worker ids, and which nodes ran or came from the cache.)"""
    pytest.importorskip("ray", reason="needs Ray (pip install 'm3c[batch]')")
    out = tmp_path / "batch"
    # One video at a time (2 CPUs each on this 2-CPU instance), in sorted order: broken, walk_a, walk_b.
    proc = start_batch(videos, out, "--cpus-per-video", "2", "--memory-per-video", "0.5")
    try:
        entries = out / "walk_b" / "cache" / "perception"
        wait_for(lambda: entries.is_dir() and any(p.name[0] != "." for p in entries.iterdir()), proc, 240.0)
        # The driver and everything it started: Ray's services and its workers (which Ray puts in sessions of
        # their own), killed at once as a machine failure would.
        for pid in [proc.pid, *descendants(proc.pid)]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not (out / SUMMARY).exists()
    assert not folder_state(out / "walk_b", PUBLISHED_FILES).complete

    resumed = start_batch(videos, out, "--cpus-per-video", "2", "--memory-per-video", "0.5")
    assert resumed.wait(timeout=600) == 1  # the broken video fails again
    summary = json.loads((out / SUMMARY).read_text())
    assert summary["engine"].startswith("ray")
    by_name = {v["name"]: v for v in summary["videos"]}
    assert by_name["walk_a"]["nodes_ran"] == 0  # finished before the kill
    assert by_name["walk_b"]["nodes_cached"] > 0 and by_name["walk_b"]["nodes_ran"] > 0  # resumed
    for stem, folder in reference.items():
        assert published_bytes(out / stem) == published_bytes(folder), stem


def test_without_ray_the_batch_runs_here_and_says_so(videos, tmp_path, monkeypatch, caplog):
    monkeypatch.setattr("m3c.pipeline.batch.ray_available", lambda: False)
    with caplog.at_level("WARNING", logger="m3c.batch"):
        report = run_batch(PipelineConfig.default(), [videos / "broken.mp4"], tmp_path / "out", show_progress=False)
    assert "Ray is not installed" in caplog.text and "one after another" in caplog.text
    assert report.engine == "sequential" and [o.name for o in report.failed] == ["broken"]
    with pytest.raises(ImportError, match="--address needs Ray"):
        run_batch(PipelineConfig.default(), [videos / "broken.mp4"], tmp_path / "out", address="10.0.0.1:6379")
