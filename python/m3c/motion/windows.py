"""The world optimization of a long video in overlapping windows of frames, so its memory does not grow with the
video's length: one problem over T frames holds every frame's residual blocks and Jacobians at once (about
0.6 MB per person-frame in the default recipe), a window holds only its own.

Each window is an ordinary `optimize` call on the cameras and the pieces of the tracks inside it. Where two
windows overlap their solutions are blended with weights that ramp linearly across the overlap (rotations by
slerp), so the result is continuous; each frame's camera is the blend of the windows' metric cameras (each
window estimates its own camera scale when the recipe frees it, which also follows a slow drift of the
odometry's scale). A video no longer than one window is optimised as one problem, exactly as `optimize` does.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from m3c.camera import WorldCameras
from m3c.motion.config import OptimizerConfig
from m3c.motion.interpolate import slerp
from m3c.motion.optimize import Cameras, StageResult, Track, WorldResult, optimize

# A track's piece in a window shorter than this (frames) is left to the neighbouring window that holds more of
# it: a few frames at a window's edge barely constrain a body. The overlap must be at least this long.
MIN_PIECE_FRAMES = 10


def check_windows(window: int, overlap: int) -> None:
    """ValueError unless `window` (0 = no windows) and `overlap` make usable windows."""
    if window == 0:
        return
    if window < 2 * MIN_PIECE_FRAMES or not MIN_PIECE_FRAMES <= overlap <= window // 2:
        raise ValueError(f"optimization windows need window >= {2 * MIN_PIECE_FRAMES} frames (or 0 for none) and "
                         f"{MIN_PIECE_FRAMES} <= window_overlap <= window / 2, got window={window}, "
                         f"window_overlap={overlap}")


def window_ranges(num_frames: int, window: int, overlap: int) -> list[tuple[int, int]]:
    """[(start, stop)) of the windows over num_frames frames: as few windows of `window` frames as cover them with
    at least `overlap` frames shared by neighbours, spread evenly (the last one ends at num_frames). One window when
    num_frames <= window. Every frame lies in one or two windows."""
    if window < 1 or overlap < 0 or 2 * overlap > window:
        raise ValueError(f"windows need window >= 1 and 0 <= overlap <= window / 2, got window={window}, "
                         f"overlap={overlap}")
    if num_frames <= window:
        return [(0, num_frames)]
    count = int(np.ceil((num_frames - overlap) / (window - overlap)))
    starts = np.round(np.linspace(0, num_frames - window, count)).astype(int)
    return [(int(s), int(s) + window) for s in starts]


def window_weights(ranges: list[tuple[int, int]], num_frames: int) -> np.ndarray:
    """(windows, num_frames) blending weights: 1 inside a window alone, ramping linearly between neighbours across
    their overlap (the earlier window falling, the later rising), 0 outside; columns sum to 1."""
    weights = np.zeros((len(ranges), num_frames))
    for k, (start, stop) in enumerate(ranges):
        w = np.ones(stop - start)
        t = np.arange(start, stop)
        if k > 0 and ranges[k - 1][1] > start:  # overlap with the previous window: rise
            length = ranges[k - 1][1] - start
            w = np.where(t < start + length, (t - start + 0.5) / length, w)
        if k + 1 < len(ranges) and ranges[k + 1][0] < stop:  # overlap with the next window: fall
            begin = ranges[k + 1][0]
            w = np.where(t >= begin, np.minimum(w, 1.0 - (t - begin + 0.5) / (stop - begin)), w)
        weights[k, start:stop] = w
    return weights


def _piece(track: Track, start: int, stop: int) -> Track | None:
    """The part of `track` within frames [start, stop), in the window's frame numbering (first frame 0)."""
    lo, hi = max(track.first_frame, start), min(track.first_frame + track.num_frames, stop)
    if hi <= lo:
        return None
    rows = slice(lo - track.first_frame, hi - track.first_frame)

    def cut(value):
        return None if value is None else np.asarray(value)[rows]

    return replace(track, first_frame=lo - start, keypoints=np.asarray(track.keypoints)[rows],
                   transl=np.asarray(track.transl)[rows], root_orient=np.asarray(track.root_orient)[rows],
                   body_pose=np.asarray(track.body_pose)[rows], betas=np.asarray(track.betas),
                   ground_normal=cut(track.ground_normal), ground_offset=cut(track.ground_offset),
                   contacts=cut(track.contacts), ground_contacts=cut(track.ground_contacts))


