"""People of a synthetic sequence: retargeted motion-capture segments placed on the ground, and how they look
(per-part colours: skin, hair, top, trousers, shoes, varied per person from the seed)."""

from __future__ import annotations

import colorsys
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from m3c.body import BodyModel
from m3c.body.transform import rest_root_joint, transform_smpl
from m3c.eval.retarget import RetargetedMotion
from m3c.body.joint_names import CONTACT_JOINTS

UP = np.array([0.0, 1.0, 0.0])

# SMPL joint -> body part of the skin it drives (by the largest skinning weight).
PARTS = ("skin", "hair", "top", "trousers", "shoes")
_JOINT_PART = {
    0: "trousers",
    1: "trousers",
    2: "trousers",
    3: "top",
    4: "trousers",
    5: "trousers",
    6: "top",
    7: "shoes",
    8: "shoes",
    9: "top",
    10: "shoes",
    11: "shoes",
    12: "skin",
    13: "top",
    14: "top",
    15: "skin",
    16: "top",
    17: "top",
    18: "sleeve",
    19: "sleeve",
    20: "skin",
    21: "skin",
    22: "skin",
    23: "skin",
}
SKIN_TONES = np.array(
    [[0.96, 0.80, 0.69], [0.89, 0.67, 0.53], [0.78, 0.57, 0.44], [0.58, 0.40, 0.29], [0.40, 0.27, 0.20]]
)


@dataclass
class PersonLook:
    colours: dict  # part -> RGB in [0, 1]
    long_sleeves: bool

    @classmethod
    def random(cls, rng) -> PersonLook:
        def cloth():
            return np.array(
                colorsys.hsv_to_rgb(rng.uniform(0, 1), rng.uniform(0.3, 0.9), rng.uniform(0.25, 0.9))
            )

        colours = {
            "skin": SKIN_TONES[rng.integers(len(SKIN_TONES))] * rng.uniform(0.95, 1.05),
            "hair": np.array([0.08, 0.06, 0.05]) + rng.uniform(0, 0.35) * np.array([1.0, 0.8, 0.5]),
            "top": cloth(),
            "trousers": cloth() * 0.8,
            "shoes": np.full(3, rng.uniform(0.05, 0.9)),
        }
        return cls({k: np.clip(v, 0, 1) for k, v in colours.items()}, bool(rng.uniform() < 0.5))


def vertex_parts(model: BodyModel) -> np.ndarray:
    """(V,) index into PARTS of each vertex, from its dominant joint; hair: head vertices above the eyes and
    behind the face."""
    weights = np.asarray(model.data.weights)
    dominant = weights.argmax(axis=1)
    names = np.array([_JOINT_PART.get(int(j), "top") for j in range(weights.shape[1])])[dominant]
    rest = model.forward(np.zeros((1, model.num_joints, 3)), np.zeros(model.num_betas))
    verts, joints = rest.vertices[0], rest.joints[0]
    head = joints[15]
    hair = (
        (names == "skin")
        & (dominant == 15)
        & ((verts[:, 1] > head[1] + 0.07) | ((verts[:, 1] > head[1] - 0.02) & (verts[:, 2] < head[2] - 0.02)))
    )
    names = names.astype(object)
    names[hair] = "hair"
    return names


def face_colours(model: BodyModel, parts: np.ndarray, look: PersonLook, rng) -> np.ndarray:
    """(F, 3) float32 albedo: each face takes its first vertex's part; a little per-face variation (cloth)."""
    table = dict(look.colours)
    table["sleeve"] = table["top"] if look.long_sleeves else table["skin"]
    per_vertex = np.stack([table[p] for p in parts])
    faces = np.asarray(model.faces)
    albedo = per_vertex[faces[:, 0]] * rng.uniform(0.93, 1.07, size=(len(faces), 1))
    return np.clip(albedo, 0, 1).astype(np.float32)


@dataclass
class Person:
    clip: str
    start: int  # first clip frame used
    root_orient: np.ndarray  # (n, 3) world
    body_pose: np.ndarray  # (n, 23, 3)
    transl: np.ndarray  # (n, 3) world
    betas: np.ndarray  # (B,)
    look: PersonLook

    def pose(self) -> np.ndarray:
        return np.concatenate([self.root_orient[:, None], self.body_pose], axis=1)


