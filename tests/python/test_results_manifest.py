"""A result folder is published as a whole: the manifest written last vouches for one run's files, and a re-run
that fails, is killed (SIGKILL, also in the middle of publishing) or is still running never leaves the earlier
run's files looking current; `m3c info` and the loaders say which state the folder is in."""

import hashlib
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pipeline_test_nodes import pipeline_yaml

import m3c
from m3c.cli import main
from m3c.io.manifest import MANIFEST, IncompleteResults, check_complete, folder_state, read_manifest, seal
from m3c.io.results import load_results
from m3c.pipeline import PipelineConfig, run_pipeline

TESTS_DIR = Path(__file__).resolve().parent
PYTHON_DIR = Path(m3c.__file__).resolve().parents[1]
FILES = ("report.txt", "arrays.npz", "note.txt")
WITH_NOTE = pipeline_yaml() + "  note:\n    type: t_note\n    inputs: {x: slow_b.data}\n"


def run(yaml_text, out, **overrides):
    config = PipelineConfig.from_yaml(yaml_text)
    return run_pipeline(config.with_overrides(overrides) if overrides else config, out, show_progress=False)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_complete_run_is_vouched_for_file_by_file(tmp_path):
    out = tmp_path / "out"
    report = run(WITH_NOTE, out)
    manifest = read_manifest(out)
    assert manifest["status"] == "complete" and sorted(manifest["files"]) == sorted(FILES)
    keys = {r.name: r.key for r in report.records}
    for name, entry in manifest["files"].items():
        assert entry["sha256"] == sha256(out / name) and entry["size"] == (out / name).stat().st_size
        assert entry["key"] == keys[entry["node"]]
    assert folder_state(out).complete
    # Changing a file afterwards is noticed.
    (out / "report.txt").write_text("edited\n")
    state = folder_state(out)
    assert state.status == "modified" and "report.txt was changed" in state.message
    with pytest.raises(IncompleteResults, match="report.txt was changed"):
        check_complete(out, ("report.txt",))


def test_failing_rerun_marks_the_old_files_stale(tmp_path):
    out = tmp_path / "out"
    run(pipeline_yaml(), out)
    before = (out / "report.txt").read_bytes()
    with pytest.raises(RuntimeError, match="told to fail"):
        run(pipeline_yaml(), out, **{"source.seed": 11, "report.fail": True})
    state = folder_state(out)
    assert state.status == "failed" and "told to fail" in state.message and "stale" in state.message
    assert (out / "report.txt").read_bytes() == before  # kept, but no longer vouched for
    with pytest.raises(IncompleteResults, match="failed"):
        check_complete(out, ("report.txt",))
    # Fixing the failure publishes the new run's files and vouches for them.
    run(pipeline_yaml(), out, **{"source.seed": 11})
    assert folder_state(out).complete and (out / "report.txt").read_bytes() != before


def test_rerun_of_fewer_nodes_keeps_current_files_and_drops_other_runs(tmp_path):
    out = tmp_path / "out"
    run(WITH_NOTE, out)
    note = (out / "note.txt").read_bytes()
    # Same settings, only the report: note.txt is still this configuration's and stays vouched for.
    config = PipelineConfig.from_yaml(WITH_NOTE)
    run_pipeline(config, out, targets=["report"], show_progress=False)
    assert folder_state(out).complete and sorted(read_manifest(out)["files"]) == sorted(FILES)
    assert (out / "note.txt").read_bytes() == note
    # Other settings, only the report: the old note.txt belongs to another run and is removed.
    run_pipeline(config.with_overrides({"slow_a.scale": 3.0}), out, targets=["report"], show_progress=False)
    assert folder_state(out).complete and sorted(read_manifest(out)["files"]) == ["arrays.npz", "report.txt"]
    assert not (out / "note.txt").exists()


CHILD = """
import os, signal, sys
sys.path[:0] = [{python!r}, {tests!r}]
import pipeline_test_nodes
from m3c.pipeline import PipelineConfig, run_pipeline
from m3c.pipeline import runner
if {kill_after_renames}:
    real_replace, count = os.replace, [0]
    def replace(src, dst):
        real_replace(src, dst)
        if "/.publish-" in str(src):  # a published file moved into place
            count[0] += 1
            if count[0] == {kill_after_renames}:
                os.kill(os.getpid(), signal.SIGKILL)
    runner.os.replace = replace
config = PipelineConfig.from_yaml({yaml!r}).with_overrides({overrides!r})
run_pipeline(config, {out!r}, show_progress=False)
"""