def blended_scale_and_offset(weights: np.ndarray, scales, offsets) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the scale (T,) and offset (T, 3) of the windows' cameras blended with `weights` (windows, T): the
    blend sum_w a_wt (s_w c_t + o_w) of the windows' metric camera centres is the centre c_t (VO units) at scale
    sum_w a_wt s_w and offset sum_w a_wt o_w."""
    return weights.T @ np.asarray(scales, dtype=np.float64), weights.T @ np.asarray(offsets, dtype=np.float64)


@dataclass
class WindowedResult(WorldResult):
    """A WorldResult over windows: camera_scale and camera_offset are the frame-weighted means of the windows'
    values (results report one figure); each frame's camera is the blend of the windows' metric cameras, at
    frame_scale (T,) and frame_offset (T, 3) (blended_scale_and_offset), and `windows` lists each window's frames,
    scale and offset."""

    frame_scale: np.ndarray | None = None  # (T,) metres per VO unit
    frame_offset: np.ndarray | None = None  # (T, 3) metres
    windows: list | None = None

    def world_cameras(self, cameras: Cameras) -> WorldCameras:
        return WorldCameras.from_vo(cameras.world_from_cam, self.frame_scale, offset=self.frame_offset)


def optimize_in_windows(model, tracks: list[Track], cameras: Cameras, config: OptimizerConfig | None = None,
                        window: int = 0, overlap: int = 0, log=None, **kwargs) -> WorldResult:
    """`optimize` over windows of `window` frames overlapping by `overlap` (window 0, or a video no longer than
    one window: one problem, `optimize` itself). kwargs go to every `optimize` call (motion_prior, pose_prior, fps,
    keypoint_regressor). log: a logger told each window's progress."""
    config = config or OptimizerConfig.default()
    world_from_cam = np.asarray(cameras.world_from_cam, dtype=np.float64)
    T = len(world_from_cam)
    if window <= 0 or T <= window:
        return optimize(model, tracks, cameras, config, **kwargs)
    check_windows(window, overlap)
    ranges = window_ranges(T, window, overlap)
    weights = window_weights(ranges, T)
    intrinsics = np.asarray(cameras.intrinsics, dtype=np.float64)
    if intrinsics.shape == (4,):
        intrinsics = np.tile(intrinsics, (T, 1))

    solved: list[dict[int, Track]] = []  # per window: track index -> its optimised piece (window numbering)
    latents: list[dict[int, np.ndarray]] = []
    results: list[WorldResult] = []
    for k, (start, stop) in enumerate(ranges):
        pieces, owners = [], []
        for p, track in enumerate(tracks):
            piece = _piece(track, start, stop)
            if piece is None or piece.num_frames < min(MIN_PIECE_FRAMES, track.num_frames):
                continue
            if not (np.asarray(piece.keypoints)[..., 2] >= config.min_confidence).any():
                continue  # nothing to score in this window: the neighbour's solution (or the lift) holds
            pieces.append(piece)
            owners.append(p)
        if log is not None:
            log.info("optimization window %d/%d: frames %d..%d, %d track piece(s)", k + 1, len(ranges), start,
                     stop - 1, len(pieces))
        window_cams = Cameras(world_from_cam[start:stop], intrinsics[start:stop], cameras.static,
                              cameras.initial_scale, cameras.scale_sigma,
                              None if cameras.times is None else np.asarray(cameras.times)[start:stop])
        if pieces:
            result = optimize(model, pieces, window_cams, config, **kwargs)
        else:  # no one to optimise: the cameras at the initial scale
            result = WorldResult([], float(cameras.initial_scale), np.zeros(3), [], False, [])
        results.append(result)
        solved.append(dict(zip(owners, result.tracks)))
        latents.append({p: lat for p, lat in zip(owners, result.latent_poses) if lat is not None})

    # Cameras: each window's metric cameras, blended.
    frame_scale, frame_offset = blended_scale_and_offset(weights, [r.camera_scale for r in results],
                                                         [r.camera_offset for r in results])
    out_tracks = [_blend_track(track, p, ranges, weights, solved) for p, track in enumerate(tracks)]
    out_latents = [_blend_latent(track, p, ranges, weights, latents) for p, track in enumerate(tracks)]
    frames_weight = weights.sum(axis=1)
    scale = float(np.average([r.camera_scale for r in results], weights=frames_weight))
    offset = np.average([np.asarray(r.camera_offset) for r in results], axis=0, weights=frames_weight)
    return WindowedResult(out_tracks, scale, offset, _merge_stages(results),
                          any(r.stopped_early for r in results), out_latents, frame_scale, frame_offset,
                          [{"frames": [start, stop], "camera_scale": float(r.camera_scale),
                            "camera_offset": [float(v) for v in r.camera_offset]}
                           for (start, stop), r in zip(ranges, results)])


