"""The track-merge rule on synthetic tracks: splits of one person are joined; two people (other clothes, or the
same clothes elsewhere), parts that overlap in time and parts too far apart in time are not. The slide rule: the
frames where a track showed another person coming back are handed to that person's track, and no others. The
colour-change rule: a track whose keypoint colours change for good as its own person comes back is split there."""

import numpy as np
import pytest

from m3c.perception.appearance import DESCRIPTOR_SIZE, bhattacharyya_distance
from m3c.perception.track_merge import (TrackMergeConfig, TrackSegment, hand_back_slides, merge_track_splits,
                                        piece_cost, split_colour_changes, split_cost)

FPS = 30.0


def descriptor(rng, base: int, noise: float = 0.02) -> np.ndarray:
    """A colour histogram concentrated on a few bins starting at `base` (people differ by base)."""
    d = np.full(DESCRIPTOR_SIZE, 1e-3)
    d[base:base + 4] += [0.4, 0.3, 0.2, 0.1]
    d = d * (1 + noise * rng.standard_normal(DESCRIPTOR_SIZE)).clip(0.5)
    return d / d.sum()


def segment(track_id, frames, start, velocity, base, rng, depth_noise=0.05) -> TrackSegment:
    """A person walking at `velocity` (m/frame) from `start` (camera frame), seen in `frames`, with a monocular
    depth that is off by a few percent per frame."""
    frames = np.asarray(frames)
    locations = np.asarray(start) + frames[:, None] * np.asarray(velocity)
    locations[:, 2] *= 1 + depth_noise * rng.standard_normal(len(frames))
    appearances = np.stack([descriptor(rng, base) for _ in frames])
    return TrackSegment(track_id, frames, locations, appearances)


def test_splits_of_one_person_are_merged(rng):
    # One player (clothes at bins 0..3) walking across at 1.5 m/s, 10 m away, split in three by detector misses.
    v = (0.05, 0.0, 0.0)
    parts = [segment(1, range(23), (-2.0, 0.8, 10.0), v, 0, rng),
             segment(6, range(24, 135), (-2.0, 0.8, 10.0), v, 0, rng),
             segment(12, range(138, 163), (-2.0, 0.8, 10.0), v, 0, rng)]
    other = segment(0, range(300), (3.0, 0.8, 11.0), (0, 0, 0), 20, rng)  # a man standing, the whole time
    assert merge_track_splits(parts + [other], FPS) == {1: 1, 6: 1, 12: 1, 0: 0}


def test_cost_matches_a_hand_computation(rng):
    a = segment(3, range(20), (0.0, 0.0, 8.0), (0.02, 0, 0), 0, rng, depth_noise=0.0)
    b = segment(4, range(25, 40), (0.1, 0.0, 8.0), (0.02, 0, 0), 0, rng, depth_noise=0.0)
    config = TrackMergeConfig()
    gap = 25 / FPS - 19 / FPS
    end, start = np.median(a.locations[-10:], axis=0), np.median(b.locations[:10], axis=0)
    mean_a, mean_b = a.appearances.mean(axis=0), b.appearances.mean(axis=0)
    appearance = bhattacharyya_distance(mean_a / mean_a.sum(), mean_b / mean_b.sum()) / config.max_appearance
    across = np.hypot(*(start - end)[:2]) / (config.max_distance + config.max_speed * gap)
    along = abs(start[2] - end[2]) / (config.depth_fraction * end[2] + config.max_speed * gap)
    assert split_cost(a, b, FPS, config) == pytest.approx(appearance + max(across, along), rel=1e-12)
    assert split_cost(b, a, FPS, config) is None  # b does not end before a starts


