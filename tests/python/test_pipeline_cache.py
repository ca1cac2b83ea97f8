"""The node cache: reuse when nothing changed, re-running exactly the dependents of a changed setting, model
load/unload around each node, failures that leave no partial entries, and a run killed (SIGKILL) at any
point that resumes to byte-identical outputs."""

import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pipeline_test_nodes import ModelNode, pipeline_yaml

import m3c
from m3c.pipeline import PipelineConfig, PipelineError, run_pipeline

TESTS_DIR = Path(__file__).resolve().parent
# The subprocess imports the same m3c as this process (the source tree in development, the installed package
# in CI).
PYTHON_DIR = Path(m3c.__file__).resolve().parents[1]


def run(config, out):
    return run_pipeline(config, out, show_progress=False)


def ran_nodes(log_path: Path) -> list[str]:
    names = log_path.read_text().split() if log_path.exists() else []
    log_path.unlink(missing_ok=True)
    return names


@pytest.fixture
def run_log(tmp_path, monkeypatch):
    path = tmp_path / "ran.txt"
    monkeypatch.setenv("M3C_TEST_RUN_LOG", str(path))
    return path


def tree_bytes(folder: Path) -> dict[str, bytes]:
    """Every file under folder (relative path -> bytes), without the run's bookkeeping (run log, lock, and the
    entries' meta.json, which records how long each node took)."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and p.name not in {"last_run.json", ".lock", "meta.json"}}


def test_second_run_reuses_everything(tmp_path, run_log):
    config = PipelineConfig.from_yaml(pipeline_yaml())
    first = run(config, tmp_path / "out")
    assert set(first.ran()) == {"source", "other", "slow_a", "slow_b", "total", "report"}
    assert sorted(ran_nodes(run_log)) == sorted(first.ran())
    before = tree_bytes(tmp_path / "out")
    second = run(config, tmp_path / "out")
    assert second.ran() == [] and set(second.status().values()) == {"cached"}
    assert ran_nodes(run_log) == []
    assert tree_bytes(tmp_path / "out") == before
    # Published files are the cached ones.
    values = np.load(tmp_path / "out" / "arrays.npz")["values"]
    assert values.shape == (6,) and values.dtype == np.float32


@pytest.mark.parametrize("override, expected", [
    ({"slow_a.scale": 2.0}, {"slow_a", "slow_b", "total", "report"}),
    ({"slow_b.steps": 5}, {"slow_b", "total", "report"}),
    ({"other.seed": 9}, {"other", "total", "report"}),
    ({"report.fail": False}, set()),  # the default value written out: same config, same key
    ({"settings.device": "cpu:0"}, set()),  # no node reads the device
])
def test_changed_setting_reruns_exactly_its_dependents(tmp_path, run_log, override, expected):
    config = PipelineConfig.from_yaml(pipeline_yaml())
    run(config, tmp_path / "out")
    ran_nodes(run_log)
    report = run(config.with_overrides(override), tmp_path / "out")
    assert set(report.ran()) == expected
    assert set(ran_nodes(run_log)) == expected
    # Switching back reuses the earlier entries: nothing runs.
    assert run(config, tmp_path / "out").ran() == []


def test_changed_result_changes_published_files(tmp_path):
    config = PipelineConfig.from_yaml(pipeline_yaml())
    run(config, tmp_path / "out")
    a = (tmp_path / "out" / "report.txt").read_text()
    run(config.with_overrides({"source.seed": 11}), tmp_path / "out")
    b = (tmp_path / "out" / "report.txt").read_text()
    assert a != b
    run(config, tmp_path / "out")
    assert (tmp_path / "out" / "report.txt").read_text() == a


def test_code_version_enters_the_key(tmp_path, monkeypatch, run_log):
    from pipeline_test_nodes import SlowNode

    config = PipelineConfig.from_yaml(pipeline_yaml())
    run(config, tmp_path / "out")
    ran_nodes(run_log)
    monkeypatch.setattr(SlowNode, "version", "2")
    assert set(run(config, tmp_path / "out").ran()) == {"slow_a", "slow_b", "total", "report"}


def test_models_are_loaded_only_while_their_node_runs(tmp_path):
    ModelNode.events.clear()
    config = PipelineConfig.from_yaml("""
nodes:
  source: {type: t_source}
  m1: {type: t_model, inputs: {x: source.data}}
  m2: {type: t_model, inputs: {x: m1.data}}
