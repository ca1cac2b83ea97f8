"""The estimator registry and the perception config: selection by name, options, errors, round trips."""

import pytest

from m3c.perception import TASKS, PerceptionConfig, available, create, register
from m3c.perception.interfaces import Detector, GenderEstimator
from m3c.perception.pipeline import DEFAULT_ESTIMATORS


def test_every_task_has_its_default_registered():
    for task in TASKS:
        assert DEFAULT_ESTIMATORS[task] in available(task)
    assert "hog" in available("detector")


def test_simple_estimators_and_options():
    assert create("gender", "neutral").estimate(3, []) == "neutral"
    given = create("gender", "given", {"genders": {3: "female"}})
    assert given.name == "given"
    assert given.estimate(3, []) == "female" and given.estimate(4, []) == "neutral"
    assert create("depth", "none").estimate(None) is None
    with pytest.raises(ValueError, match="gender must be one of"):
        create("gender", "given", {"genders": {1: "robot"}})


def test_unknown_names_and_options_are_explained():
    with pytest.raises(ValueError, match="no detector estimator named 'yolo'; available: hog, mediapipe"):
        create("detector", "yolo")
    with pytest.raises(ValueError, match="unknown option.*colour.*takes: genders, default"):
        create("gender", "given", {"colour": "red"})
    with pytest.raises(ValueError, match="unknown task"):
        available("teleport")


def test_custom_estimators_register_and_must_implement_the_interface():
    @register("gender", "test_always_male")
    class AlwaysMale(GenderEstimator):
        def estimate(self, track_id, people):
            return "male"

    assert create("gender", "test_always_male").estimate(0, []) == "male"

    @register("detector", "test_not_a_detector")
    class NotADetector(GenderEstimator):
        def estimate(self, track_id, people):
            return "male"

    with pytest.raises(TypeError, match="must implement Detector"):
        create("detector", "test_not_a_detector")
    with pytest.raises(ValueError, match="already registered"):
        register("gender", "test_always_male")(type("Other", (AlwaysMale,), {}))
    assert issubclass(Detector, object)


def test_run_settings_reach_the_estimators_that_take_them(monkeypatch):
    """The patches' padding is one setting of the run (PerceptionConfig.padding): an estimator that takes a padding
    gets it unless its own options set one; one that takes none is built as before."""
    @register("gender", "test_padded")
    class Padded(GenderEstimator):
        def __init__(self, padding: float = 5.0):
            self.padding = padding

        def estimate(self, track_id, people):
            return "neutral"

    assert create("gender", "test_padded", defaults={"padding": 8.0}).padding == 8.0
    assert create("gender", "test_padded", {"padding": 2.0}, defaults={"padding": 8.0}).padding == 2.0
    assert create("gender", "neutral", defaults={"padding": 8.0}).estimate(0, []) == "neutral"
    import m3c.perception.pipeline as pipeline

    built = {}
    real_create = pipeline.create
    monkeypatch.setattr(pipeline, "create", lambda task, name, options, shared, defaults=None: built.setdefault(
        task, defaults) and real_create(task, name, options, shared, defaults=defaults))
    result = pipeline.run_perception_frames(iter([]), 30.0, (64, 64), PerceptionConfig.from_dict({"padding": 8.0}))
    assert result.num_frames == 0 and set(built) == set(TASKS)
    assert all(d == {"padding": 8.0} for d in built.values())
    with pytest.raises(ValueError, match="padding must be a finite number of pixels >= 0"):
        PerceptionConfig.from_dict({"padding": -1.0})


def test_config_from_dict_yaml_round_trip(tmp_path):
    cfg = PerceptionConfig.from_dict({"detector": "hog", "pose2d": {"name": "mediapipe", "options": {"patch_pass":
                                                                                                      "always"}},
                                      "tracker": {"max_age": 12}, "detect_every": 3, "intrinsics": [1, 2, 3, 4]})
    assert cfg.estimators["detector"].name == "hog" and cfg.estimators["segmenter"].name == "mediapipe"
    assert cfg.estimators["pose2d"].options == {"patch_pass": "always"}
    assert cfg.tracker.max_age == 12 and cfg.detect_every == 3
    again = PerceptionConfig.from_dict(cfg.to_dict())
    assert again.to_dict() == cfg.to_dict()
    import yaml

    path = tmp_path / "perception.yaml"
    path.write_text(yaml.safe_dump(cfg.to_dict()))
    assert PerceptionConfig.from_yaml(path).to_dict() == cfg.to_dict()
    with pytest.raises(ValueError, match="unknown perception setting"):
        PerceptionConfig.from_dict({"detectr": "hog"})
    with pytest.raises(ValueError, match="give an estimator name"):
        PerceptionConfig.from_dict({"detector": {"model": "x"}})
    with pytest.raises(ValueError, match="static_camera is no longer a perception setting.*--static-camera"):
        PerceptionConfig.from_dict({"static_camera": True})  # a config written for the removed 3D-speed contacts
    with pytest.raises(ValueError, match="contact_depth_window must be > 0 seconds or None, got 0"):
        PerceptionConfig.from_dict({"contact_depth_window": 0})
    assert PerceptionConfig.from_dict({"contact_depth_window": None}).contact_depth_window is None


def test_setup_script_installs_the_perception_extras_pin():
    import re
    from pathlib import Path

    tomllib = pytest.importorskip("tomllib", reason="tomllib needs Python >= 3.11")
    root = Path(__file__).resolve().parents[2]
    extra = tomllib.loads((root / "pyproject.toml").read_text())["project"]["optional-dependencies"]["perception"]
    pins = re.findall(r'pip install --quiet "(mediapipe==[^"]+)"', (root / "scripts" / "setup.sh").read_text())
    assert pins == extra
