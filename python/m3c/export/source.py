"""What every exporter reads: a result folder's arrays, the body model that produced them, and per selected track
its frames, shape, rest skeleton and motion.

The body model is the one named in results.json: M3C's open model is found on its own; any other (SMPL, SMPL-X)
must be passed as a file, and its name must match, because the exported skeleton and mesh come from it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.body import OPEN_MODEL_NAME, default_body_model
from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.io.results import load_results

GROUND_MARGIN = 1.0  # metres of ground shown beyond the people's and the camera's paths


@dataclass
class TrackMotion:
    """One track over its own frames (valid in results.npz), world frame of the results (y up, metres)."""
    track_id: int
    index: int                  # row in results.npz's per-track arrays
    frames: np.ndarray          # (n,) indices into the processed frames (0..T-1), contiguous
    betas: np.ndarray           # (B,)
    rest_joints: np.ndarray     # (24, 3) joints of the rest pose at these betas, no translation (metres)
    pose: np.ndarray            # (n, 24, 3) axis-angle: world root orientation, then body_pose
    transl: np.ndarray          # (n, 3) SMPL translation in the world (metres)
    world_joints: np.ndarray    # (n, 24, 3) results.npz's joints (metres)
    # (n, 2, 15, 3) left, right SMPL-H finger poses (zeros: the rest hand, where none was fitted); None: the
    # body model has no hands, or the hands node did not run (--no-hands) and the results hold none
    hand_pose: np.ndarray | None = None
    hands: object = None        # m3c.body.hands.HandModel of the body model, with hand_pose

    @property
    def root_positions(self) -> np.ndarray:
        """(n, 3) the root joint's world position: the body rotates about its rest root, so J0 + transl."""
        return self.rest_joints[0] + self.transl


@dataclass
class ExportSource:
    folder: Path
    summary: dict
    arrays: dict
    model: object               # m3c.body.BodyModel
    tracks: list[TrackMotion]

    @property
    def fps(self) -> float:
        return float(self.arrays["fps"])

    @property
    def num_frames(self) -> int:
        return len(self.arrays["frame_ids"])

    @property
    def parents(self) -> np.ndarray:
        return np.asarray(self.model.parents, dtype=int)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return SMPL_JOINT_NAMES

    @property
    def ground_found(self) -> bool:
        return self.summary["world"]["ground"] == "y = 0"

    @property
    def intrinsics(self) -> np.ndarray:
        """(4,) fx, fy, cx, cy (pixels): the median over frames (M3C's are constant over a video)."""
        return np.median(self.arrays["intrinsics"].astype(np.float64), axis=0)

    @property
    def image_size(self) -> tuple[int, int]:
        width, height = (int(v) for v in self.arrays["image_size"])
        return width, height

    @property
    def vertical_fov(self) -> float:
        """The camera's vertical field of view (radians) from fy and the image height."""
        return float(2.0 * np.arctan(0.5 * self.image_size[1] / self.intrinsics[1]))

    def ground_extent(self, margin: float = GROUND_MARGIN) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) world x, z corners of a ground patch under every person's joints and every camera position,
        `margin` metres beyond them."""
        points = np.concatenate([t.world_joints.reshape(-1, 3) for t in self.tracks]
                                + [self.arrays["world_from_cam"][:, :3, 3].astype(np.float64)])
        return points[:, [0, 2]].min(axis=0) - margin, points[:, [0, 2]].max(axis=0) + margin


def results_body_model(summary: dict, body_model: str | Path | None = None):
    """The BodyModel named in results.json: the open model, or the file `body_model` (which must match)."""
    info = summary["body_model"]
    name = info["name"]
    if body_model is None:
        if name != OPEN_MODEL_NAME:
            raise ValueError(f"these results were made with the body model {name!r}; pass its file "
                             "(--body-model PATH, the same file `m3c run` was given) to export them")
        model = default_body_model()
    else:
        model = default_body_model(Path(body_model).expanduser(), num_betas=int(info["num_betas"]))
        if model.data.name != name:
            raise ValueError(f"the body model file {body_model} is {model.data.name!r}, but the results were made "
                             f"with {name!r}; pass that model's file")
    if model.num_joints != 24:
        raise ValueError(f"exports need SMPL's 24-joint layout; {name} has {model.num_joints} joints")
    return model


def select_tracks(track_ids: np.ndarray, wanted) -> list[int]:
    """Rows of the wanted track ids (all when wanted is None), in the order given; unknown ids are an error."""
    ids = [int(t) for t in track_ids]
    if wanted is None:
        return list(range(len(ids)))
    rows = []
    for t in wanted:
        if int(t) not in ids:
            raise ValueError(f"no track {t} in these results; tracks are {ids or 'none'} (see `m3c info OUT_DIR`)")
        rows.append(ids.index(int(t)))
    return rows


def parse_track_ids(text: str | None) -> list[int] | None:
    """'1,3' -> [1, 3]; None or '' -> None (every track)."""
    if not text:
        return None
    try:
        return [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise ValueError(f"--tracks takes comma-separated track ids (e.g. 1,3), got {text!r}") from None


def per_track_paths(source: ExportSource, out: Path, suffix: str, stem: str) -> list[Path]:
    """Where per-track files go: out itself for one track and a file name with `suffix`, else
    out/<stem>_track<ID><suffix>."""
    if out.suffix.lower() == suffix:
        if len(source.tracks) != 1:
            raise ValueError(f"{out} names one file but {len(source.tracks)} tracks are selected; give a folder, "
                             "or pick one track with --tracks")
        return [out]
    return [out / f"{stem}_track{t.track_id}{suffix}" for t in source.tracks]


def load_source(folder: str | Path, tracks=None, body_model: str | Path | None = None) -> ExportSource:
    """Reads OUT_DIR's results and the body model; `tracks` are tracker ids (None: every track)."""
    folder = Path(folder)
    summary, arrays = load_results(folder)
    model = results_body_model(summary, body_model)
    from m3c.body.hands import hand_model_for

    hands = hand_model_for(model.data.name)
    rows = select_tracks(arrays["track_ids"], tracks)
    if not rows:
        raise ValueError(f"{folder}: the results hold no tracks; nothing to export")
    motions = []
    for p in rows:
        frames = np.flatnonzero(arrays["valid"][p])
        betas = arrays["betas"][p].astype(np.float64)
        rest = model.joints(np.zeros((1, 24, 3)), betas)[0]
        pose = np.concatenate([arrays["world_root_orient"][p, frames][:, None], arrays["body_pose"][p, frames]],
                              axis=1).astype(np.float64)
        hand_pose = None
        if hands is not None and "left_hand_pose" in arrays:
            hand_pose = np.stack([arrays["left_hand_pose"][p, frames], arrays["right_hand_pose"][p, frames]],
                                 axis=1).astype(np.float64)
            # The rest hand where none was fitted; no fingers at all when the hands node did not run.
            hands_ran = bool(summary.get("hands", {}).get("enabled"))
            hand_pose = np.nan_to_num(hand_pose) if hands_ran or np.isfinite(hand_pose).any() else None
        motions.append(TrackMotion(int(arrays["track_ids"][p]), p, frames, betas, rest, pose,
                                   arrays["world_transl"][p, frames].astype(np.float64),
                                   arrays["world_joints"][p, frames].astype(np.float64), hand_pose,
                                   hands if hand_pose is not None else None))
    return ExportSource(folder, summary, arrays, model, motions)


