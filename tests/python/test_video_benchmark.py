"""The rendered ground-truth video benchmark: self-consistent truth, scoring the truth against itself, determinism,
and a short sequence through the whole harness (the real pipeline)."""

import json

import cv2
import numpy as np
import pytest
from m3c.eval import video_benchmark as vb
from m3c.synth import CAMERA_KINDS, SequenceSpec, make_video, setup_sequence


def project(points_in_world, world_from_cam, intrinsics):
    """The pinhole model written out here, independently of m3c.camera: (pixels (..., 2), depth (...))."""
    cam_from_world = np.linalg.inv(world_from_cam)
    xc = points_in_world @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
    fx, fy, cx, cy = intrinsics
    return np.stack([fx * xc[..., 0] / xc[..., 2] + cx, fy * xc[..., 1] / xc[..., 2] + cy], -1), xc[..., 2]


@pytest.fixture(scope="module")
def model(open_model):
    return open_model


@pytest.fixture(scope="module")
def clips(mocap_clips):
    return mocap_clips


@pytest.fixture(scope="module")
def follow_video(model, clips, tmp_path_factory):
    spec = SequenceSpec(0, "follow", 2, num_frames=40, width=320, height=180)
    return make_video(model, clips, spec, tmp_path_factory.mktemp("videos"))


def test_cli_lists_the_camera_kinds():
    from m3c.cli import CAMERA_KINDS_TEXT

    assert CAMERA_KINDS_TEXT == CAMERA_KINDS


def test_truth_is_self_consistent(model, clips, follow_video):
    truth = follow_video.truth()
    P, n = truth["betas"].shape[0], truth["world_from_cam"].shape[0]
    assert truth["joints"].shape == (P, n, 24, 3) and follow_video.video.is_file()
    # The stored joints and keypoints are the body model's, projected by an independent projection.
    regressor = model.coco17_regressor()
    for p in range(P):
        pose = np.concatenate([truth["root_orient"][p][:, None], truth["body_pose"][p]], axis=1)
        np.testing.assert_allclose(
            model.joints(pose, truth["betas"][p], truth["transl"][p]), truth["joints"][p], atol=1e-9
        )
        kps = model.keypoints(regressor, pose, truth["betas"][p], truth["transl"][p])
        for i in range(n):
            uv, depth = project(kps[i], truth["world_from_cam"][i], truth["intrinsics"])
            inside = truth["keypoints_in_image"][p, i]
            assert (depth[inside] > 0).all()
            np.testing.assert_allclose(truth["keypoints_2d"][p, i][inside], uv[inside], atol=1e-3)
    assert (truth["visible_pixels"] <= truth["silhouette_pixels"]).all()
    assert (truth["silhouette_pixels"] > 0).all()
    # Every ground-truth joint in the image lands on its own person's pixels wherever that pixel shows the
    # person or something nearer (so nothing is drawn through a body); re-rendering reproduces the video.
    setup = setup_sequence(model, clips, follow_video.spec)
    cap = cv2.VideoCapture(str(follow_video.video))
    decoded = [cap.read()[1] for _ in range(n)]
    checked = 0
    for i in range(0, n, 5):
        frame = setup.frame(i)
        # H.264 (crf 16, 4:2:0 chroma) of fine textures at 320 x 180: a few grey levels on average.
        assert np.abs(decoded[i].astype(int) - frame.image.astype(int)).mean() < 6.0
        for p in range(P):
            uv, depth = project(truth["joints"][p, i], truth["world_from_cam"][i], truth["intrinsics"])
            pix = np.round(uv).astype(int)
            inside = (pix[:, 0] >= 1) & (pix[:, 0] < 319) & (pix[:, 1] >= 1) & (pix[:, 1] < 179)
            for (x, y), z in zip(pix[inside], depth[inside]):
                window = frame.ids[y - 1 : y + 2, x - 1 : x + 2]
                nearer = frame.depth[y - 1 : y + 2, x - 1 : x + 2] < z
                assert (window == p).any() or nearer.all(), (i, p, x, y)
                checked += 1
    assert checked > 200
    meta = follow_video.meta()
    assert meta["camera"]["kind"] == "follow" and len(meta["people"]) == P
    assert 40 <= meta["camera"]["hfov_deg"] <= 75


