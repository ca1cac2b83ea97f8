"""Python front-ends of the patch VO: the binding (a Lucas-Kanade front-end written in Python through it must
track a rendered room as well as the built-in one does), and DPVO's networks as the front-end (random weights in
the official layout: the plumbing, not the accuracy)."""

import numpy as np
import pytest
import torch

from m3c.models.dpvo import DPVONet
from m3c.vo import VOConfig, relative_ate, run_vo
from m3c.vo.dpvo import DPVOFrontEnd
from m3c.vo.odometry import VisualOdometry
from m3c.vo.synthetic import forward_trajectory, render_sequence

pytestmark = pytest.mark.usefixtures("one_torch_thread")


class PythonLucasKanade:
    """OpenCV's pyramidal LK with a forward-backward check, as a Python front-end (no masks, no Verify)."""

    def __init__(self):
        self.frames = {}
        self.calls = {"add_frame": 0, "sample_patches": 0, "track": 0, "release_frame": 0}

    def add_frame(self, frame, gray, mask):
        self.calls["add_frame"] += 1
        self.frames[frame] = gray.copy()

    def sample_patches(self, frame, count):
        import cv2

        self.calls["sample_patches"] += 1
        corners = cv2.goodFeaturesToTrack(self.frames[frame], count, 0.01, 8, blockSize=7)
        return np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(np.float64)

    def track(self, target, hosts, host_uv, predicted_uv):
        import cv2

        self.calls["track"] += 1
        uv = np.zeros((len(hosts), 2))
        ok = np.zeros(len(hosts), dtype=bool)
        params = dict(winSize=(15, 15), maxLevel=3, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        for host in np.unique(hosts):
            rows = np.flatnonzero(hosts == host)
            p0 = host_uv[rows].astype(np.float32).reshape(-1, 1, 2)
            guess = predicted_uv[rows].astype(np.float32).reshape(-1, 1, 2)
            p1, s1, _ = cv2.calcOpticalFlowPyrLK(self.frames[host], self.frames[target], p0, guess.copy(), **params)
            back, s2, _ = cv2.calcOpticalFlowPyrLK(self.frames[target], self.frames[host], p1, p0.copy(), **params)
            good = (s1[:, 0] == 1) & (s2[:, 0] == 1) & (np.linalg.norm((back - p0)[:, 0], axis=1) < 0.75)
            uv[rows] = p1[:, 0]
            ok[rows] = good
        return uv, np.ones(len(hosts)), ok

    def release_frame(self, frame):
        self.calls["release_frame"] += 1
        self.frames.pop(frame, None)


@pytest.fixture(scope="module")
def room():
    return render_sequence(forward_trajectory(40), seed=0)


def test_python_front_end_drives_the_bundle_adjustment(room):
    front = PythonLucasKanade()
    vo = VisualOdometry(room.intrinsics, VOConfig(), front_end=front)
    for frame in room.frames:
        vo.add_frame(frame)
    result = vo.finish()
    assert front.calls["add_frame"] == len(room.frames) and front.calls["track"] > len(room.frames)
    assert front.calls["release_frame"] > 0
    ours = relative_ate(result.world_from_cam, room.world_from_cam)
    builtin = relative_ate(run_vo(room.frames, intrinsics=room.intrinsics).world_from_cam, room.world_from_cam)
    assert ours < max(0.02, 2 * builtin), f"ATE {100 * ours:.2f}% vs the built-in front-end's {100 * builtin:.2f}%"


def test_front_end_errors_reach_python(room):
    class Broken(PythonLucasKanade):
        def track(self, target, hosts, host_uv, predicted_uv):
            return np.zeros((len(hosts), 3)), np.ones(len(hosts)), np.ones(len(hosts), dtype=bool)

    vo = VisualOdometry(room.intrinsics, VOConfig(), front_end=Broken())
    with pytest.raises(ValueError, match=r"track\(\) uv"):
        for frame in room.frames[:3]:
            vo.add_frame(frame)


@pytest.fixture(scope="module")
def dpvo_net():
    torch.manual_seed(0)
    return DPVONet().eval()


def test_dpvo_front_end_samples_off_people_and_measures(room, dpvo_net):
    front = DPVOFrontEnd(dpvo_net, iterations=2)
    h, w = room.frames[0].shape[:2]
    mask = np.zeros((h, w), dtype=np.uint8)
    mask[:, : w // 2] = 1  # a "person" over the left half
    for t in range(2):
        front.push_image(np.repeat(room.frames[t][..., None], 3, axis=2))  # the room is rendered gray
        front.add_frame(t, room.frames[t], mask)
    centres = front.sample_patches(0, 32)
    assert 0 < len(centres) <= 32 and (centres[:, 0] >= w // 2).all()  # none on the person
    np.testing.assert_array_equal(front.sample_patches(0, 32), centres)  # the same patches when asked again
    uv, weight, ok = front.track(1, np.zeros(len(centres), dtype=np.int64), centres, centres)
    assert uv.shape == (len(centres), 2) and np.isfinite(uv).all()
    assert ((weight > 0) & (weight < 1)).all() and ok.dtype == bool
    front.release_frame(0)
    assert 0 not in front._frames and not any(k[0] == 0 for k in front._patches)


def test_dpvo_front_end_in_the_vo(room, dpvo_net):
    front = DPVOFrontEnd(dpvo_net, iterations=1)
    vo = VisualOdometry(room.intrinsics, VOConfig(max_image_side=160, patches_per_frame=24), front_end=front)
    for frame in room.frames[:8]:
        vo.add_frame(frame)
    result = vo.finish()
    assert result.world_from_cam.shape == (8, 4, 4) and np.isfinite(result.world_from_cam).all()
