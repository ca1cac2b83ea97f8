"""The perception pipeline end to end on a synthetic two-person scene, with test estimators registered under
their own names (no MediaPipe needed): tracking through occlusions, body fits, contacts, saving and loading."""

import json

import numpy as np
import pytest

from m3c.body import default_body_model
from m3c.eval.scenes import make_scene
from m3c.motion import track_joints
from m3c.perception import (PerceptionConfig, Person, iou, load_result, register, run_perception_frames)
from m3c.perception.body import keypoint_regressor
from m3c.perception.interfaces import DepthEstimator, Detector, PoseEstimator2D, Segmenter

COLOURS = [((200, 40, 40), (40, 40, 160)), ((40, 170, 60), (220, 210, 50))]


@register("detector", "test_scene_truth")
class SceneDetector(Detector):
    """The scene's visible people, with their keypoints; `known` people are not reported again."""

    def __init__(self, frames: list):
        self.frames = frames

    def detect(self, ctx, known=None):
        out = []
        for person in self.frames[ctx.index]:
            if not any(iou(person.box, k.box) > 0.5 for k in known or []):
                out.append(Person(person.box, 0.9, person.keypoints, person.keypoints3d,
                                  sources={"detector": "test_scene_truth", "pose2d": "test_scene_truth"}))
        return out


@register("segmenter", "test_box_mask")
class BoxMask(Segmenter):
    def segment(self, ctx, people):
        out = []
        for p in people:
            box = np.round(p.box).astype(int)
            mask = np.ones((box[3] - box[1], box[2] - box[0]), bool)
            out.append(Person(p.box, p.score, p.keypoints, p.keypoints3d, mask, box,
                              dict(p.sources, segmenter="test_box_mask")))
        return out


@register("pose2d", "test_scene_truth")
class ScenePose(PoseEstimator2D):
    """The keypoints of the visible person whose box overlaps the asked-for box most (None if nobody does)."""

    def __init__(self, frames: list):
        self.frames = frames

    def estimate(self, ctx, people):
        out = []
        for p in people:
            if p.keypoints is not None:
                out.append(p)
                continue
            visible = self.frames[ctx.index]
            overlaps = [iou(p.box, v.box) for v in visible]
            if not overlaps or max(overlaps) < 0.3:
                out.append(None)
                continue
            v = visible[int(np.argmax(overlaps))]
            out.append(Person(v.box, 0.9, v.keypoints, v.keypoints3d, p.mask, p.mask_box,
                              dict(p.sources, pose2d="test_scene_truth")))
        return out


@register("depth", "test_rows")
class RowDepth(DepthEstimator):
    """The row index as depth: what a configured depth estimator returns is kept (4x downsampled)."""

    def estimate(self, ctx):
        return np.tile(np.arange(ctx.size[0], dtype=np.float32)[:, None], (1, ctx.size[1]))