def _blend_track(track: Track, p: int, ranges, weights: np.ndarray, solved: list[dict[int, Track]]) -> Track:
    """Track p's optimised values over its frames: the windows that solved a piece of it, blended with their
    weights renormalised over those windows; frames no window solved keep the input values."""
    n, first = track.num_frames, track.first_frame
    frames = np.arange(first, first + n)
    transl = np.array(track.transl, dtype=np.float64, copy=True)
    root = np.array(track.root_orient, dtype=np.float64, copy=True)
    body = np.array(track.body_pose, dtype=np.float64, copy=True)
    total = np.zeros(n)
    betas_sum, betas_weight = np.zeros_like(np.asarray(track.betas, dtype=np.float64)), 0.0
    for k, (start, _) in enumerate(ranges):
        piece = solved[k].get(p)
        if piece is None:
            continue
        rows = np.arange(piece.num_frames) + piece.first_frame + start - first  # rows of the track
        w = weights[k, frames[rows]]
        share = np.where(total[rows] + w > 0, w / np.maximum(total[rows] + w, 1e-300), 0.0)
        fresh = total[rows] == 0  # the first window to cover a frame sets it
        transl[rows] = np.where(fresh[:, None], piece.transl, (1 - share)[:, None] * transl[rows]
                                + share[:, None] * piece.transl)
        root[rows] = slerp(root[rows], np.asarray(piece.root_orient), np.where(fresh, 1.0, share))
        body[rows] = slerp(body[rows], np.asarray(piece.body_pose), np.where(fresh, 1.0, share)[:, None])
        total[rows] += w
        betas_sum += w.sum() * np.asarray(piece.betas, dtype=np.float64)
        betas_weight += w.sum()
    betas = betas_sum / betas_weight if betas_weight > 0 else np.asarray(track.betas, dtype=np.float64)
    return replace(track, first_frame=first, keypoints=np.asarray(track.keypoints), transl=transl,
                   root_orient=root, body_pose=body, betas=betas)




def _blend_latent(track: Track, p: int, ranges, weights: np.ndarray, latents: list[dict[int, np.ndarray]]):
    """Track p's VPoser latents blended linearly as its poses are; None unless every window that solved a piece of
    it had them."""
    pieces = [(k, latents[k][p]) for k in range(len(ranges)) if p in latents[k]]
    if not pieces:
        return None
    first = track.first_frame
    out = np.zeros((track.num_frames, pieces[0][1].shape[1]))
    total = np.zeros(track.num_frames)
    for k, latent in pieces:
        start = ranges[k][0]
        lo = max(first, start)
        rows = np.arange(len(latent)) + lo - first
        w = weights[k, rows + first]
        out[rows] += w[:, None] * latent
        total[rows] += w
    return np.where(total[:, None] > 0, out / np.maximum(total, 1e-300)[:, None], 0.0)


def _merge_stages(results: list[WorldResult]) -> list[StageResult]:
    """One report per stage over the windows: iterations, parts, seconds, objectives and term costs summed (the
    windows' problems are independent, so the sum is the objective of their union), the first non-"ok" status,
    every distinct message."""
    merged: dict[str, StageResult] = {}
    for result in results:
        for stage in result.stages:
            if stage.name not in merged:
                merged[stage.name] = StageResult(stage.name, stage.status, stage.message, stage.iterations,
                                                 stage.seconds, stage.objective_before, stage.objective_after,
                                                 stage.camera_scale, stage.world_before, stage.world_after,
                                                 {k: tuple(v) for k, v in stage.terms.items()}, stage.parts)
                continue
            m = merged[stage.name]
            if m.status == "ok" and stage.status != "ok":
                m.status = stage.status
            parts = m.message.split("; ") if m.message else []
            parts += [part for part in stage.message.split("; ") if part and part not in parts]
            m.message = "; ".join(parts)
            m.iterations += stage.iterations
            m.parts += stage.parts
            m.seconds += stage.seconds
            m.objective_before += stage.objective_before
            m.objective_after += stage.objective_after
            m.world_before += stage.world_before  # the windows' world checks add up as their objectives do
            m.world_after += stage.world_after
            for term, (before, after) in stage.terms.items():
                b, a = m.terms.get(term, (0.0, 0.0))
                m.terms[term] = (b + before, a + after)
    return list(merged.values())