def _results_from_truth(truth: dict) -> dict:
    """A results.npz-like dict holding the ground truth itself: every track detected in every frame."""
    P, n = truth["betas"].shape[0], truth["world_from_cam"].shape[0]
    keypoints = np.concatenate(
        [truth["keypoints_2d"], truth["keypoints_in_image"][..., None].astype(np.float32)], axis=-1
    )
    arrays = {
        "frame_ids": np.arange(n),
        "track_ids": np.arange(P) + 10,
        "valid": np.ones((P, n), bool),
        "visible": np.ones((P, n), bool),
        "keypoints_2d": keypoints,
    }
    for prefix in ("", "lift_"):
        arrays[f"{prefix}world_root_orient" if prefix else "world_root_orient"] = truth["root_orient"]
        arrays[f"{prefix}world_transl"] = truth["transl"]
        arrays[f"{prefix}body_pose"] = truth["body_pose"]
        arrays[f"{prefix}betas"] = truth["betas"]
        arrays[f"{prefix}world_from_cam"] = truth["world_from_cam"]
    arrays["lift_world_root_orient"] = truth["root_orient"]
    return arrays


def test_scoring_the_truth_against_itself_gives_zero_errors(model, follow_video):
    truth = follow_video.truth()
    detection, methods = vb.score_results(model, truth, _results_from_truth(truth), "self")
    assert detection["id_switches"] == 0 and detection["visible"] > 0
    assert detection["detected"] == detection["visible"]
    for method, score in methods.items():
        assert len(score.body.matching.matches) == 2
        for key in ("pa_mpjpe", "mpjpe", "pve", "w_mpjpe", "wa_mpjpe", "rte"):
            assert score.body.mean(key) == pytest.approx(0.0, abs=1e-6), (method, key)
        # Foot sliding counts the motion of foot points on steps where the truth moves under 1 cm (GVHMR's
        # contact rule), so the truth itself slides a few millimetres, never more than that threshold.
        assert 0.0 < score.body.mean("foot_sliding") < 10.0
        cam = score.camera
        assert cam["scale_error_pct"] == pytest.approx(0.0, abs=1e-9)
        assert cam["ate_mm"] == pytest.approx(0.0, abs=1e-6)
        assert cam["ground_height_error_m"] == 0.0 and cam["tilt_error_deg"] == pytest.approx(0.0, abs=1e-4)
        assert score.speed_error_pct and np.allclose(score.speed_error_pct, 0.0)