def start_child(out: Path, yaml_text: str, overrides: dict, kill_after_renames: int = 0) -> subprocess.Popen:
    script = CHILD.format(python=str(PYTHON_DIR), tests=str(TESTS_DIR), yaml=yaml_text, overrides=overrides,
                          out=str(out), kill_after_renames=kill_after_renames)
    return subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def test_rerun_killed_mid_publish_is_reported_and_finished_by_the_next_run(tmp_path):
    out = tmp_path / "out"
    run(WITH_NOTE, out)
    old = {name: (out / name).read_bytes() for name in FILES}
    # A re-run with other settings is killed after the first of its three files was renamed into place.
    proc = start_child(out, WITH_NOTE, {"source.seed": 11}, kill_after_renames=1)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGKILL, err
    now = {name: (out / name).read_bytes() for name in FILES}
    assert sum(now[n] != old[n] for n in FILES) == 1  # half published: one new file beside two old ones
    state = folder_state(out)
    assert state.status == "interrupted" and "stopped before it finished" in state.message
    assert state.manifest["previous"]["run_key"]
    code = main(["info", str(out)])
    assert code == 2
    # The same command again finishes it: every file is the new run's, as a run that was never killed gives.
    run(WITH_NOTE, out, **{"source.seed": 11})
    reference = tmp_path / "reference"
    run(WITH_NOTE, reference, **{"source.seed": 11})
    assert folder_state(out).complete
    assert {n: (out / n).read_bytes() for n in FILES} == {n: (reference / n).read_bytes() for n in FILES}
    assert (out / MANIFEST).read_bytes() == (reference / MANIFEST).read_bytes()
    assert not list(out.glob(".publish-*"))


def test_rerun_killed_while_computing_leaves_the_folder_marked(tmp_path):
    out = tmp_path / "out"
    run(pipeline_yaml(0.02), out)
    proc = start_child(out, pipeline_yaml(0.02), {"source.seed": 11})
    try:
        deadline = time.monotonic() + 60
        while read_manifest(out)["status"] != "running":
            assert time.monotonic() < deadline
            time.sleep(0.01)
        assert folder_state(out).status == "running"  # the child holds the run lock
        time.sleep(0.1)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate(timeout=60)
    state = folder_state(out)
    assert state.status == "interrupted"
    with pytest.raises(IncompleteResults, match="stale"):
        check_complete(out, ("report.txt",))


def test_loaders_check_the_manifest(tmp_path):
    from m3c.io.results import ARRAYS, SCHEMA

    folder = tmp_path / "results"
    folder.mkdir()
    np.savez(folder / "results.npz", frame_ids=np.arange(3))
    (folder / "results.json").write_text(json.dumps({"schema": SCHEMA}))
    with pytest.raises(IncompleteResults, match="without manifest.json"):
        load_results(folder)
    summary, arrays = load_results(folder, check=False)  # read anyway when asked to
    assert summary["schema"] == SCHEMA and list(arrays) == ["frame_ids"]
    seal(folder, ["results.npz", "results.json"])
    assert load_results(folder)[0]["schema"] == SCHEMA
    assert set(ARRAYS) >= {"frame_ids"}


def test_rerun_refused_before_it_starts_marks_the_folder_stale(tmp_path, capsys):
    out = tmp_path / "out"
    run(pipeline_yaml(), out)
    config = tmp_path / "pipeline.yaml"
    config.write_text(pipeline_yaml())
    # A bad setting: the command fails before anything runs, but the folder no longer holds its results.
    code = main(["run", str(config), "--out", str(out), "--config", str(config), "--set", "source.nope=1"])
    assert code == 2 and "unknown setting" in capsys.readouterr().err
    state = folder_state(out)
    assert state.status == "failed" and "unknown setting" in state.message
    assert state.manifest["previous"]["files"]["report.txt"]["sha256"] == sha256(out / "report.txt")
    # The same command as before makes it complete again (everything is cached).
    assert run(pipeline_yaml(), out).ran() == [] and folder_state(out).complete
