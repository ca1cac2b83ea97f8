"""BVH motion capture (Biovision hierarchy): reading and writing the skeleton, the channels, and world joint
positions.

Conventions of the format, as the files in the wild use them: each joint's CHANNELS are applied in the order
listed, rotations compose left to right (R = R_c1 R_c2 R_c3, angles in degrees) and map the joint's frame into
its parent's. A joint with position channels takes them as its translation in the parent's frame (its OFFSET
is the rest value of the same thing, e.g. Bandai Namco files repeat the offset in every frame); a joint
without takes its OFFSET. End Sites become joints without channels, named "<parent>_end".
Units are the file's own (CMU: about 5.6 cm per unit; many files: cm); the up axis is usually y.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from m3c.io.atomic import atomic_path

import numpy as np
from scipy.spatial.transform import Rotation

_AXES = {"Xrotation": "x", "Yrotation": "y", "Zrotation": "z"}
_POSITIONS = {"Xposition": 0, "Yposition": 1, "Zposition": 2}


class BVHError(ValueError):
    """A BVH file that cannot be read: the message names the file, the line and what was expected."""


@dataclass
class BVHJoint:
    name: str
    parent: int            # index into BVHMotion.joints, -1 for the root
    offset: np.ndarray     # (3,) in the parent's frame, file units
    channels: list[str]    # e.g. ["Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation"]
    channel_start: int     # first column of this joint's channels in the motion table
    end_site: bool = False


@dataclass
class BVHMotion:
    joints: list[BVHJoint]
    frame_time: float      # seconds
    motion: np.ndarray     # (F, C) channel values as in the file
    path: str = ""

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time

    @property
    def num_frames(self) -> int:
        return len(self.motion)

    @property
    def names(self) -> list[str]:
        return [j.name for j in self.joints]

    def index(self, name: str) -> int:
        for i, joint in enumerate(self.joints):
            if joint.name == name:
                return i
        raise KeyError(f"{self.path or 'BVH'}: no joint named {name!r}; joints are {self.names}")

    def world_transforms(self, frames=None) -> tuple[np.ndarray, np.ndarray]:
        """World rotations (F, J, 3, 3) and positions (F, J, 3) of every joint (file units) by forward
        kinematics."""
        motion = self.motion if frames is None else self.motion[frames]
        F, J = len(motion), len(self.joints)
        rot = np.zeros((F, J, 3, 3))
        pos = np.zeros((F, J, 3))
        for j, joint in enumerate(self.joints):
            local_t = np.tile(joint.offset, (F, 1))
            axes, angle_cols = "", []
            for k, ch in enumerate(joint.channels):
                col = joint.channel_start + k
                if ch in _POSITIONS:
                    local_t[:, _POSITIONS[ch]] = motion[:, col]
                else:
                    axes += _AXES[ch]
                    angle_cols.append(col)
            if axes:
                # Upper-case axes: intrinsic rotations, R = R_a1 R_a2 R_a3 in the listed order.
                local_r = Rotation.from_euler(axes.upper(), motion[:, angle_cols], degrees=True).as_matrix()
            else:
                local_r = np.tile(np.eye(3), (F, 1, 1))
            if joint.parent < 0:
                rot[:, j], pos[:, j] = local_r, local_t
            else:
                p = joint.parent
                rot[:, j] = rot[:, p] @ local_r
                pos[:, j] = pos[:, p] + np.einsum("fij,fj->fi", rot[:, p], local_t)
        return rot, pos

    def positions(self, frames=None) -> np.ndarray:
        """World joint positions (F, J, 3) in file units."""
        return self.world_transforms(frames)[1]


def _tokens(text: str):
    for line_no, line in enumerate(text.splitlines(), start=1):
        for tok in line.split():
            yield line_no, tok


def read_bvh(path: str | Path) -> BVHMotion:
    """Parses a BVH file. Raises BVHError naming the line for malformed files."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"BVH file not found: {path}")
    return parse_bvh(path.read_text(errors="replace"), path)