def _displacement(clip: RetargetedMotion, n: int) -> np.ndarray:
    """Horizontal pelvis-translation displacement of every n-frame window of the clip."""
    xz = clip.transl[:, [0, 2]]
    return np.linalg.norm(xz[n - 1 :] - xz[: len(xz) - n + 1], axis=-1)


def place_people(
    model: BodyModel,
    clips: list[RetargetedMotion],
    count: int,
    n: int,
    rng,
    travelling_first: bool = False,
    tries: int = 200,
) -> list[Person]:
    """`count` people on the ground around the origin, each a random n-frame segment of a clip, turned and moved;
    people keep 0.5 m apart (pelvis) at every frame. travelling_first: person 0 is the segment of a clip that
    covers the most ground (a walker or runner to follow), heading along +z on average."""
    usable = [c for c in clips if c.num_frames >= n]
    if not usable:
        raise ValueError(
            f"no motion clip has {n} frames (longest: {max(c.num_frames for c in clips)}); ask for "
            "fewer frames or add longer clips (--clips / --mocap)"
        )
    for _ in range(tries):
        people = []
        for k in range(count):
            if k == 0 and travelling_first:
                moves = [_displacement(c, n) for c in usable]
                best = max(range(len(usable)), key=lambda i: moves[i].max())
                clip = usable[best]
                order = np.argsort(moves[best])[::-1]
                start = int(order[rng.integers(max(1, len(order) // 10))])
            else:
                clip = usable[rng.integers(len(usable))]
                start = int(rng.integers(0, clip.num_frames - n + 1))
            people.append(_place(model, clip, start, n, rng, k, count, k == 0 and travelling_first))
        if _apart(model, people, 0.5):
            return people
    raise ValueError(
        f"could not place {count} people {n} frames long without collisions in {tries} tries; ask "
        "for fewer people or frames"
    )


def _place(
    model, clip: RetargetedMotion, start: int, n: int, rng, k: int, count: int, heading_z: bool
) -> Person:
    def aim(move):
        if heading_z and np.linalg.norm(move) > 0.3:
            yaw = -np.arctan2(move[0], move[1])  # rotate the travel direction onto +z
        else:
            yaw = rng.uniform(0, 2 * np.pi)
        # Spread people around the origin; the travelling person passes through it.
        return yaw, np.zeros(2) if (heading_z or count == 1) else rng.uniform(-1.8, 1.8, size=2)

    return _segment_person(model, clip, start, n, rng, aim)


def _segment_person(model, clip: RetargetedMotion, start: int, n: int, rng, aim) -> Person:
    """The clip's n frames from `start` as a person of a new shape (the clip's betas, perturbed), turned by a yaw
    about the vertical and the middle of its pelvis path moved onto a spot (xz): aim(move) -> (yaw, spot), move
    the segment's horizontal pelvis travel; then standing on y = 0 (the new shape changes leg length: the lowest
    point over the segment, robustly)."""
    seg = slice(start, start + n)
    betas = clip.betas + 0.5 * rng.normal(size=clip.betas.shape)
    root, transl, body = clip.root_orient[seg].copy(), clip.transl[seg].copy(), clip.body_pose[seg].copy()
    j0 = rest_root_joint(model, betas)
    pelvis = transl + j0
    yaw, spot = aim(pelvis[-1, [0, 2]] - pelvis[0, [0, 2]])
    turn = Rotation.from_rotvec(yaw * UP).as_matrix()
    T = np.eye(4)
    T[:3, :3] = turn
    T[[0, 2], 3] = spot - (turn @ pelvis[[0, -1]].mean(axis=0))[[0, 2]]
    root, transl = transform_smpl(T, root, transl, j0)
    lowest = model.forward(np.concatenate([root[:, None], body], 1), betas, transl).vertices[:, :, 1].min(axis=1)
    transl[:, 1] -= np.quantile(lowest, 0.1)
    return Person(clip.info.get("name", "clip"), start, root, body, transl, betas, PersonLook.random(rng))


def _apart(model: BodyModel, people: list[Person], distance: float) -> bool:
    pelvis = [model.joints(p.pose(), p.betas, p.transl)[:, 0, [0, 2]] for p in people]
    for a in range(len(people)):
        for b in range(a + 1, len(people)):
            if np.min(np.linalg.norm(pelvis[a] - pelvis[b], axis=-1)) < distance:
                return False
    return True


# A background crowd (m3c.synth.sequence's `crowd`): walkers, not scored, at CROWD_DISTANCE metres from the
# camera inside its view, crossing it at an angle; CROWD_NEAR of them between the camera and the scored people.
CROWD_DISTANCE = (3.0, 25.0)
CROWD_NEAR = 0.2
CROWD_MIN_SPEED = 0.5  # m/s: the crowd's segments travel at least this fast (walkers, not bystanders)
CROWD_MAX_LIFT = 0.08  # m: and never lift both feet higher (a walk, not jumps)


def place_crowd(model: BodyModel, clips: list[RetargetedMotion], count: int, n: int, fps: float, rng,
                world_from_cam: np.ndarray, hfov: float, avoid: list[Person], tries: int = 50) -> list[Person]:
    """`count` walkers of n frames, each the fastest-travelling segments' random pick, placed so that the middle
    of its walk lies in the mid-sequence camera's view at a random distance within CROWD_DISTANCE (CROWD_NEAR
    of them nearer than the closest scored person) and its path crosses the view at 30-90 degrees to the line
    of sight; 0.5 m from everyone at every frame (a walker that cannot be placed in `tries` draws is left out)."""
    segments = []  # (clip, start) of every usable segment that walks: travels, a foot always on the ground
    for clip in clips:
        if clip.num_frames < n:
            continue
        moves = _displacement(clip, n)
        lowest = model.forward(clip.pose(), clip.betas, clip.transl).vertices[:, :, 1].min(axis=1)
        airborne = np.concatenate([[0], np.cumsum(lowest - np.quantile(lowest, 0.1) > CROWD_MAX_LIFT)])
        grounded = airborne[n:] - airborne[:-n] == 0
        starts = np.flatnonzero((moves >= CROWD_MIN_SPEED * n / fps) & grounded)
        segments += [(clip, int(s)) for s in starts[:: max(1, len(starts) // 20)]]
    if not segments:
        raise ValueError(f"no motion clip walks {CROWD_MIN_SPEED} m/s over {n} frames with a foot on the ground: a "
                         "crowd needs walking clips (--clips / --mocap)")
    mid = world_from_cam[len(world_from_cam) // 2]
    centre = mid[[0, 2], 3]
    forward = mid[[0, 2], 2] / max(np.linalg.norm(mid[[0, 2], 2]), 1e-9)
    scored = [model.joints(p.pose(), p.betas, p.transl)[:, 0, [0, 2]] for p in avoid]
    nearest = min((float(np.linalg.norm(j - centre, axis=-1).min()) for j in scored), default=CROWD_DISTANCE[1])
    paths: list[np.ndarray] = list(scored)
    crowd = []
    for k in range(count):
        for _ in range(tries):
            clip, start = segments[rng.integers(len(segments))]
            near = rng.uniform() < CROWD_NEAR
            low, high = (CROWD_DISTANCE[0], max(CROWD_DISTANCE[0] + 0.5, nearest - 1.0)) if near else CROWD_DISTANCE
            distance = float(np.sqrt(rng.uniform(low ** 2, high ** 2)))  # uniform over the view's area
            bearing = rng.uniform(-0.45, 0.45) * hfov
            ray = _turned(forward, bearing)
            spot = centre + distance * ray
            heading = _turned(ray, rng.choice([-1.0, 1.0]) * rng.uniform(np.pi / 6, np.pi / 2))
            yaw = np.arctan2(heading[0], heading[1])
            # The segment turned so that it travels along heading, the middle of its path at spot.
            person = _segment_person(model, clip, start, n, rng,
                                     lambda move: (yaw - np.arctan2(move[0], move[1]), spot))
            pelvis = model.joints(person.pose(), person.betas, person.transl)[:, 0, [0, 2]]
            if all(np.min(np.linalg.norm(pelvis - other, axis=-1)) >= 0.5 for other in paths):
                crowd.append(person)
                paths.append(pelvis)
                break
    return crowd


def _turned(v: np.ndarray, angle: float) -> np.ndarray:
    """An xz direction turned by angle (radians) in the ground plane."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def true_contacts(model, pose, betas, transl, height=0.1, speed=0.01) -> np.ndarray:
    """Contact labels (n, 4) of the CONTACT_JOINTS: near the ground and moving less than `speed` m per
    frame."""
    joints = model.joints(pose, betas, transl)[:, list(CONTACT_JOINTS)]
    step = np.linalg.norm(np.diff(joints, axis=0), axis=-1)
    step = np.concatenate([step, step[-1:]], axis=0)
    return ((joints[..., 1] < height) & (step < speed)).astype(np.float64)