""")
    run(config, tmp_path / "out")
    assert ModelNode.events == [("load", "m1"), ("run", "m1", True), ("unload", "m1"),
                                ("load", "m2"), ("run", "m2", True), ("unload", "m2")]


def test_failing_node_leaves_no_entry_and_no_published_file(tmp_path):
    config = PipelineConfig.from_yaml(pipeline_yaml()).with_overrides({"report.fail": True})
    with pytest.raises(RuntimeError, match="told to fail"):
        run(config, tmp_path / "out")
    out = tmp_path / "out"
    assert not (out / "report.txt").exists() and not (out / "arrays.npz").exists()
    assert not list((out / "cache").glob("*/.tmp-*"))
    assert not (out / "cache" / "report").exists() or not any((out / "cache" / "report").iterdir())
    # The nodes before it are cached: fixing the failure runs only the report.
    assert run(config.with_overrides({"report.fail": False}), out).ran() == ["report"]


def test_failure_before_anything_committed_leaves_no_output_folder(tmp_path):
    config = PipelineConfig.from_yaml("nodes:\n  s: {type: t_source, config: {fail: true}}\n"
                                      "  r: {type: t_report, inputs: {x: s.data}}")
    with pytest.raises(RuntimeError, match="told to fail"):
        run(config, tmp_path / "new")
    assert not (tmp_path / "new").exists()
    # A folder that existed before the run is never removed.
    (tmp_path / "existing").mkdir()
    with pytest.raises(RuntimeError, match="told to fail"):
        run(config, tmp_path / "existing")
    assert (tmp_path / "existing").is_dir() and not list((tmp_path / "existing" / "cache").glob("*/*"))


def test_second_concurrent_run_is_refused(tmp_path):
    import fcntl

    out = tmp_path / "out"
    (out / "cache").mkdir(parents=True)
    with open(out / "cache" / ".lock", "w") as fh:
        fcntl.flock(fh, fcntl.LOCK_EX)
        with pytest.raises(PipelineError, match="another m3c run"):
            run(PipelineConfig.from_yaml(pipeline_yaml()), out)


RUNNER_SCRIPT = """
import sys
sys.path[:0] = [{python!r}, {tests!r}]
import pipeline_test_nodes
from m3c.pipeline import PipelineConfig, run_pipeline
run_pipeline(PipelineConfig.from_yaml({yaml!r}), {out!r}, show_progress=False)
"""


def start_run(out: Path, delay: float) -> subprocess.Popen:
    script = RUNNER_SCRIPT.format(python=str(PYTHON_DIR), tests=str(TESTS_DIR), yaml=pipeline_yaml(delay),
                                  out=str(out))
    return subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait_for(predicate, timeout: float = 60.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > end:
            raise TimeoutError
        time.sleep(0.005)


@pytest.mark.slow
@pytest.mark.parametrize("kill_point", ["slow_a", "slow_b", "after_slow_b"])
def test_killed_run_resumes_to_identical_outputs(tmp_path, kill_point):
    reference = tmp_path / "reference"
    run(PipelineConfig.from_yaml(pipeline_yaml(0.02)), reference)
    expected = tree_bytes(reference)

    out = tmp_path / "out"
    proc = start_run(out, delay=0.02)
    try:
        cache = out / "cache"
        if kill_point == "after_slow_b":
            # Killed right after slow_b committed (while total/report run or are about to).
            wait_for(lambda: any((cache / "slow_b").glob("[0-9a-f]*")) if (cache / "slow_b").is_dir() else False)
        else:
            # Killed in the middle of the node's work: its temporary entry exists, the node is sleeping.
            wait_for(lambda: any((cache / kill_point).glob(".tmp-*")) if (cache / kill_point).is_dir() else False)
            time.sleep(0.1)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.wait(timeout=60)
    assert proc.returncode == -signal.SIGKILL
    if kill_point != "after_slow_b":
        assert list(cache.glob(f"{kill_point}/.tmp-*")), "the kill should leave an unfinished entry behind"
        assert not (out / "report.txt").exists()

    report = run(PipelineConfig.from_yaml(pipeline_yaml(0.02)), out)
    assert "source" not in report.ran()  # finished work is reused
    assert not list(cache.glob("*/.tmp-*"))
    assert tree_bytes(out) == expected


@pytest.mark.slow
def test_run_killed_at_a_sweep_of_moments_resumes_to_identical_outputs(tmp_path):
    reference = tmp_path / "reference"
    run(PipelineConfig.from_yaml(pipeline_yaml(0.02)), reference)
    expected = tree_bytes(reference)
    # Moments from the start of slow_a (each slow node takes ~0.24 s) through the commits and publishing of the
    # last nodes and the run report (a run killed while writing the report once left its temporary file).
    for i, offset in enumerate([0.0, 0.07, 0.13, 0.2, 0.26, 0.33, 0.4, 0.47, 0.53, 0.58, 0.63, 0.68, 0.75]):
        out = tmp_path / f"out{i}"
        proc = start_run(out, delay=0.02)
        try:
            slow_a = out / "cache" / "slow_a"
            wait_for(lambda: slow_a.is_dir() and any(slow_a.iterdir()))
            time.sleep(offset)
            proc.send_signal(signal.SIGKILL)
        finally:
            proc.wait(timeout=60)
        run(PipelineConfig.from_yaml(pipeline_yaml(0.02)), out)
        assert tree_bytes(out) == expected, f"killed {offset} s into slow_a"