def parse_bvh(text: str, path: str | Path = "BVH") -> BVHMotion:
    """Parses BVH text (e.g. a member of an archive); `path` names it in errors and in BVHMotion.path."""
    head, sep, tail = text.partition("MOTION")
    if not sep:
        raise BVHError(f"{path}: no MOTION section; is this a BVH file?")
    tokens = list(_tokens(head))
    if not tokens or tokens[0][1] != "HIERARCHY":
        raise BVHError(f"{path}: expected HIERARCHY at the start of the file")

    joints: list[BVHJoint] = []
    stack: list[int] = []
    num_channels = 0
    i = 1

    def expect(want: str):
        nonlocal i
        if i >= len(tokens) or tokens[i][1] != want:
            where = f"line {tokens[i][0]}" if i < len(tokens) else "end of the hierarchy"
            got = tokens[i][1] if i < len(tokens) else "nothing"
            raise BVHError(f"{path}: expected {want!r} at {where}, got {got!r}")
        i += 1

    def number() -> float:
        nonlocal i
        line, tok = tokens[i]
        try:
            value = float(tok)
        except ValueError:
            raise BVHError(f"{path}: line {line}: expected a number, got {tok!r}") from None
        i += 1
        return value

    while i < len(tokens):
        line, tok = tokens[i]
        if tok in ("ROOT", "JOINT"):
            if tok == "ROOT" and stack:
                raise BVHError(f"{path}: line {line}: ROOT inside another joint")
            name = tokens[i + 1][1]
            i += 2
            expect("{")
            expect("OFFSET")
            offset = np.array([number(), number(), number()])
            expect("CHANNELS")
            count = int(number())
            channels = [tokens[i + k][1] for k in range(count)]
            bad = [c for c in channels if c not in _AXES and c not in _POSITIONS]
            if bad:
                raise BVHError(f"{path}: line {line}: unknown channels {bad}")
            i += count
            joints.append(BVHJoint(name, stack[-1] if stack else -1, offset, channels, num_channels))
            num_channels += count
            stack.append(len(joints) - 1)
        elif tok == "End":
            if not stack:
                raise BVHError(f"{path}: line {line}: End Site outside a joint")
            i += 2  # "End Site"
            expect("{")
            expect("OFFSET")
            offset = np.array([number(), number(), number()])
            expect("}")
            joints.append(BVHJoint(joints[stack[-1]].name + "_end", stack[-1], offset, [], num_channels, True))
        elif tok == "}":
            if not stack:
                raise BVHError(f"{path}: line {line}: unbalanced '}}'")
            stack.pop()
            i += 1
        else:
            raise BVHError(f"{path}: line {line}: unexpected {tok!r} in the hierarchy")
    if stack:
        raise BVHError(f"{path}: the hierarchy has {len(stack)} unclosed joint(s)")
    if not joints:
        raise BVHError(f"{path}: the hierarchy has no joints")

    lines = [ln for ln in tail.splitlines() if ln.strip()]
    try:
        frames = int(lines[0].split(":")[1])
        frame_time = float(lines[1].split(":")[1])
    except (IndexError, ValueError):
        raise BVHError(f"{path}: the MOTION section must start with 'Frames: N' and 'Frame Time: dt'") from None
    if frame_time <= 0:
        raise BVHError(f"{path}: Frame Time must be positive, got {frame_time}")
    rows = lines[2:2 + frames]
    if len(rows) < frames:
        raise BVHError(f"{path}: the header promises {frames} frames, the file has {len(rows)}")
    try:
        flat = np.array(" ".join(rows).split(), dtype=np.float64)  # one conversion: fast on long clips
        if flat.size != frames * num_channels:  # rows of unequal length: the row-wise reading names it
            flat = np.array([[float(v) for v in row.split()] for row in rows], dtype=np.float64)
        motion = flat.reshape(frames, -1)
    except ValueError:
        raise BVHError(f"{path}: a motion row is not numeric or rows differ in length") from None
    if motion.shape[1] != num_channels:
        raise BVHError(f"{path}: motion rows have {motion.shape[1]} values, the hierarchy declares {num_channels} "
                       "channels")
    return BVHMotion(joints, frame_time, motion, str(path))


def _format(values) -> str:
    return " ".join(f"{v:.6f}" for v in values)


def write_bvh(path: str | Path, bvh: BVHMotion) -> None:
    """Writes `bvh` as a BVH file (atomically), in the conventions read_bvh reads. Joints may come in any order
    with parents before children; the file nests them depth first and orders the motion columns to match."""
    joints = bvh.joints
    if not joints or joints[0].parent != -1 or any(j.parent >= i or (i and j.parent < 0)
                                                    for i, j in enumerate(joints)):
        raise ValueError("write_bvh needs one root first and every parent before its children")
    if not np.all(np.isfinite(bvh.motion)):
        raise ValueError("the motion has NaN or infinite values; BVH cannot store them")
    children: list[list[int]] = [[] for _ in joints]
    for i, joint in enumerate(joints[1:], start=1):
        children[joint.parent].append(i)
    lines, columns = ["HIERARCHY"], []

    def emit(i: int, depth: int) -> None:
        joint, pad = joints[i], "  " * depth
        if joint.end_site:
            lines.extend([f"{pad}End Site", f"{pad}{{", f"{pad}  OFFSET {_format(joint.offset)}", f"{pad}}}"])
            return
        lines.extend([f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {joint.name}", f"{pad}{{",
                      f"{pad}  OFFSET {_format(joint.offset)}",
                      f"{pad}  CHANNELS {len(joint.channels)} {' '.join(joint.channels)}"])
        columns.extend(range(joint.channel_start, joint.channel_start + len(joint.channels)))
        for child in children[i]:
            emit(child, depth + 1)
        lines.append(f"{pad}}}")

    emit(0, 0)
    lines.extend(["MOTION", f"Frames: {bvh.num_frames}", f"Frame Time: {bvh.frame_time:.8f}"])
    motion = bvh.motion[:, columns]
    lines.extend(_format(row) for row in motion)
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")