@pytest.fixture(scope="module")
def scene_frames():
    model = default_body_model()
    scene = make_scene(model, num_people=2, num_frames=50, fps=30.0, seed=7, keypoint_noise_px=1.0)
    W, H = scene.image_size
    K = scene.cameras_true.intrinsics
    regressor = keypoint_regressor(model, 17)
    frames, images, owner = [], [], []
    rng = np.random.default_rng(0)
    for t in range(50):
        image = np.full((H, W, 3), 110, np.uint8)
        cam_from_world = np.linalg.inv(scene.cameras_true.world_from_cam[t])
        visible = []
        for i, truth in enumerate(scene.truth):
            pose = np.concatenate([truth.root_orient[t:t + 1, None], truth.body_pose[t:t + 1]], axis=1)
            world = model.keypoints(regressor, pose, truth.betas, truth.transl[t:t + 1])[0]
            cam = world @ cam_from_world[:3, :3].T + cam_from_world[:3, 3]
            uv = cam[:, :2] / cam[:, 2:] * K[:2] + K[2:]
            box = np.array([uv[:, 0].min() - 10, uv[:, 1].min() - 15, uv[:, 0].max() + 10, uv[:, 1].max() + 10])
            box = np.clip(box, 0, [W, H, W, H])
            x0, y0, x1, y1 = np.round(box).astype(int)
            image[y0:(y0 + y1) // 2, x0:x1] = COLOURS[i][0]
            image[(y0 + y1) // 2:y1, x0:x1] = COLOURS[i][1]
            if scene.init[i].keypoints[t, :, 2].max() == 0:
                continue  # dropped or occluded in the scene
            keypoints = np.column_stack([uv + rng.normal(size=uv.shape), np.full(17, 0.9)])
            hips = cam[[11, 12]].mean(axis=0)
            keypoints3d = np.column_stack([cam - hips + 0.02 * rng.normal(size=cam.shape), np.full(17, 0.9)])
            visible.append(Person(box, 0.9, keypoints, keypoints3d))
            owner.append((t, i, box))
        frames.append(visible)
        images.append(image)
    return model, scene, frames, images, owner


def run_scene(scene_frames, **settings):
    model, scene, frames, images, owner = scene_frames
    W, H = scene.image_size
    config = PerceptionConfig.from_dict({"detector": {"name": "test_scene_truth", "options": {"frames": frames}},
                                         "segmenter": "test_box_mask",
                                         "pose2d": {"name": "test_scene_truth", "options": {"frames": frames}},
                                         "depth": "test_rows",
                                         "intrinsics": list(scene.cameras_true.intrinsics), "detect_every": 3,
                                         **settings})
    return run_perception_frames(iter(images), scene.fps, (H, W), config, source="synthetic")


@pytest.fixture(scope="module")
def scene_run(scene_frames):
    model, scene, _, _, owner = scene_frames
    return model, scene, run_scene(scene_frames), owner


def test_one_track_per_person_through_occlusions(scene_run):
    model, scene, result, owner = scene_run
    assert len(result.tracks) == 2
    seen_by = {}
    for track in result.tracks:
        people = set()
        for f, box in zip(track.frame_ids, track.boxes):
            match = [i for t, i, b in owner if t == f and iou(b, box) > 0.9]
            assert len(match) == 1
            people.add(match[0])
        assert len(people) == 1  # never another person's detections: no swaps
        seen_by[people.pop()] = track
    assert set(seen_by) == {0, 1}
    for i, track in seen_by.items():
        visible = [t for t, j, _ in owner if j == i]
        assert len(track.frame_ids) >= 0.9 * len(visible)
        assert np.all(np.diff(track.frame_ids) > 0)


def test_bodies_contacts_and_provenance(scene_run):
    model, scene, result, _ = scene_run
    for track in result.tracks:
        assert track.bodies.valid.all()
        assert np.median(track.bodies.reprojection_error_px) < 2.0
        assert track.contacts.shape == (len(track.frame_ids), 4)
        assert track.gender == "neutral"
        assert track.estimators["detector"] in ("test_scene_truth", "test_scene_truth,tracker", "tracker")
        assert track.estimators["segmenter"] == "test_box_mask" and track.estimators["body"] == "fit"
    assert result.estimators == {"detector": "test_scene_truth", "segmenter": "test_box_mask",
                                 "pose2d": "test_scene_truth", "body": "fit", "contacts": "kinematic",
                                 "depth": "test_rows", "gender": "neutral"}
    assert result.frame_masks.shape == (50, 540 // 4, 960 // 4 // 8)
    assert result.depth.shape == (50, 135, 240)
    np.testing.assert_array_equal(result.depth[7, :, 0], np.arange(2, 540, 4))


def test_save_and_load(scene_run, tmp_path):
    _, _, result, _ = scene_run
    result.save(tmp_path / "perception")
    summary = json.loads((tmp_path / "perception.json").read_text())
    assert len(summary["tracks"]) == 2 and summary["fps"] == 30.0
    loaded = load_result(tmp_path / "perception")
    assert loaded.num_frames == 50 and loaded.estimators == result.estimators
    for a, b in zip(result.tracks, loaded.tracks):
        np.testing.assert_array_equal(a.frame_ids, b.frame_ids)
        np.testing.assert_allclose(a.bodies.transl, b.bodies.transl, rtol=1e-6)  # stored as float32
        assert a.bodies.status == b.bodies.status and a.estimators == b.estimators
    np.testing.assert_array_equal(loaded.frame_masks, result.frame_masks)
    np.testing.assert_array_equal(loaded.depth, result.depth)


def test_track_splits_are_merged_back(scene_frames):
    """A tracker that forgets a person after one missed frame splits each track at the scene's occlusions; the
    merge rule joins the parts again (appearance and 3D location agree), never across the two people."""
    _, _, _, _, owner = scene_frames
    settings = {"tracker": {"max_age": 1}}
    split = run_scene(scene_frames, merge={"enabled": False}, **settings)
    merged = run_scene(scene_frames, **settings)
    assert len(split.tracks) > 2  # the splits happen (so the merge has work to do)
    assert len(merged.tracks) == 2 and merged.merged
    assert set(merged.merged.values()) <= {t.track_id for t in merged.tracks}
    for track in merged.tracks:
        people = {i for f, box in zip(track.frame_ids, track.boxes)
                  for t, i, b in owner if t == f and iou(b, box) > 0.9}
        assert len(people) == 1
        parts = [t for t in split.tracks if merged.merged.get(t.track_id, t.track_id) == track.track_id]
        np.testing.assert_array_equal(track.frame_ids, np.concatenate([t.frame_ids for t in parts]))


def test_ground_motion_cue_falls_back_where_the_ground_cannot_be_tracked(scene_frames, scene_run):
    """The scene's background is flat grey: no ground motion can be read, so the opt-in image cue leaves every
    contact to the kinematic rules (the same contacts as without it) and the run still finishes."""
    _, _, result, _ = scene_run
    cued = run_scene(scene_frames, ground_motion={"enabled": True})
    assert "ground_motion" in cued.seconds and len(cued.tracks) == len(result.tracks)
    for a, b in zip(result.tracks, cued.tracks):
        np.testing.assert_array_equal(a.contacts, b.contacts)
        # The ground's contacts (the heights rule; given apart where they differ from the planted feet's).
        np.testing.assert_array_equal(a.contacts if a.ground_contacts is None else a.ground_contacts,
                                      b.contacts if b.ground_contacts is None else b.ground_contacts)
    with pytest.raises(ValueError, match="ground_motion"):
        PerceptionConfig.from_dict({"ground_motion": {"rings": []}})


@register("detector", "test_network_sees_all")
class NetworkDetector(SceneDetector):
    """The scene detector, blind to person `blind` in `frames_blind` (as BlazePose's tiles can be), while its
    multi-person network's skeletons are every visible person's keypoints."""

    def __init__(self, frames: list, owner: list, blind: int, frames_blind: range):
        super().__init__(frames)
        self.hidden = {t: b for t, i, b in owner if i == blind and t in frames_blind}

    def detect(self, ctx, known=None):
        return [p for p in super().detect(ctx, known)
                if ctx.index not in self.hidden or iou(p.box, self.hidden[ctx.index]) < 0.9]

    def skeletons(self, ctx):
        return [p.keypoints * [1, 1, 0.6] for p in self.frames[ctx.index]]


@register("pose2d", "test_blind_pose")
class BlindPose(ScenePose):
    """The scene's pose estimator, finding nobody on person `blind`'s patch in `frames_blind`."""

    def __init__(self, frames: list, owner: list, blind: int, frames_blind: range):
        super().__init__(frames)
        self.hidden = {t: b for t, i, b in owner if i == blind and t in frames_blind}

    def estimate(self, ctx, people):
        out = super().estimate(ctx, people)
        hidden = self.hidden.get(ctx.index)
        return [None if p is not None and hidden is not None and iou(p.box, hidden) > 0.9 else p for p in out]


def test_a_tracked_person_the_pose_search_loses_is_kept_on_the_networks_skeleton(scene_frames, caplog):
    model, scene, frames, images, owner = scene_frames
    blind = dict(owner=owner, blind=1, frames_blind=range(4, 14))  # person 1 in view from frame 0 to 16
    settings = {"detector": {"name": "test_network_sees_all", "options": {"frames": frames, **blind}},
                "pose2d": {"name": "test_blind_pose", "options": {"frames": frames, **blind}}}
    with caplog.at_level("INFO", logger="m3c.perception.pipeline"):
        kept = run_scene(scene_frames, skeleton_agreement=0.25, **settings)
    assert "kept on the detector's network skeleton where its pose search found nobody: frames 4-13" in caplog.text
    lost = run_scene(scene_frames, **settings)  # off by default
    seen = {t for t, i, _ in owner if i == 1 and t in range(4, 14)}
    assert len(seen) == 10  # the premise: the person is in view there

    def frames_of(result):
        return {int(f) for track in result.tracks for f, box in zip(track.frame_ids, track.boxes)
                if any(t == f and i == 1 and iou(b, box) > 0.5 for t, i, b in owner)}

    assert not seen & frames_of(lost)  # switched off, the person is missing there
    assert seen <= frames_of(kept)
    assert len(kept.tracks) == 2
    for track in kept.tracks:  # one person per track, and the skeleton's keypoints where it was kept
        people = {i for f, box in zip(track.frame_ids, track.boxes) for t, i, b in owner if t == f
                  and iou(b, box) > 0.5}
        assert len(people) == 1
        if people == {1}:
            rows = np.isin(track.frame_ids, sorted(seen))
            np.testing.assert_allclose(track.keypoints[rows, :17, 2], 0.9 * 0.6)
    with pytest.raises(ValueError, match="skeleton_agreement"):
        PerceptionConfig(skeleton_agreement=-0.1)
