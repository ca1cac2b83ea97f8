"""The chase world view (m3c.viz.chase) on a synthetic walker whose truth is known: the person stays about half the
frame high from start to end, the camera glides (no cut), planted feet leave prints that stay, a sliding foot
draws a smear, and the inset shows the whole scene."""

import numpy as np
import pytest

from m3c.viz.chase import GROUND, ChaseFrames, ChaseView, TrackMotion, _darker
from m3c.viz.scene import track_colour

FPS = 30.0


def walker(frames: int = 150, speed: float = 1.3, slide: bool = False, first: int = 0, track_id: int = 0,
           start=(0.0, 0.0)) -> TrackMotion:
    """A walker along +x on the ground y = 0: feet planted in turn for half a stride each (1 s strides)."""
    t = np.arange(frames) / FPS
    pelvis = np.stack([start[0] + speed * t, np.full(frames, 0.9), np.full(frames, start[1])], axis=1)
    heels, toes, planted = np.zeros((2, frames, 3)), np.zeros((2, frames, 3)), np.zeros((2, frames), bool)
    phase = (t % 1.0) < 0.5
    for foot, (side, down) in enumerate(((-0.1, phase), (0.1, ~phase))):
        x = pelvis[:, 0].copy()
        if not slide:  # a planted foot holds where it landed
            landing = np.maximum.accumulate(np.where(down & ~np.r_[False, down[:-1]], np.arange(frames), 0))
            x = np.where(down, pelvis[landing, 0], x)
        heels[foot] = np.stack([x - 0.05, np.full(frames, 0.07), pelvis[:, 2] + side], axis=1)
        toes[foot] = np.stack([x + 0.15, np.full(frames, 0.025), pelvis[:, 2] + side], axis=1)
        planted[foot] = down
    return TrackMotion(track_id, first, pelvis, heels, toes, planted)


def chase(tracks, frames=150, cameras=None):
    if cameras is None:  # a video camera following at 4 m behind and to the side
        cameras = np.tile(np.eye(4), (frames, 1, 1))
        cameras[:, :3, 3] = np.stack([np.linspace(-1, 4, frames), np.full(frames, 1.6), np.full(frames, -4.0)], 1)
    people = [np.array([m.pelvis[t - m.first_frame] for m in tracks
                        if 0 <= t - m.first_frame < m.num_frames]).reshape(-1, 3) for t in range(frames)]
    view = ChaseView(people, cameras[:, :3, 3], 0.0, FPS)
    return view, ChaseFrames(view, tracks, cameras, np.array([800.0, 800.0, 480, 270]), (960, 540),
                             np.arange(frames) / FPS)


def test_the_person_stays_half_the_frame_high():
    track = walker()
    view, _ = chase([track])
    shares = []
    for t in range(track.num_frames):
        foot = track.pelvis[t] * [1, 0, 1]
        head = foot + [0.0, 1.7, 0.0]
        uv, z = view.project(np.stack([foot, head]), t)
        assert (z > 0).all()
        shares.append(abs(uv[0, 1] - uv[1, 1]) / view.height)
        assert 0 < uv[0, 0] < view.width and 0 < uv[1, 1] < view.height  # in the frame
    assert 0.4 < min(shares) and max(shares) < 0.6


def test_the_camera_glides_without_cuts():
    view, _ = chase([walker()])
    centres = view.poses[:, :3, 3]
    speed = np.linalg.norm(np.diff(centres, axis=0), axis=1) * FPS
    accel = np.linalg.norm(np.diff(centres, n=2, axis=0), axis=1) * FPS ** 2
    assert speed.max() < 2.5  # the walker's 1.3 m/s, never a jump
    assert accel.max() < 2.0
    # a group that splits: the camera widens smoothly rather than jumping
    a, b = walker(), walker(speed=-1.0, start=(0.0, 1.0), track_id=1)
    view, _ = chase([a, b])
    assert np.abs(np.diff(view.distance, n=2)).max() < 0.01
    assert view.distance[-1] > view.distance[0] + 1.0


def _print_pixels(image, track_id):
    colour = np.array(_darker(track_colour(track_id), 0.7))
    blended = 0.75 * colour + 0.25 * np.array(GROUND)
    return (np.abs(image.astype(float) - blended).max(axis=2) < 12)


def test_planted_feet_leave_prints_that_stay():
    track = walker()
    view, frames = chase([track])
    first = frames.frame(10, [], np.zeros((0, 3), np.int32))
    later = frames.frame(140, [], np.zeros((0, 3), np.int32))
    # the left foot's first landing, seen at frame 140 where it is still marked
    heel, toe = track.heels[0, 5], track.toes[0, 5]
    centre = (heel + toe) / 2 * [1, 0, 1]
    uv, z = view.project(centre[None], 140)
    u, v = np.round(uv[0]).astype(int)
    assert z[0] > 0 and 0 <= u < view.width and 0 <= v < view.height
    assert _print_pixels(later, 0)[v - 1:v + 2, u - 1:u + 2].any()
    assert _print_pixels(later, 0).sum() > 3 * _print_pixels(first, 0).sum() > 0  # a row of steps grows


def test_a_sliding_foot_draws_a_smear():
    planted, sliding = walker(), walker(slide=True)
    _, a = chase([planted])
    _, b = chase([sliding])
    faces = np.zeros((0, 3), np.int32)
    steps = _print_pixels(a.frame(149, [], faces), 0).sum()
    smear = _print_pixels(b.frame(149, [], faces), 0).sum()
    assert smear > 1.5 * steps


def test_time_scale_bar_and_inset_are_drawn():
    _, frames = chase([walker()])
    image = frames.frame(75, [], np.zeros((0, 3), np.int32))
    assert image.shape == (540, 960, 3)
    corner = image[540 - 135 - 10:540 - 10, 960 - 240 - 10:960 - 10]
    assert (np.abs(corner.astype(int) - 250).max(axis=2) > 60).sum() > 50  # paths and frustum on the map
    top_left = image[10:35, 10:300]
    assert (top_left.max(axis=2) < 100).sum() > 50  # the time
    floor = np.array(GROUND)  # the ground fills the view behind the walker (the horizon lies above the frame)
    assert (np.abs(image[100:120, 400:500].astype(int) - floor).max(axis=2) < 3).mean() > 0.3


def test_nobody_seen_still_draws():
    cameras = np.tile(np.eye(4), (5, 1, 1))
    view = ChaseView([np.zeros((0, 3))] * 5, cameras[:, :3, 3], 0.0, FPS)
    frames = ChaseFrames(view, [], cameras, np.array([500.0, 500.0, 480, 270]), (960, 540), np.arange(5) / FPS)
    assert frames.frame(2, [], np.zeros((0, 3), np.int32)).shape == (540, 960, 3)


@pytest.mark.parametrize("view", ["chase", "overview"])
def test_node_config_is_checked(view):
    from m3c.nodes.world_view import WorldViewNode

    node = WorldViewNode.__new__(WorldViewNode)
    node.config = WorldViewNode.Config(view=view)
    node.check(None)
    node.config = WorldViewNode.Config(view="sideways")
    with pytest.raises(ValueError, match="world_view.view must be one of chase, overview"):
        node.check(None)
