"""`m3c eval benchmark | 3dpw | retarget` through the command line."""

import json

import numpy as np
import pytest

from m3c.cli import main
from m3c.motion import OptimizerConfig


def test_eval_benchmark_cli(tmp_path, capsys):
    config = OptimizerConfig.default()
    config.stages = config.stages[:2]
    yaml_path = tmp_path / "opt.yaml"
    yaml_path.write_text(config.to_yaml())
    out = tmp_path / "bench.json"
    assert main(["eval", "benchmark", "--sequences", "1", "--frames", "24", "--max-people", "1", "--quiet",
                 "--optimizer-config", str(yaml_path), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Global Opt" in text and "seq00_walking^1" in text
    summary = json.loads(out.read_text())
    assert summary["config"]["num_frames"] == 24
    assert summary["methods"]["Local"]["pa_mpjpe"] > 0


def test_eval_3dpw_cli(tmp_path, capsys, synthetic_model_data, rng):
    from test_eval_threedpw_eval import make_dataset, write_predictions

    from m3c.body import BodyModel

    data = synthetic_model_data
    model_path = tmp_path / "model.npz"
    np.savez(model_path, v_template=data.v_template, shapedirs=data.shapedirs, posedirs=data.posedirs,
             J_regressor=data.J_regressor, weights=data.weights,
             kintree_table=np.stack([data.parents, np.arange(data.num_joints)]), f=data.faces)
    model = BodyModel.from_file(model_path)
    truth = make_dataset(tmp_path / "3DPW", model, rng, people_per_seq=(1,))
    for name, (people, world_from_cam) in truth.items():
        p = people[0]
        write_predictions(tmp_path / "pred", name, [(np.arange(12), p["pose"], p["betas"], p["transl"])],
                          world_from_cam)
    out = tmp_path / "pw.json"
    assert main(["eval", "3dpw", str(tmp_path / "3DPW"), "--results", f"Mine={tmp_path / 'pred'}", "--quiet",
                 "--smpl-neutral", str(model_path), "--smpl-male", str(model_path), "--smpl-female",
                 str(model_path), "--json", str(out)]) == 0
    assert "downtown_fake_00^1" in capsys.readouterr().out
    summary = json.loads(out.read_text())
    assert summary["joints"] == "SMPL-24"
    assert summary["methods"]["Mine"]["mpjpe"] == pytest.approx(0.0, abs=1e-6)


def test_eval_cli_errors(capsys):
    assert main(["eval", "3dpw", "/nonexistent", "--results", "no-equals-sign", "--smpl-neutral", "a",
                 "--smpl-male", "b", "--smpl-female", "c"]) == 2
    assert "METHOD=FOLDER" in capsys.readouterr().err
    assert main(["eval", "retarget", "/nonexistent.bvh", "/tmp/x.npz"]) == 2
    assert "BVH file not found" in capsys.readouterr().err


def test_provenance_commit_is_the_repository_that_tracks_the_source(tmp_path):
    """A benchmark JSON names the commit of M3C's own checkout; a file that a repository merely contains (an
    installed M3C under a pyenv clone) gets no commit, a tracked one gets that repository's HEAD."""
    import shutil
    import subprocess

    from m3c.cli.common import source_commit

    if shutil.which("git") is None:
        pytest.skip("git is not installed")

    def git(*args):
        return subprocess.run(["git", "-C", str(tmp_path), "-c", "user.name=t", "-c", "user.email=t@t", *args],
                              check=True, capture_output=True, text=True).stdout.strip()

    git("init", "-q")
    (tmp_path / "other.txt").write_text("the repository's own file\n")
    git("add", "other.txt")
    git("commit", "-q", "-m", "one")
    source = tmp_path / "site-packages" / "m3c" / "common.py"
    source.parent.mkdir(parents=True)
    source.write_text("# an untracked copy\n")
    assert source_commit(source) is None
    git("add", str(source))
    git("commit", "-q", "-m", "two")
    assert source_commit(source) == git("rev-parse", "--short", "HEAD")
    source.write_text("# edited\n")
    assert source_commit(source) == git("rev-parse", "--short", "HEAD") + "+changes"
    assert source_commit(tmp_path.parent / "nowhere" / "x.py") is None