def test_scores_see_errors(model, follow_video):
    """A doubled camera path and a shifted, slowed person are measured as such."""
    truth = follow_video.truth()
    arrays = _results_from_truth(truth)
    cams = truth["world_from_cam"].copy()
    cams[:, :3, 3] *= 2.0
    arrays["world_from_cam"] = cams
    assert vb.camera_scores(cams, truth["world_from_cam"])["scale_error_pct"] == pytest.approx(100.0)
    # Jitter is not scale: 2 cm of noise per frame lengthens the path several times, the scale stays.
    shaken = truth["world_from_cam"].copy()
    shaken[:, :3, 3] += 0.02 * np.random.default_rng(0).standard_normal(shaken[:, :3, 3].shape)
    assert abs(vb.camera_scores(shaken, truth["world_from_cam"])["scale_error_pct"]) < 2.0
    # A camera held fixed while the truth moved (the odometry's "turned in place") is scored, not a crash: the
    # best point for a path is its mean, a point has no length.
    fixed = truth["world_from_cam"].copy()
    fixed[:, :3, 3] = fixed[0, :3, 3]
    centres = truth["world_from_cam"][:, :3, 3]
    held = vb.camera_scores(fixed, truth["world_from_cam"])
    assert held["scale_error_pct"] == -100.0
    assert held["ate_mm"] == pytest.approx(1000 * np.sqrt(((centres - centres.mean(0)) ** 2).sum(-1).mean()))
    assert held["ate_mm"] > 100.0
    # A near-still camera whose hand shakes over a long path but never gets 0.5 m from its start has no scale to
    # be wrong about: held fixed, it is not scored -100 %.
    still = np.repeat(truth["world_from_cam"][:1], 150, axis=0)
    still[:, :3, 3] += 0.1 * np.random.default_rng(1).uniform(-1, 1, (150, 3))
    assert np.linalg.norm(np.diff(still[:, :3, 3], axis=0), axis=1).sum() > 5 * vb.MIN_CAMERA_PATH
    assert vb.camera_travel(still) < vb.MIN_CAMERA_PATH
    assert "scale_error_pct" not in vb.camera_scores(np.repeat(still[:1], 150, axis=0), still)
    half = truth["transl"].copy()
    half[..., [0, 2]] = half[:, :1, [0, 2]] + 0.5 * (half[..., [0, 2]] - half[:, :1, [0, 2]])
    arrays["world_transl"] = half
    _, methods = vb.score_results(model, truth, arrays, "slow")
    opt = methods["Global Opt"]
    assert opt.body.mean("w_mpjpe") > 10.0
    moving = [v for v in opt.speed_error_pct]
    assert moving and all(-60 < v < -40 for v in moving)
    # Legs that walk while the body moves at half speed: the planted foot slides back at about half the person's
    # speed (each person's slower foot faster than in the truth; the walker's by over 0.3 m/s).
    _, perfect = vb.score_results(model, truth, _results_from_truth(truth), "truth")
    still_feet = perfect["Global Opt"].slow_foot_mps
    assert still_feet and max(still_feet) < 0.15  # the bar for a crowd's scored walkers
    assert len(opt.slow_foot_mps) == len(still_feet) == len(moving)
    assert all(half > own + 0.04 for half, own in zip(opt.slow_foot_mps, still_feet)), opt.slow_foot_mps
    assert max(opt.slow_foot_mps) > 0.3
    # Dropping a track's detections lowers the recall; swapping the ids half-way is an identity switch.
    arrays = _results_from_truth(truth)
    arrays["visible"][0, :20] = False
    arrays["track_ids"] = np.array([10, 11])
    detection = vb.detection_scores(truth, arrays)
    assert detection["detected"] < detection["visible"]
    swapped = _results_from_truth(truth)
    for key in ("keypoints_2d",):
        swapped[key][:, 20:] = swapped[key][::-1, 20:]
    assert vb.detection_scores(truth, swapped)["id_switches"] == 2


def test_rendering_is_deterministic(model, clips, tmp_path):
    spec = SequenceSpec(3, "handheld", 2, num_frames=6, width=160, height=96)
    a = make_video(model, clips, spec, tmp_path / "a")
    b = make_video(model, clips, spec, tmp_path / "b")
    ta, tb = a.truth(), b.truth()
    assert ta.keys() == tb.keys()
    for key in ta:
        np.testing.assert_array_equal(ta[key], tb[key])
    frames = []
    for video in (a, b):
        cap = cv2.VideoCapture(str(video.video))
        frames.append(np.stack([cap.read()[1] for _ in range(6)]))
    np.testing.assert_array_equal(frames[0], frames[1])
    other = make_video(
        model, clips, SequenceSpec(3, "handheld", 2, 6, width=160, height=96, seed=1), tmp_path / "c"
    )
    assert not np.array_equal(other.truth()["world_from_cam"], ta["world_from_cam"])
    # The cache: asking again renders nothing.
    assert make_video(model, clips, spec, tmp_path / "a").render_seconds == 0.0


