"""Walkers face where they walk (m3c.motion.heading): a walker whose lifted heading is off by a known angle is
turned back to his direction of travel, about his root joint; side steps, standing and tracks without a gait are
left alone; the optimize node turns the start it gives the optimizer and leaves the lift's arrays alone."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body import default_body_model
from m3c.body.transform import facing_directions
from m3c.eval.scenes import walking_pose
from m3c.motion.heading import WalkingHeadingConfig, turn_to_walking_direction

FPS = 30.0


def _walker(model, off_deg: float, travel_deg: float = 0.0, speed: float = 1.2, seconds: float = 5.0):
    """A procedural walker (0.9 strides a second) travelling along the horizontal direction travel_deg (about y,
    from +z) at `speed`, his body turned off_deg further than that."""
    t = np.arange(round(seconds * FPS)) / FPS
    body = walking_pose(2 * np.pi * 0.9 * t)
    root = np.tile(Rotation.from_euler("y", travel_deg + off_deg, degrees=True).as_rotvec(), (len(t), 1))
    direction = Rotation.from_euler("y", travel_deg, degrees=True).apply([0.0, 0.0, 1.0])
    transl = np.outer(speed * t, direction) + [0.3, 0.0, -1.0]
    return root, body, np.zeros(model.num_betas), transl, t


def _facing(model, root, body, betas, transl):
    joints = model.joints(np.concatenate([root[:, None], body], axis=1), betas, transl)
    return facing_directions(joints, [0.0, 1.0, 0.0]), joints


@pytest.mark.parametrize("off, travel", [(20.0, 0.0), (-35.0, 120.0)])
def test_turns_a_walker_to_his_direction_of_travel(off, travel):
    model = default_body_model()
    root, body, betas, transl, t = _walker(model, off, travel)
    turned, turn = turn_to_walking_direction(model, root, body, betas, transl, [0, 1, 0], t)
    facing, joints = _facing(model, turned, body, betas, transl)
    travel_dir = Rotation.from_euler("y", travel, degrees=True).apply([0.0, 0.0, 1.0])
    error = np.degrees(np.arccos(np.clip(facing @ travel_dir, -1, 1)))
    assert np.count_nonzero(turn) > 0.9 * len(t)  # the line fits' ends are slower: a few frames may stay
    assert np.median(error[turn != 0]) < 1.5 and np.median(np.degrees(np.abs(turn[turn != 0]))) == \
        pytest.approx(abs(off), abs=2.0)
    # Turned about the vertical through the root joint: the pelvis joint stays, the body keeps its pose.
    _, before = _facing(model, root, body, betas, transl)
    np.testing.assert_allclose(joints[:, 0], before[:, 0], atol=1e-9)
    np.testing.assert_allclose(Rotation.from_rotvec(turned).as_euler("YXZ")[:, 1:],
                               Rotation.from_rotvec(root).as_euler("YXZ")[:, 1:], atol=1e-9)


def test_leaves_side_steps_standing_and_non_walkers_alone():
    model = default_body_model()
    # A side step: facing 90 degrees off the travel, beyond max_turn_deg.
    root, body, betas, transl, t = _walker(model, 90.0)
    turned, turn = turn_to_walking_direction(model, root, body, betas, transl, [0, 1, 0], t)
    assert not turn.any() and np.array_equal(turned, root)
    # Standing in place while stepping (too slow), and gliding without stepping (no gait).
    root, body, betas, transl, t = _walker(model, 20.0, speed=0.0)
    assert not turn_to_walking_direction(model, root, body, betas, transl, [0, 1, 0], t)[1].any()
    root, body, betas, transl, t = _walker(model, 20.0)
    still = np.zeros_like(body)
    assert not turn_to_walking_direction(model, root, still, betas, transl, [0, 1, 0], t)[1].any()
    # Disabled, or a looser limit that takes the side step too.
    assert not turn_to_walking_direction(model, root, body, betas, transl, [0, 1, 0], t,
                                         WalkingHeadingConfig(enabled=False))[1].any()
    root, body, betas, transl, t = _walker(model, 90.0)
    assert turn_to_walking_direction(model, root, body, betas, transl, [0, 1, 0], t,
                                     WalkingHeadingConfig(max_turn_deg=100.0))[1].any()
    for bad, message in (({"min_speed": -1.0}, "min_speed"), ({"max_turn_deg": 200.0}, "max_turn_deg"),
                         ({"half_window_s": 0.0}, "half_window_s")):
        with pytest.raises(ValueError, match=message):
            WalkingHeadingConfig(**bad).validate()


def test_optimize_node_turns_only_the_optimizers_start():
    from m3c.nodes.optimize import walking_heading_config, with_walking_heading
    from m3c.pipeline import PipelineError

    model = default_body_model()
    root, body, betas, transl, t = _walker(model, 25.0)
    track = {"track_id": 3, "first_frame": 10, "root_orient": root, "body_pose": body, "betas": betas,
             "transl": transl, "ground_normal": np.tile([0.0, 2.0, 0.0], (len(t), 1))}
    times = np.concatenate([np.arange(10) / FPS - 1.0, t])  # the track starts at processed frame 10
    walker, turn = with_walking_heading(model, track, times, walking_heading_config({}))
    assert np.count_nonzero(turn) > 0.9 * len(t) and walker["root_orient"] is not root
    assert np.array_equal(track["root_orient"], root)  # the lift's own track is not changed
    with pytest.raises(PipelineError, match="optimize.walking_heading: .*max_turn_deg"):
        walking_heading_config({"max_turn_deg": -1})
    with pytest.raises(PipelineError, match="optimize.walking_heading"):
        walking_heading_config({"nope": 1})