@dataclass
class FingerSkeleton:
    """A track's 30 finger joints (left hand's 15 in SMPL-H order, then the right's) below the 24 SMPL joints:
    names, parents (indices into the 24 + 30 joints: the wrists, or the previous finger joint), rest (30, 3)
    rest positions, pose (n, 30, 3) local axis-angle, tips (10, 3) rest fingertips, tip_parents (10,)."""
    names: tuple[str, ...]
    parents: np.ndarray
    rest: np.ndarray
    pose: np.ndarray
    tips: np.ndarray
    tip_parents: np.ndarray


def finger_skeleton(track: TrackMotion) -> FingerSkeleton | None:
    """The track's fingers (m3c.body.hands), None when the results hold no hand poses for it."""
    from m3c.body.hands import HAND_JOINT_NAMES, HAND_PARENTS, SIDES, TIP_JOINTS, WRIST_JOINTS

    if track.hand_pose is None:
        return None
    _, joints, tips = track.hands.rest(track.betas)
    names, parents, tip_parents = [], [], []
    for s, side in enumerate(SIDES):
        first = 24 + 15 * s
        names += [f"{side}_{name}" for name in HAND_JOINT_NAMES]
        parents += [WRIST_JOINTS[side] if p < 0 else first + p for p in HAND_PARENTS]
        tip_parents += [first + j for j in TIP_JOINTS]
    return FingerSkeleton(tuple(names), np.asarray(parents), joints.reshape(30, 3),
                          track.hand_pose.reshape(len(track.frames), 30, 3), tips.reshape(10, 3),
                          np.asarray(tip_parents))


def finger_skin(track: TrackMotion, weights: np.ndarray) -> np.ndarray:
    """(V, 54) skinning weights with the fingers: the body model's (V, 24) `weights`, each hand vertex's weight
    on its hand joint (22, 23) moved onto the 15 finger joints (columns 24.., finger_skeleton's order) as the
    track's hand model weights it."""
    from m3c.body.hands import HAND_JOINTS, SIDES

    out = np.concatenate([np.asarray(weights, dtype=np.float64), np.zeros((len(weights), 30))], axis=1)
    for s, side in enumerate(SIDES):
        ids = track.hands.vertex_ids[side]
        out[ids, HAND_JOINTS[side]] = 0.0
        out[ids, 24 + 15 * s:39 + 15 * s] = track.hands.weights[side]
    return out