def test_every_camera_kind_keeps_its_people_in_view(model, clips):
    for index, kind in enumerate(CAMERA_KINDS):
        spec = SequenceSpec(index, kind, 1 + index % 3, num_frames=60, width=320, height=180)
        setup = setup_sequence(model, clips, spec)
        assert 40 <= setup.camera_info["hfov_deg"] <= 75
        heights = setup.world_from_cam[:, 1, 3]
        assert heights.min() > 1.0 and heights.max() < 6.0, kind
        people = [0] if kind in ("follow", "tracking") else range(spec.num_people)
        for p in people:
            pel = np.stack(
                [
                    project(setup.joints[p, i, 0], setup.world_from_cam[i], setup.intrinsics)[0]
                    for i in range(60)
                ]
            )
            inside = (pel[:, 0] > 0) & (pel[:, 0] < 320) & (pel[:, 1] > 0) & (pel[:, 1] < 180)
            assert inside.mean() > 0.95, (kind, p)
        path = np.linalg.norm(np.diff(setup.world_from_cam[:, :3, 3], axis=0), axis=-1).sum()
        assert (path < 1e-9) == (kind in ("static", "pan", "high")), kind


def test_a_failed_sequence_is_reported_and_the_others_go_on(model, tmp_path, monkeypatch):
    real = vb.make_video

    def flaky(model, clips, spec, out_dir, log=None, progress=None):
        if spec.index == 0:
            raise RuntimeError("renderer exploded")
        return real(model, clips, spec, out_dir, log, progress)

    monkeypatch.setattr(vb, "make_video", flaky)
    config = vb.VideoBenchmarkConfig(
        num_sequences=2, num_frames=10, cameras=("static",), width=160, height=96, render_only=True
    )
    report = vb.run_video_benchmark(model, config, tmp_path, show_progress=False)
    assert "renderer exploded" in report.sequences[0].error
    assert not report.sequences[1].error and report.sequences[1].folder
    assert "FAILED" in report.text() and "rendered only" in report.text()


def test_short_sequence_through_the_whole_harness(model, tmp_path):
    pytest.importorskip(
        "mediapipe", reason="the default perception backend (the perception extra) is not installed"
    )
    config = vb.VideoBenchmarkConfig(
        num_sequences=1, num_frames=30, cameras=("follow",), max_people=1, width=480, height=270
    )
    report = vb.run_video_benchmark(model, config, tmp_path, show_progress=False)
    seq = report.sequences[0]
    assert not seq.error, seq.error
    assert seq.detection["visible"] > 0 and seq.detection["detected"] >= 0.8 * seq.detection["visible"]
    for method in vb.METHODS:
        row = report.row(seq, method)
        assert row["matched"] == 1
        for key in ("pa_mpjpe", "mpjpe", "w_mpjpe", "wa_mpjpe", "ate_mm", "scale_error_pct"):
            assert row[key] is not None and np.isfinite(row[key]), (method, key)
        assert row["pa_mpjpe"] < 300.0
    vb.write_json(report, tmp_path / "report.json")
    summary = json.loads((tmp_path / "report.json").read_text())
    assert summary["sequences"][0]["methods"]["Global Opt"]["matched"] == 1
    assert seq.name in report.text() and "perception" in report.stage_seconds()
    # A second run reuses the video and every pipeline node.
    again = vb.run_video_benchmark(model, config, tmp_path, show_progress=False)
    assert again.sequences[0].render_seconds == 0.0 and again.sequences[0].node_seconds == {}
    assert report.row(seq, "Global Opt")["w_mpjpe"] == again.row(again.sequences[0], "Global Opt")["w_mpjpe"]


def test_bad_settings_are_refused_before_anything_runs(model, tmp_path):
    for kwargs, message in (({"cameras": ("dolly",)}, "camera motions"), ({"width": 321}, "even"),
                            ({"num_frames": 5}, "at least 10"), ({"max_people": 4}, "max_people")):
        with pytest.raises(ValueError, match=message):
            vb.run_video_benchmark(model, vb.VideoBenchmarkConfig(**kwargs), tmp_path, show_progress=False)
    assert not any(tmp_path.iterdir())


