"""3DPW (von Marcard et al., ECCV 2018) sequence files: sequenceFiles/{train,validation,test}/<name>.pkl.

Each file is a latin1 pickle (written by Python 2) holding a dict; per-person fields are lists with one entry
per actor (one or two people):
  sequence        str, the sequence name
  genders         'm' / 'f' per actor (the dataset's README calls the field `gender`; both are read)
  betas           (10,) or longer SMPL shape per actor (the first 10 are used)
  poses           (N, 72) SMPL axis-angle per actor, world frame, aligned with the N image frames
  trans           (N, 3) SMPL translation per actor, world frame, metres
  jointPositions  (N, 72) the 24 SMPL joints per actor, world frame
  poses2d         (N, 3, 18) OpenPose COCO-18 keypoints (x, y, confidence) per actor
  campose_valid   (N,) per actor: frames whose camera pose was aligned to the image (evaluate only these)
  cam_poses       (N, 4, 4) camera extrinsics: cam_from_world, OpenCV camera axes
  cam_intrinsics  (3, 3) K
  img_frame_ids   (N,) image index of each frame
Other fields (poses_60Hz, trans_60Hz, betas_clothed, v_template_clothed, texture_maps) are not read.
The video runs at 30 fps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from m3c.io import safe_pickle

FPS = 30.0
SPLITS = ("train", "validation", "test")
# OpenPose COCO-18 (nose, neck, r-shoulder, r-elbow, r-wrist, l-shoulder, l-elbow, l-wrist, r-hip, r-knee,
# r-ankle,
# l-hip, l-knee, l-ankle, r-eye, l-eye, r-ear, l-ear) rows giving M3C's COCO-17 order.
OPENPOSE18_TO_COCO17 = (0, 15, 14, 17, 16, 5, 2, 6, 3, 7, 4, 11, 8, 12, 9, 13, 10)


@dataclass
class ThreeDPWPerson:
    gender: str                # "male" or "female"
    betas: np.ndarray          # (10,)
    root_orient: np.ndarray    # (N, 3) world frame axis-angle
    body_pose: np.ndarray      # (N, 23, 3)
    transl: np.ndarray         # (N, 3) world frame, metres
    joints: np.ndarray         # (N, 24, 3) world frame, metres (the dataset's jointPositions)
    keypoints: np.ndarray      # (N, 17, 3) COCO-17 (u, v, confidence), from the OpenPose-18 poses2d
    valid: np.ndarray          # (N,) bool: campose_valid


@dataclass
class ThreeDPWSequence:
    name: str
    split: str
    cam_from_world: np.ndarray  # (N, 4, 4)
    intrinsics: np.ndarray      # (4,) fx, fy, cx, cy
    image_ids: np.ndarray       # (N,) int
    people: list[ThreeDPWPerson]
    fps: float = FPS

    @property
    def num_frames(self) -> int:
        return len(self.cam_from_world)

    @property
    def world_from_cam(self) -> np.ndarray:
        return np.linalg.inv(self.cam_from_world)


def _field(data: dict, path: Path, *names: str):
    for name in names:
        if name in data:
            return data[name]
    raise ValueError(f"{path}: not a 3DPW sequence file, the field {names[0]!r} is missing "
                     f"(fields: {sorted(data)})")


def _per_person(value, count: int, name: str, path: Path, shape_tail: tuple) -> list[np.ndarray]:
    items = list(value)
    if len(items) != count:
        raise ValueError(f"{path}: {name} has {len(items)} entries for {count} people")
    out = []
    for k, item in enumerate(items):
        arr = np.asarray(item, dtype=np.float64)
        if arr.shape[1:] != shape_tail and not (shape_tail == () and arr.ndim == 1):
            raise ValueError(f"{path}: {name}[{k}] must have shape (N, {', '.join(map(str, shape_tail))}), "
                             f"got {arr.shape}")
        out.append(arr)
    return out


def read_sequence(path: str | Path, split: str = "") -> ThreeDPWSequence:
    """Reads one 3DPW sequence .pkl (latin1 pickle, no chumpy needed)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"3DPW sequence file not found: {path} (3DPW is obtained from "
                                "https://virtualhumans.mpi-inf.mpg.de/3DPW/ and read from sequenceFiles/<split>/)")
    try:  # numpy arrays, lists and strings: nothing else is resolved (m3c.io.safe_pickle)
        data = safe_pickle.load_restricted(path, safe_pickle.DATA_GLOBALS, source=f"3DPW sequence {path}",
                                           encoding="latin1")
    except safe_pickle.UnsafePickleError:
        raise
    except Exception as err:
        raise ValueError(f"{path}: not a readable pickle ({err})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a 3DPW sequence file holds a dict, this one holds {type(data).__name__}")
    poses = _field(data, path, "poses")
    count = len(poses)
    poses = _per_person(poses, count, "poses", path, (72,))
    trans = _per_person(_field(data, path, "trans"), count, "trans", path, (3,))
    joints = _per_person(_field(data, path, "jointPositions"), count, "jointPositions", path, (72,))
    poses2d = _per_person(_field(data, path, "poses2d", "poses2D"), count, "poses2d", path, (3, 18))
    valid = [np.asarray(v, dtype=bool).reshape(-1) for v in _field(data, path, "campose_valid")]
    genders = list(_field(data, path, "genders", "gender"))
    betas = [np.asarray(b, dtype=np.float64).reshape(-1)[:10] for b in _field(data, path, "betas")]
    cam_from_world = np.asarray(_field(data, path, "cam_poses"), dtype=np.float64)
    K = np.asarray(_field(data, path, "cam_intrinsics"), dtype=np.float64)
    n = len(cam_from_world)
    if cam_from_world.shape != (n, 4, 4):
        raise ValueError(f"{path}: cam_poses must have shape (N, 4, 4), got {cam_from_world.shape}")
    if K.shape != (3, 3):
        raise ValueError(f"{path}: cam_intrinsics must have shape (3, 3), got {K.shape}")
    image_ids = np.asarray(data.get("img_frame_ids", np.arange(n)), dtype=np.int64).reshape(-1)

    people = []
    for k in range(count):
        lengths = {len(poses[k]), len(trans[k]), len(joints[k]), len(poses2d[k]), len(valid[k])}
        if lengths != {n}:
            raise ValueError(f"{path}: person {k}'s fields cover {sorted(lengths)} frames, the cameras {n}")
        if len(betas) != count or len(genders) != count or len(betas[k]) < 10:
            raise ValueError(f"{path}: betas/genders must list 10 shape values and a gender for each of "
                             f"{count} people")
        g = str(genders[k]).lower()
        gender = {"m": "male", "f": "female"}.get(g[:1])
        if gender is None:
            raise ValueError(f"{path}: gender {genders[k]!r} of person {k} is neither 'm' nor 'f'")
        kp18 = np.transpose(poses2d[k], (0, 2, 1))  # (N, 18, 3)
        people.append(ThreeDPWPerson(
            gender, betas[k], poses[k][:, :3].copy(), poses[k][:, 3:].reshape(n, 23, 3).copy(), trans[k].copy(),
            joints[k].reshape(n, 24, 3).copy(), kp18[:, list(OPENPOSE18_TO_COCO17)].copy(), valid[k]))
    intrinsics = np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    name = str(data.get("sequence", path.stem))
    return ThreeDPWSequence(name, split or path.parent.name, cam_from_world, intrinsics, image_ids, people)


def list_sequences(root: str | Path, split: str) -> list[Path]:
    """The sequence files of a split under a 3DPW root (which holds sequenceFiles/)."""
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    folder = Path(root) / "sequenceFiles" / split
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder} does not exist: pass the 3DPW root folder that holds sequenceFiles/")
    return sorted(folder.glob("*.pkl"))