def test_two_people_are_not_merged(rng):
    # Someone leaves and someone else steps into the same place 3 frames later, in other clothes.
    first = segment(1, range(60), (1.0, 0.8, 9.0), (0, 0, 0), 0, rng)
    second = segment(2, range(63, 120), (1.0, 0.8, 9.0), (0, 0, 0), 24, rng)
    assert bhattacharyya_distance(first.appearances[0], second.appearances[0]) > 0.8
    assert merge_track_splits([first, second], FPS) == {1: 1, 2: 2}
    # Team-mates in the same kit: one leaves on the left, the other appears 5 m to the right.
    mate = segment(3, range(63, 120), (6.0, 0.8, 9.0), (0, 0, 0), 0, rng)
    assert merge_track_splits([first, mate], FPS) == {1: 1, 3: 3}
    # ... or at the same image place, but twice as far from the camera.
    behind = segment(4, range(63, 120), (2.0, 1.6, 18.0), (0, 0, 0), 0, rng)
    assert merge_track_splits([first, behind], FPS) == {1: 1, 4: 4}


def test_overlapping_or_distant_parts_are_not_merged(rng):
    # Same clothes, same place, overlapping frames: two people side by side (or a duplicate), never one.
    a = segment(1, range(60), (1.0, 0.8, 9.0), (0, 0, 0), 0, rng)
    b = segment(2, range(59, 120), (1.2, 0.8, 9.0), (0, 0, 0), 0, rng)
    assert merge_track_splits([a, b], FPS) == {1: 1, 2: 2}
    # A gap longer than max_gap_s.
    late = segment(3, range(60 + int(3.5 * FPS), 250), (1.0, 0.8, 9.0), (0, 0, 0), 0, rng)
    assert merge_track_splits([a, late], FPS) == {1: 1, 3: 3}
    assert merge_track_splits([a, late], FPS, TrackMergeConfig(max_gap_s=5.0)) == {1: 1, 3: 1}
    assert merge_track_splits([a, late], FPS, TrackMergeConfig(max_gap_s=5.0, enabled=False)) == {1: 1, 3: 3}


def test_two_people_split_at_once_are_joined_each_to_their_own(rng):
    # Two people walk towards each other and both tracks break at the crossing (frames 50-53); their second
    # parts start where the other's first part ended in image x, so only appearance and depth tell them apart.
    a1 = segment(10, range(50), (-1.5, 0.8, 8.0), (0.03, 0, 0), 0, rng)
    b1 = segment(11, range(50), (1.5, 0.8, 12.0), (-0.03, 0, 0), 24, rng)
    a2 = segment(20, range(54, 100), (-1.5, 0.8, 8.0), (0.03, 0, 0), 0, rng)
    b2 = segment(21, range(54, 100), (1.5, 0.8, 12.0), (-0.03, 0, 0), 24, rng)
    assert merge_track_splits([b2, a1, a2, b1], FPS) == {10: 10, 20: 10, 11: 11, 21: 11}


def test_unknown_cues_never_merge_and_bad_input_is_named(rng):
    a = segment(1, range(20), (0, 0.8, 9.0), (0, 0, 0), 0, rng)
    b = segment(2, range(22, 40), (0, 0.8, 9.0), (0, 0, 0), 0, rng)
    assert merge_track_splits([a, b], FPS) == {1: 1, 2: 1}
    no_location = TrackSegment(2, b.frames, np.full((len(b.frames), 3), np.nan), b.appearances)
    assert merge_track_splits([a, no_location], FPS) == {1: 1, 2: 2}
    no_colour = TrackSegment(2, b.frames, b.locations, np.full(b.appearances.shape, np.nan))
    assert merge_track_splits([a, no_colour], FPS) == {1: 1, 2: 2}
    with pytest.raises(ValueError, match="unique"):
        merge_track_splits([a, a], FPS)
    with pytest.raises(ValueError, match="increasing"):
        TrackSegment(5, [3, 2], np.zeros((2, 3)), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="fps"):
        merge_track_splits([a, b], 0.0)
    with pytest.raises(ValueError, match="max_gap_s"):
        TrackMergeConfig(max_gap_s=0)