def test_a_pose_fitting_two_overlapping_people_is_no_identity_switch():
    """CLEAR MOT matching: a person keeps its last track while that track still fits it, even where the track's
    pose fits another, hidden person better; a real swap of the tracks is still two switches."""
    T = 10
    base = np.column_stack([np.linspace(0, 40, 17), np.linspace(0, 100, 17)])  # 100 px tall
    truth = {"keypoints_2d": np.stack([np.repeat(base[None], T, 0), np.repeat(base[None] + [25.0, 0], T, 0)]),
             "keypoints_in_image": np.ones((2, T, 17), bool), "silhouette_pixels": np.full((2, T), 100),
             "visible_pixels": np.full((2, T), 100)}
    keypoints = np.concatenate([truth["keypoints_2d"], np.ones((2, T, 17, 1))], axis=-1)
    arrays = {"track_ids": np.array([10, 11]), "frame_ids": np.arange(T), "visible": np.ones((2, T), bool),
              "keypoints_2d": keypoints.copy()}
    # Frame 5: person 0 hidden (its track unseen); track 11 (person 1's) shows a pose 10 px from person 0's and
    # 15 px from person 1's: both within the match distance (0.2 of 100 px).
    arrays["visible"][0, 5] = False
    arrays["keypoints_2d"][1, 5, :, 0] = base[:, 0] + 10.0
    scores = vb.detection_scores(truth, arrays)
    assert scores["id_switches"] == 0 and scores["detected"] == 2 * T - 1
    # Frame-by-frame Hungarian matching alone (no kept correspondences) gives track 11 to person 0 there: 2.
    costs = np.linalg.norm(arrays["keypoints_2d"][1, 5, :, :2] - truth["keypoints_2d"][:, 5], axis=-1).mean(-1) / 100
    assert costs[0] < costs[1] <= vb.MATCH_DISTANCE
    swapped = {**arrays, "keypoints_2d": keypoints.copy(), "visible": np.ones((2, T), bool)}
    swapped["keypoints_2d"][:, 5:] = keypoints[::-1, 5:]
    swapped_scores = vb.detection_scores(truth, swapped)
    assert swapped_scores["id_switches"] == 2
    # Each switch is listed: at frame 5 person 0 goes from track 10 to 11 and person 1 from 11 to 10.
    assert sorted((e["frame"], e["person"], e["from_track"], e["to_track"])
                  for e in swapped_scores["switch_events"]) == [(5, 0, 10, 11), (5, 1, 11, 10)]
    assert scores["switch_events"] == []


def test_planted_feet_are_scored_against_the_true_contacts(follow_video):
    """The true contacts score precision and recall 1; every foot said planted keeps the recall and lowers the
    precision to the planted share; contacts a quarter second late lose both."""
    truth = follow_video.truth()
    arrays = {**_results_from_truth(truth), "contacts": truth["contacts"].astype(np.float32)}
    scores = vb.detection_scores(truth, arrays)
    assert scores["contact_true"] > 0 and scores["contact_hits"] == scores["contact_predicted"] == scores["contact_true"]
    feet = np.maximum(truth["contacts"][..., [0, 1]], truth["contacts"][..., [2, 3]]) > 0.5
    always = vb.detection_scores(truth, {**arrays, "contacts": np.ones_like(arrays["contacts"])})
    assert always["contact_hits"] == scores["contact_true"]
    assert always["contact_predicted"] == 2 * scores["matched_person_frames"]
    assert always["contact_hits"] / always["contact_predicted"] == pytest.approx(feet.mean(), abs=0.02)
    late = vb.detection_scores(truth, {**arrays, "contacts": np.roll(arrays["contacts"], 8, axis=1)})
    assert late["contact_hits"] < 0.95 * late["contact_predicted"] and late["contact_hits"] < 0.95 * late["contact_true"]
    # Results without contacts (an older results file) score none.
    assert "contact_hits" not in vb.detection_scores(truth, _results_from_truth(truth))
