"""results.json's `priors`: which learned priors shaped the bodies (the per-frame fit's, the optimizer's stages)
and the non-commercial licence whenever one of M3C's shipped priors ran."""

from m3c.nodes.results import SHIPPED_PRIOR_LICENCE, priors_summary

STAGES = [{"name": "shape", "status": "ok"},
          {"name": "pose_prior", "status": "skipped", "message": "pose_prior unavailable"},
          {"name": "motion_prior", "status": "reverted", "message": "the world check rose 9%"}]


def test_default_run_and_the_shipped_fit_prior():
    default = priors_summary({"perception": {"type": "perception", "estimators": {}}}, STAGES)
    assert default["body_fit"]["pose_prior"] == "none" and default["licence"] is None
    shipped = {"body": {"name": "fit", "options": {"pose_prior": "shipped"}}}
    out = priors_summary({"perception": {"type": "perception", "estimators": shipped}}, STAGES)
    assert out["body_fit"] == {"pose_prior": "shipped", "vposer_weight": 2.0}
    assert out["stages"] == {"pose_prior": {"status": "skipped", "message": "pose_prior unavailable"},
                             "motion_prior": {"status": "reverted", "message": "the world check rose 9%"}}
    assert out["licence"] == SHIPPED_PRIOR_LICENCE and "non-commercial" in out["licence"]


def test_no_shipped_prior_no_licence():
    backends = {"perception": {"estimators": {"body": {"name": "fit", "options": {"pose_prior": "none"}}}},
                "optimize": {"type": "optimize", "pose_prior": None, "motion_prior": "none"}}
    out = priors_summary(backends, STAGES)
    assert out["body_fit"]["pose_prior"] == "none" and out["licence"] is None
    hmr = priors_summary({"perception": {"estimators": {"body": "hmr2"}},
                          "optimize": {"motion_prior": "shipped"}}, STAGES)
    assert hmr["body_fit"] is None and hmr["licence"] == SHIPPED_PRIOR_LICENCE


def test_a_missing_fit_pose_prior_is_refused_before_any_node_runs(tmp_path, capsys):
    from pathlib import Path

    from m3c.cli import main

    clip = Path(__file__).resolve().parents[2] / "examples" / "pexels_walking_moving_camera.mp4"
    out = tmp_path / "out"
    setting = 'perception.estimators={"body": {"name": "fit", "options": {"pose_prior": "/nope.safetensors"}}}'
    code = main(["run", str(clip), "--out", str(out), "--set", setting])
    assert code != 0 and not out.exists()
    assert "the body fit's pose_prior: /nope.safetensors does not exist" in capsys.readouterr().err