def test_a_piece_inside_a_gap_joins_the_track_around_it(rng):
    # The player (bins 0..3) is lost for frames 100-105; frames 101-103 are a half-detected piece of her whose box
    # gives a depth 50% too far (and a height off), on her line of sight.
    player = segment(1, [*range(100), *range(106, 200)], (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    frames = np.arange(101, 104)
    truth = np.array([1.0, 0.8, 9.0]) + frames[:, None] * np.array([0.01, 0, 0])
    piece = TrackSegment(7, frames, truth * 1.5, np.stack([descriptor(rng, 0) for _ in frames]))
    man = segment(0, range(200), (-3.0, 0.8, 10.0), (0, 0, 0), 20, rng)
    assert split_cost(player, piece, FPS, TrackMergeConfig()) is None  # the split rule cannot take it
    assert merge_track_splits([player, piece, man], FPS) == {1: 1, 7: 1, 0: 0}
    assert merge_track_splits([player, piece, man], FPS, TrackMergeConfig(max_piece_s=0)) == {1: 1, 7: 7, 0: 0}
    # The cost by hand: appearance plus the worse end's distance across the line of sight at the player's depth.
    config = TrackMergeConfig()
    mean_a, mean_b = player.appearances.mean(axis=0), piece.appearances.mean(axis=0)
    appearance = bhattacharyya_distance(mean_a / mean_a.sum(), mean_b / mean_b.sum()) / config.max_appearance
    before, after = np.median(player.locations[90:100], axis=0), np.median(player.locations[100:110], axis=0)
    first, last = piece.locations[1], piece.locations[1]  # medians of 3 rows
    across = max(np.linalg.norm(first[:2] * before[2] / first[2] - before[:2]) / (0.75 + 3.0 * 2 / FPS),
                 np.linalg.norm(last[:2] * after[2] / last[2] - after[:2]) / (0.75 + 3.0 * 3 / FPS))
    assert piece_cost(player, piece, FPS, config) == pytest.approx(appearance + across, rel=1e-9)


def test_a_piece_whose_mask_colours_are_mixed_joins_by_its_keypoint_colours(rng):
    # The piece of the player coming out from behind a man: its patch's mask covers both, so the masks' colours
    # are half hers (bins 0..3) and half his (bins 20..23); the colours at her keypoints are hers.
    player = segment(1, [*range(100), *range(106, 200)], (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    player.pose_colours = np.stack([descriptor(rng, 40) for _ in player.frames])  # her kit at the keypoints
    frames = np.arange(101, 104)
    mixed = np.stack([0.5 * descriptor(rng, 0) + 0.5 * descriptor(rng, 20) for _ in frames])
    locations = np.array([1.0, 0.8, 9.0]) + frames[:, None] * np.array([0.01, 0, 0])
    piece = TrackSegment(7, frames, locations, mixed, np.stack([descriptor(rng, 40) for _ in frames]))
    config = TrackMergeConfig()
    mask_distance = bhattacharyya_distance(player.mean_appearance(), piece.mean_appearance())
    pose_distance = bhattacharyya_distance(player.mean_appearance(pose=True), piece.mean_appearance(pose=True))
    assert mask_distance > config.max_appearance and pose_distance < 0.1  # the premise
    assert merge_track_splits([player, piece], FPS) == {1: 1, 7: 1}
    without = TrackSegment(7, frames, locations, mixed)  # no keypoint colours: the masks' alone refuse it
    assert merge_track_splits([player, without], FPS) == {1: 1, 7: 7}
    # The cost: the keypoint colours' distance in units of max_piece_colour, plus the bearing's as before.
    across = piece_cost(player, piece, FPS, config) - pose_distance / config.max_piece_colour
    assert 0 <= across < 1
    # Someone else's keypoint colours (bins 60..63) keep it apart, and so does a tighter max_piece_colour.
    stranger = TrackSegment(8, frames, locations, mixed, np.stack([descriptor(rng, 60) for _ in frames]))
    assert merge_track_splits([player, stranger], FPS) == {1: 1, 8: 8}
    assert merge_track_splits([player, piece], FPS, TrackMergeConfig(max_piece_colour=0.5 * pose_distance)) == \
        {1: 1, 7: 7}
    with pytest.raises(ValueError, match="max_piece_colour"):
        TrackMergeConfig(max_piece_colour=0)


def test_pieces_of_someone_else_or_outside_a_gap_stay_apart(rng):
    player = segment(1, [*range(100), *range(106, 200)], (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    other_clothes = segment(7, range(101, 104), (2.0, 0.8, 9.0), (0.01, 0, 0), 24, rng)
    elsewhere = segment(8, range(101, 104), (-2.5, 0.8, 9.0), (0, 0, 0), 0, rng)  # same kit, 3.5 m to the left
    overlapping = segment(9, range(98, 104), (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)  # the player seen twice
    long_piece = segment(10, range(101, 104), (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    for piece in (other_clothes, elsewhere, overlapping):
        assert merge_track_splits([player, piece], FPS)[piece.track_id] == piece.track_id
    assert merge_track_splits([player, long_piece], FPS, TrackMergeConfig(max_piece_s=0.05))[10] == 10
    # Two pieces of the same gap at the same frames: only one can be the player.
    twin = segment(11, range(101, 104), (1.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    merged = merge_track_splits([player, long_piece, twin], FPS)
    assert sorted(merged[i] for i in (10, 11)) in ([1, 10], [1, 11])


# Slides: a tracked patch that followed a person coming out from behind -----------------------------------------
def skeleton(centre_u: float, height: float = 200.0, top: float = 100.0, confidence: float = 0.9) -> np.ndarray:
    """17 COCO keypoints (u, v, confidence) of an upright stick figure of `height` pixels centred at centre_u."""
    v = top + height * np.linspace(0.0, 1.0, 17)
    u = centre_u + 0.15 * height * np.sin(np.arange(17) * 1.3)
    return np.column_stack([u, v, np.full(17, confidence)])


def slide_scene(slide=range(20, 25), gap=range(15, 25), mix=0.3):
    """Person X at u = 400 and person Y at u = 470 (0.35 of their height apart), both drifting right. Track 0
    follows X but shows Y at the frames of `slide` (the first of them a blend, `mix` X); track 1 follows Y and
    misses the frames of `gap`."""
    x = {f: skeleton(400 + f) for f in range(30)}
    y = {f: skeleton(470 + f) for f in range(30)}
    track0 = dict(x)
    for f in slide:
        track0[f] = y[f].copy()
    track0[slide[0]][:, :2] = mix * x[slide[0]][:, :2] + (1 - mix) * y[slide[0]][:, :2]
    track1 = {f: y[f] for f in range(30) if f not in gap}
    return {0: track0, 1: track1}


def test_a_track_that_slid_onto_a_returning_person_hands_those_frames_back():
    tracks = slide_scene()
    moves = hand_back_slides(tracks)
    # Exactly the frames where track 0 showed Y; frame 20, 30% X, lies 0.13 of a height from Y's pose at 25 and
    # 0.22 from X's (drifted 5 frames): nearer Y, but not by SLIDE_RATIO, so a blend, dropped from both.
    assert moves == [(0, 1, list(range(21, 25)), [20])]
    assert set(tracks[0]) == set(range(30)) and set(tracks[1]) == set(range(30)) - set(range(15, 25))  # untouched
    # A first frame 10% X is Y's (0.06 against 0.29); one 50% X is not even nearer Y (0.20 against 0.15): the
    # slide starts at 21.
    assert hand_back_slides(slide_scene(mix=0.1)) == [(0, 1, list(range(20, 25)), [])]
    assert hand_back_slides(slide_scene(mix=0.5)) == [(0, 1, list(range(21, 25)), [])]
    # A slide of nothing but a blend (40% X: 0.145 against 0.205): dropped, nothing handed.
    assert hand_back_slides(slide_scene(slide=range(24, 25), gap=range(20, 25), mix=0.4)) == [(0, 1, [], [24])]
    # The cap, and the rule switched off.
    assert hand_back_slides(tracks, TrackMergeConfig(max_slide_frames=3)) == [(0, 1, [22, 23, 24], [])]
    assert hand_back_slides(tracks, TrackMergeConfig(max_slide_frames=0)) == []


def test_no_slide_without_a_jump_back_or_a_returning_track_where_it_was():
    # Track 1 was there the frame before: it did not come back.
    assert hand_back_slides(slide_scene(gap=range(15, 24))) == []
    # Track 0 never left X: no jump back.
    tracks = slide_scene()
    tracks[0] = {f: skeleton(400 + f) for f in range(30)}
    assert hand_back_slides(tracks) == []
    # Track 1 comes back far from where track 0 was (Y re-found 2 heights away).
    tracks = slide_scene()
    tracks[1] = {f: (skeleton(470 + f) if f < 15 else skeleton(870 + f)) for f in tracks[1]}
    assert hand_back_slides(tracks) == []
    # A jump of less than slide_jump (Y 0.35 heights from X) is no evidence.
    assert hand_back_slides(slide_scene(), TrackMergeConfig(slide_jump=0.5)) == []
    # Keypoints too unsure to compare.
    tracks = slide_scene()
    tracks[0][24] = skeleton(494, confidence=0.1)
    assert hand_back_slides(tracks) == []
    with pytest.raises(ValueError, match="max_slide_frames"):
        TrackMergeConfig(max_slide_frames=-1)
    with pytest.raises(ValueError, match="slide_jump"):
        TrackMergeConfig(slide_jump=0)


def test_the_perception_stage_moves_a_slides_records_with_their_cues_and_flows(caplog):
    from m3c.perception.pipeline import _hand_back_slides
    from m3c.perception.types import Person

    tracks = slide_scene()
    records = {i: [(f, Person(np.array([0.0, 0.0, 1.0, 1.0]), 0.9, k), None, None) for f, k in sorted(t.items())]
               for i, t in tracks.items()}
    cues = {i: [(np.array([float(f), float(i), 5.0]), None) for f, _ in sorted(t.items())] for i, t in tracks.items()}
    flows = {0: {f: np.full((4, 2), float(f)) for f in tracks[0]}}
    with caplog.at_level("INFO", logger="m3c.perception.pipeline"):
        moves = _hand_back_slides([0, 1], records, cues, flows, TrackMergeConfig())
    assert moves == [(0, 1, list(range(21, 25)), [20])]
    assert ("track 0 had slid onto the person of track 1: frames handed to it: 21-24; blends of the two people "
            "dropped: 20") in caplog.text
    # Frame 20, the blend, is in neither track.
    for i, frames in ((0, [f for f in range(30) if not 20 <= f < 25]), (1, [f for f in range(30) if not 15 <= f < 21])):
        assert [r[0] for r in records[i]] == frames
        assert [c[0][0] for c in cues[i]] == frames  # each cue still beside its frame's record
    assert np.array_equal(records[1][15][1].keypoints, tracks[0][21])  # frame 21: what track 0 saw there
    assert sorted(flows[1]) == list(range(21, 25)) and 20 not in flows[0] and 19 in flows[0]
    # Without a blend the log says so.
    clean = slide_scene(mix=0.1)
    records = {i: [(f, Person(np.array([0.0, 0.0, 1.0, 1.0]), 0.9, k), None, None) for f, k in sorted(t.items())]
               for i, t in clean.items()}
    cues = {i: [(None, None) for _ in t] for i, t in clean.items()}
    caplog.clear()
    with caplog.at_level("INFO", logger="m3c.perception.pipeline"):
        _hand_back_slides([0, 1], records, cues, {}, TrackMergeConfig())
    assert "frames handed to it: 20-24; blends of the two people dropped: none" in caplog.text


# Colour changes: a track that slid onto someone for good while its own person came back as a new track -----------
def colour(share_a: float) -> np.ndarray:
    """A keypoint colour descriptor: person A's colours (bins 0..3) for share_a of it, B's (bins 40..43) for the
    rest."""
    a, b = np.zeros(DESCRIPTOR_SIZE), np.zeros(DESCRIPTOR_SIZE)
    a[0:4], b[40:44] = [0.4, 0.3, 0.2, 0.1], [0.4, 0.3, 0.2, 0.1]
    return share_a * a + (1 - share_a) * b


def change_scene(new_start: int = 48, new_share_a: float = 1.0, blend=(0.8, 0.5, 0.2)):
    """Track 0 follows A (frames 0-119) until it slides onto B at frames 40-42 (the keypoint colours of `blend`)
    and stays on B; B's own track 1 ended at frame 20; A comes back as track 2 from new_start (its colours
    new_share_a A's); track 3 is someone else (bins 80..83) throughout."""
    track0 = {f: colour(1.0) if f < 40 else colour(0.0) for f in range(120)}
    for f, share in zip(range(40, 43), blend):
        track0[f] = colour(share)
    other = np.zeros(DESCRIPTOR_SIZE)
    other[80:84] = [0.4, 0.3, 0.2, 0.1]
    return {0: track0, 1: {f: colour(0.0) for f in range(21)},
            2: {f: colour(new_share_a) for f in range(new_start, 120)}, 3: {f: other for f in range(120)}}


def test_a_track_whose_colours_change_as_its_person_comes_back_is_split_there():
    scene = change_scene()
    [(track, new, first, dropped)] = split_colour_changes(scene, FPS)
    assert (track, new) == (0, 2)
    # The mixed frame (half A, half B) is dropped; what is kept before the split is mostly A, after it mostly B.
    assert 41 in dropped and set(dropped) <= {40, 41, 42}
    kept = [f for f in scene[0] if f not in dropped]
    assert all(scene[0][f][:4].sum() >= 0.8 for f in kept if f < first)
    assert all(scene[0][f][:4].sum() <= 0.2 for f in kept if f >= first)
    # A colour unknown in some frames changes nothing.
    scene[0][30], scene[0][50] = None, None
    assert split_colour_changes(scene, FPS)[0][:2] == (0, 2)
    assert split_colour_changes(scene, FPS, TrackMergeConfig(colour_window=0)) == []
    assert split_colour_changes({0: {}, 1: {}}, FPS) == []  # tracks without frames


def test_no_colour_split_without_a_lasting_change_and_a_new_track_like_before():
    # The new track wears B's colours (someone else), or comes more than max_reappear_s after the change.
    assert split_colour_changes(change_scene(new_share_a=0.0), FPS) == []
    assert split_colour_changes(change_scene(new_start=80), FPS) == []
    assert split_colour_changes(change_scene(new_start=80), FPS, TrackMergeConfig(max_reappear_s=1.5)) != []
    # No lasting change: track 0 shows B for three frames only.
    scene = change_scene()
    scene[0] = {f: colour(0.0) if 40 <= f < 43 else colour(1.0) for f in range(120)}
    assert split_colour_changes(scene, FPS) == []
    # A change under min_colour_change: B dressed nearly as A.
    scene = change_scene()
    scene[0] = {f: colour(1.0) if f < 40 else colour(0.9) for f in range(120)}
    assert split_colour_changes(scene, FPS) == []
    with pytest.raises(ValueError, match="colour_window"):
        TrackMergeConfig(colour_window=-1)
    with pytest.raises(ValueError, match="min_colour_change"):
        TrackMergeConfig(min_colour_change=0)


def test_parts_kept_apart_are_not_merged_again(rng):
    before = segment(1, range(40), (0.0, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    after = segment(2, range(41, 80), (0.41, 0.8, 9.0), (0.01, 0, 0), 0, rng)
    assert merge_track_splits([before, after], FPS) == {1: 1, 2: 1}
    assert merge_track_splits([before, after], FPS, apart={frozenset((1, 2))}) == {1: 1, 2: 2}


def test_the_perception_stage_splits_records_cues_and_flows_at_a_colour_change():
    from m3c.perception.pipeline import _split_colour_changes
    from m3c.perception.types import Person

    scene = change_scene()
    records = {i: [(f, Person(np.array([0.0, 0.0, 1.0, 1.0]), 0.9, skeleton(400.0)), None, None) for f in sorted(t)]
               for i, t in scene.items()}
    cues = {i: [(np.array([float(f), float(i), 5.0]), None, t[f]) for f in sorted(t)] for i, t in scene.items()}
    flows = {0: {f: np.full((4, 2), float(f)) for f in scene[0]}}
    ids = [0, 1, 2, 3]
    [(_, _, first, dropped)] = split_colour_changes(scene, FPS)
    assert _split_colour_changes(ids, records, cues, flows, FPS, TrackMergeConfig()) == {frozenset((0, 4))}
    assert ids == [0, 1, 2, 3, 4]
    for i, frames in ((0, [f for f in range(first) if f not in dropped]),
                      (4, [f for f in range(first, 120) if f not in dropped])):
        assert [r[0] for r in records[i]] == frames
        assert [c[0][0] for c in cues[i]] == frames  # each cue still beside its frame's record
        assert sorted(flows[i]) == frames
