"""MediaPipe's legacy pose solution (mp.solutions.pose, BlazePose) as the offline detector, segmenter and 2D
pose estimator. Its models (pose_detection.tflite, pose_landmark_full.tflite) ship inside the
mediapipe==0.10.14 wheel (the optional extra m3c[perception]); nothing is downloaded at run time.

BlazePose finds one person per run. Several people come from detect-whiten-redetect: each found person's
segmentation (dilated) is whitened and the frame is searched again, until nobody more is found. Keypoints are
then taken on the thesis's patches (5 px padding, square, shifted inside the frame) with the other people's
tight boxes whitened except the focused person's mask, whenever a patch overlaps another person ("auto"),
always, or never.

The 33 BlazePose landmarks map to COCO-17 (the same anatomical names, "left" = the person's left) followed by
the heels and foot tips (types.FOOT_KEYPOINT_NAMES), with their visibility as confidence; the metric world
landmarks (metres, origin at the hip centre, image axes) become the root-relative 3D keypoints used by the body
fit.
"""

from __future__ import annotations

import logging
import warnings

import numpy as np

from m3c.perception._cv import import_cv2
from m3c.perception.boxes import WHITE, as_box, clip_boxes, crop, iou, isolate, pixel_region, process_box
from m3c.perception.interfaces import Detector, PoseEstimator2D, Segmenter
from m3c.perception.paf import INSTALL_COMMAND as PAF_INSTALL
from m3c.perception.paf import PafPoseNetwork, skeleton_box
from m3c.perception.paf import model_available as paf_model_available
from m3c.perception.paf import model_path as paf_model_path
from m3c.perception.registry import register
from m3c.perception.types import FrameContext, Person, pose_distance

LOG = logging.getLogger("m3c.perception.mediapipe")
NAME = "mediapipe"
# BlazePose landmark index of each COCO-17 keypoint (COCO order in m3c.body.joint_names.COCO17_NAMES).
MP_TO_COCO17 = (0, 2, 5, 7, 8, 11, 12, 13, 14, 15, 16, 23, 24, 25, 26, 27, 28)
# ... and of the foot points: heels, then foot index (the tip of the foot, at the big toe).
MP_TO_FEET = (29, 30, 31, 32)
NUM_LANDMARKS = 33


def import_mediapipe():
    try:
        import mediapipe
    except ImportError as err:
        raise ImportError("the MediaPipe estimators need the optional package mediapipe==0.10.14, whose pose models "
                          "ship inside the wheel: pip install 'm3c[perception]' (or pip install "
                          "mediapipe==0.10.14)") from err
    return mediapipe


def mediapipe_available() -> bool:
    try:
        import_mediapipe()
        import_cv2()
    except ImportError:
        return False
    return True


def landmarks_to_keypoints(landmarks: np.ndarray, world: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """BlazePose landmarks (33, 4) u, v, z, visibility (pixels) and world landmarks (33, 3) metres -> keypoints
    (21, 3) u, v, confidence (COCO-17 then the four foot points) and 3D keypoints (21, 4) x, y, z, confidence
    (None without world landmarks)."""
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.shape != (NUM_LANDMARKS, 4):
        raise ValueError(f"landmarks must have shape (33, 4), got {landmarks.shape}")
    idx = list(MP_TO_COCO17 + MP_TO_FEET)
    conf = np.clip(landmarks[idx, 3], 0.0, 1.0)
    keypoints = np.column_stack([landmarks[idx, 0], landmarks[idx, 1], conf])
    if world is None:
        return keypoints, None
    world = np.asarray(world, dtype=np.float64)
    if world.shape != (NUM_LANDMARKS, 3):
        raise ValueError(f"world landmarks must have shape (33, 3), got {world.shape}")
    return keypoints, np.column_stack([world[idx], conf])


def tight_box(keypoints: np.ndarray, mask: np.ndarray | None, mask_box, frame_size: tuple[int, int],
              min_confidence: float = 0.5) -> np.ndarray | None:
    """The person's tight box: the bounding box of the segmentation (its pixels' outer edges) and of the confident
    keypoints, inside the frame. None when there is neither."""
    xs, ys = [], []
    if mask is not None and mask.any():
        rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
        xs += [mask_box[0] + cols[0] - 0.5, mask_box[0] + cols[-1] + 0.5]
        ys += [mask_box[1] + rows[0] - 0.5, mask_box[1] + rows[-1] + 0.5]
    good = keypoints[:, 2] >= min_confidence
    if good.any():
        xs += [keypoints[good, 0].min(), keypoints[good, 0].max()]
        ys += [keypoints[good, 1].min(), keypoints[good, 1].max()]
    if not xs:
        return None
    return clip_boxes([min(xs), min(ys), max(xs), max(ys)], frame_size)


class MediaPipeEngine:
    """One BlazePose graph in static-image mode (every run detects, then finds landmarks and the mask)."""

    def __init__(self, min_detection_confidence: float = 0.5, mask_threshold: float = 0.5,
                 model_complexity: int = 1):
        if model_complexity != 1:
            raise ValueError(f"model_complexity={model_complexity}: only 1 (pose_landmark_full) ships inside the "
                             "mediapipe wheel; MediaPipe would download the others at run time, which M3C never does")
        if not 0.0 < min_detection_confidence < 1.0 or not 0.0 < mask_threshold < 1.0:
            raise ValueError("min_detection_confidence and mask_threshold must be in (0, 1)")
        mp = import_mediapipe()
        self.mask_threshold = mask_threshold
        with _quiet():
            self._pose = mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1, smooth_landmarks=False,
                                                enable_segmentation=True,
                                                min_detection_confidence=min_detection_confidence)
        self.runs = 0

    def run(self, image: np.ndarray, origin=(0, 0)):
        """BlazePose on an RGB image (a frame or a patch whose top-left frame pixel is origin). Returns
        (landmarks (33, 4) u, v, z, visibility in frame pixels, world (33, 3), mask (h, w) bool) or None."""
        image = np.ascontiguousarray(image)
        with _quiet():
            result = self._pose.process(image)
        self.runs += 1
        if result.pose_landmarks is None:
            return None
        h, w = image.shape[:2]
        lm = np.array([[p.x, p.y, p.z, p.visibility] for p in result.pose_landmarks.landmark], dtype=np.float64)
        # MediaPipe's x, y are fractions of the image's width and height, from its left and top edges: the frame's
        # pixel convention (m3c.perception.boxes) puts those edges at -0.5 (patch pixel 0 is frame pixel origin).
        lm[:, 0] = lm[:, 0] * w + origin[0] - 0.5
        lm[:, 1] = lm[:, 1] * h + origin[1] - 0.5
        world = None
        if result.pose_world_landmarks is not None:
            world = np.array([[p.x, p.y, p.z] for p in result.pose_world_landmarks.landmark], dtype=np.float64)
        mask = None
        if result.segmentation_mask is not None:
            mask = np.asarray(result.segmentation_mask) > self.mask_threshold
        return lm, world, mask

    def close(self) -> None:
        self._pose.close()


class _quiet(warnings.catch_warnings):
    """protobuf (pulled in by mediapipe) warns on every graph run about an API mediapipe still calls."""

    def __enter__(self):
        super().__enter__()
        warnings.filterwarnings("ignore", message=r"SymbolDatabase\.GetPrototype\(\) is deprecated")
        return self


def shared_engine(shared: dict | None, **options) -> MediaPipeEngine:
    """One engine per option set in the pipeline's shared dict (or a private one without it)."""
    if shared is None:
        return MediaPipeEngine(**options)
    engines = shared.setdefault(NAME, {})
    key = tuple(sorted(options.items()))
    if key not in engines:
        engines[key] = MediaPipeEngine(**options)
    return engines[key]


def _person_from_run(run, run_box, frame_size, sources: dict, min_confidence: float) -> Person | None:
    landmarks, world, mask = run
    keypoints, keypoints3d = landmarks_to_keypoints(landmarks, world)
    box = tight_box(keypoints, mask, run_box, frame_size, min_confidence)
    if box is None:
        return None
    score = float(np.mean(keypoints[:, 2]))
    return Person(box, score, keypoints, keypoints3d, mask, None if mask is None else run_box, dict(sources))


EDGE_RETRY_OVERHANG = 0.1  # of the centred square's side past the frame: a person cut by its edge (_patch_person)


def centred_square(box, padding: float) -> np.ndarray:
    """The integer pixel range (x0, y0, x1, y1) of the padded box's square centred on it, which may extend past
    the frame (process_box shifts it into the frame instead)."""
    x0, y0, x1, y1 = as_box(box) + np.array([-padding, -padding, padding, padding])
    side = int(np.ceil(max(x1 - x0, y1 - y0)))
    left, top = int(np.floor((x0 + x1 - side) / 2 + 0.5)), int(np.floor((y0 + y1 - side) / 2 + 0.5))
    return np.array([left, top, left + side, top + side], dtype=np.float64)


def _isolated(ctx: FrameContext, person: Person, other_boxes: np.ndarray, region: np.ndarray) -> np.ndarray:
    """The frame's pixels in the index range `region` (inside the frame), the other people whitened."""
    patch = crop(ctx.image, region)
    if len(other_boxes):
        patch = isolate(patch, region, person.box, other_boxes, person.mask_in(region))
    return patch


def _centred_run(ctx: FrameContext, engine: MediaPipeEngine, person: Person, other_boxes: np.ndarray,
                 padding: float):
    """(run, the in-frame part of its square) of BlazePose on the person's square centred on them, white past the
    frame, when that square reaches past the frame by EDGE_RETRY_OVERHANG of its side or more; else None."""
    square = centred_square(person.box, padding)
    inside = np.clip(square, 0, [ctx.size[1], ctx.size[0]] * 2)
    side = int(square[2] - square[0])
    if np.abs(square - inside).max() < EDGE_RETRY_OVERHANG * side or inside[2] <= inside[0] or inside[3] <= inside[1]:
        return None
    canvas = np.full((side, side, 3), WHITE, dtype=np.uint8)
    (x0, y0, x1, y1), (sx, sy) = inside.astype(int), square[:2].astype(int)
    canvas[y0 - sy:y1 - sy, x0 - sx:x1 - sx] = _isolated(ctx, person, other_boxes, inside)
    run = engine.run(canvas, origin=(sx, sy))
    if run is not None and run[2] is not None:  # the mask kept inside the frame only
        run = (run[0], run[1], run[2][y0 - sy:y1 - sy, x0 - sx:x1 - sx])
    return run, inside


def _patch_person(ctx: FrameContext, engine: MediaPipeEngine, person: Person, others: list[Person], padding: float,
                  min_confidence: float) -> Person | None:
    """BlazePose on the person's isolated patch (cached per frame, so the segmenter and the pose estimator
    share it).

    A person at the frame's edge sits off-centre in the square shifted into the frame, where BlazePose's detector
    often finds nobody (a tracked walker leaving the picture: 12 of 12 such misses on the video benchmark's seed 1
    follow shot; the centred square found 7). Such a miss is retried on the square centred on the person, white
    past the frame's edge (as the body networks' patches are, m3c.perception.boxes.extract_patch), when that square
    reaches past the frame by EDGE_RETRY_OVERHANG of its side or more: a square moved by a few pixels is no
    different input, and a second run there only re-rolls BlazePose on a box holding two people."""
    patch_box = process_box(person.box, ctx.size, padding)
    other_boxes = np.array([o.box for o in others]).reshape(-1, 4)
    key = (NAME, "patch", tuple(patch_box), tuple(map(tuple, np.round(other_boxes, 2))))
    if key not in ctx.cache:
        patch = _isolated(ctx, person, other_boxes, patch_box)
        run = engine.run(patch, origin=(patch_box[0], patch_box[1])) if patch.size else None
        run_box = patch_box
        retried = _centred_run(ctx, engine, person, other_boxes, padding) if run is None else None
        if retried is not None:
            run, run_box = retried
        found = None
        if run is not None:
            sources = {"segmenter": NAME, "pose2d": NAME}
            found = _person_from_run(run, run_box.astype(np.int64), ctx.size, sources, min_confidence)
            # BlazePose returns the most prominent person in the patch: it must be the one asked for.
            if found is not None and iou(found.box, person.box) < 0.2:
                found = None
        ctx.cache[key] = found
    return ctx.cache[key]


def square_tiles(frame_size: tuple[int, int], overlap: float = 0.5, side: int | None = None) -> list[np.ndarray]:
    """Square tiles of `side` pixels (default: the frame's shorter side) covering the frame, neighbours
    overlapping by at least `overlap` of the side: BlazePose's detector sees a 224 x 224 image, so a person is
    found at a larger scale in a tile than in a wide frame, and a smaller tile holds fewer people (BlazePose finds
    nobody at all in a tile where two stand close together)."""
    height, width = frame_size
    side = min(height, width) if side is None else int(side)
    if not 0 < side <= min(height, width):
        raise ValueError(f"tile side must be in 1 .. {min(height, width)} for a {width} x {height} frame, "
                         f"got {side}")

    def starts(length: int) -> np.ndarray:
        count = 1 if length == side else int(np.ceil((length - side) / (side * (1.0 - overlap)))) + 1
        return np.round(np.linspace(0, length - side, count)).astype(int)

    return [np.array([x, y, x + side, y + side]) for y in starts(height) for x in starts(width)]


def _contains(a: np.ndarray, b: np.ndarray, fraction: float) -> bool:
    """Whether the intersection of boxes a and b covers `fraction` of the smaller one."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return False
    smaller = min((a[2] - a[0]) * (a[3] - a[1]), (b[2] - b[0]) * (b[3] - b[1]))
    return smaller > 0 and w * h >= fraction * smaller


def _piece_of(box: np.ndarray, other: np.ndarray) -> bool:
    """Whether box overlaps other by a fifth of its own area and is less than half as tall."""
    return _contains(box, other, 0.2) and box[3] - box[1] < 0.5 * (other[3] - other[1])


@register("detector", NAME)
class MediaPipeDetector(Detector):
    """Detect-whiten-redetect with BlazePose on square tiles of the frame (see square_tiles); fills boxes,
    scores, masks and keypoints. Known people are whitened before the search. A search at least fine_every frames
    after the last fine one goes on over tiles of fine_tiles times the frame's shorter side (0: never); there a
    find that overlaps a known person's box and is less than half as tall is taken for a piece of that person (in
    a small tile BlazePose sees a person in an arm the whitening left).

    Before the tiles, the multi-person network of m3c.perception.paf (paf: "auto" when it is installed, "on"
    required, "off") proposes every person it sees at once: each one that is not a known person is posed by
    BlazePose on its own patch, the other people whitened, and kept when BlazePose's keypoints agree with the
    network's (mean distance under paf_agreement of the person's height); BlazePose alone finds nobody in a tile
    where two people stand close together."""

    def __init__(self, max_people: int = 6, min_score: float = 0.5, min_box_height: float = 32.0,
                 whiten_dilation: float = 0.05, tile_overlap: float = 0.5, fine_tiles: float = 0.6,
                 fine_every: int = 15, min_detection_confidence: float = 0.5, paf: str = "auto",
                 paf_agreement: float = 0.25, shared: dict | None = None):
        if max_people < 1:
            raise ValueError(f"max_people must be >= 1, got {max_people}")
        if not 0.0 <= tile_overlap < 1.0:
            raise ValueError(f"tile_overlap must be in [0, 1), got {tile_overlap}")
        if not 0.0 <= fine_tiles < 1.0 or fine_every < 1:
            raise ValueError(f"fine_tiles must be in [0, 1) (0: off) and fine_every >= 1, got {fine_tiles}, "
                             f"{fine_every}")
        self.max_people, self.min_score, self.min_box_height = max_people, min_score, min_box_height
        self.whiten_dilation, self.tile_overlap = whiten_dilation, tile_overlap
        self.fine_tiles, self.fine_every = fine_tiles, fine_every
        self._last_fine: int | None = None
        self._skeletons: tuple[int | None, list[np.ndarray]] = (None, [])  # the network's people of one frame
        if paf not in ("auto", "on", "off") or not paf_agreement > 0:
            raise ValueError(f'paf must be "auto", "on" or "off" and paf_agreement > 0, got {paf!r}, {paf_agreement}')
        self.paf_agreement = paf_agreement
        self.paf = None
        if paf == "on" or (paf == "auto" and paf_model_available()):
            self.paf = PafPoseNetwork()
        elif paf == "auto":
            LOG.warning("the multi-person pose network is not installed (%s): people standing close together may "
                        "be missed; install it with `%s`", paf_model_path(), PAF_INSTALL)
        self.engine = shared_engine(shared, min_detection_confidence=min_detection_confidence)

    def _whiten(self, work: np.ndarray, person: Person, frame_size: tuple[int, int]) -> None:
        """Whitens a found person: its dilated mask, or its box when the mask is missing or much smaller."""
        cv2 = import_cv2()
        region = person.full_mask(frame_size)
        if region.sum() < 0.1 * (person.box[2] - person.box[0]) * (person.box[3] - person.box[1]):
            x0, y0, x1, y1 = pixel_region(person.box, frame_size)
            region[y0:y1, x0:x1] = True
        radius = max(1, int(round(self.whiten_dilation * (person.box[3] - person.box[1]))))
        kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
        work[cv2.dilate(region.astype(np.uint8), kernel) > 0] = 255

    def detect(self, ctx: FrameContext, known: list[Person] | None = None) -> list[Person]:
        work = ctx.image.copy()
        known = list(known or [])
        for person in known:
            self._whiten(work, person, ctx.size)
        people = self._network_people(ctx, work, known) if self.paf is not None else []
        tiles = [(tile, False) for tile in square_tiles(ctx.size, self.tile_overlap)]
        due = self._last_fine is None or not 0 <= ctx.index - self._last_fine < self.fine_every
        if self.fine_tiles > 0 and due:
            # Then smaller tiles, on what the first pass left: people standing close together.
            side = int(self.fine_tiles * min(ctx.size))
            tiles += [(tile, True) for tile in square_tiles(ctx.size, self.tile_overlap, side)]
            self._last_fine = ctx.index
        for tile, fine in tiles:
            for _ in range(self.max_people + 2):  # each run whitens what it found, so this ends; a cap anyway
                if len(people) >= self.max_people:
                    break
                run = self.engine.run(crop(work, tile), origin=(tile[0], tile[1]))
                if run is None:
                    break
                sources = {"detector": NAME, "segmenter": NAME, "pose2d": NAME}
                person = _person_from_run(run, tile, ctx.size, sources, 0.5)
                too_small = person is not None and person.box[3] - person.box[1] < self.min_box_height
                if person is None or person.score < self.min_score or too_small:
                    break  # nobody more in this tile, or too unsure
                # Whatever is found is whitened, so the next search moves on even if this one is rejected.
                self._whiten(work, person, ctx.size)
                duplicate = [i for i, p in enumerate(people) if _contains(person.box, p.box, 0.7)]
                if any(_contains(person.box, k.box, 0.7) or (fine and _piece_of(person.box, k.box)) for k in known):
                    continue  # what the whitening left of a known person
                if duplicate:
                    # The same person seen again (e.g. a partial first view): keep the more confident view.
                    i = duplicate[0]
                    if person.score > people[i].score:
                        people[i] = person
                    continue
                people.append(person)
        return people

    def _network_people(self, ctx: FrameContext, work: np.ndarray, known: list[Person]) -> list[Person]:
        """The people the multi-person network sees that are not known, each posed by BlazePose on its isolated
        patch (whitened in work once found)."""
        skeletons = []
        for keypoints in self.paf.people(ctx.image):
            box = skeleton_box(keypoints, ctx.size)
            if box is not None and box[3] - box[1] >= self.min_box_height:
                skeletons.append((keypoints, box))
        self._skeletons = (ctx.index, [keypoints for keypoints, _ in skeletons])
        found: list[Person] = []
        for i, (keypoints, box) in enumerate(skeletons):
            if len(found) + len(known) >= self.max_people:
                break
            if any(_agree(keypoints, k.keypoints, self.paf_agreement) for k in known + found):
                continue
            others = known + found + [Person(b, 1.0) for j, (_, b) in enumerate(skeletons) if j != i]
            person = _patch_person(ctx, self.engine, Person(box, 1.0), others, 5.0, 0.5)
            # Known people are told apart by their keypoints, not their boxes: a tracked box can span a person
            # standing behind.
            if (person is None or person.score < self.min_score
                    or person.box[3] - person.box[1] < self.min_box_height
                    or not _agree(keypoints, person.keypoints, self.paf_agreement)
                    or any(_agree(k.keypoints, person.keypoints, self.paf_agreement) for k in known + found
                           if k.keypoints is not None)):
                continue
            person.sources = {"detector": NAME + "+paf", "segmenter": NAME, "pose2d": NAME}
            self._whiten(work, person, ctx.size)
            found.append(person)
        return found

    def skeletons(self, ctx: FrameContext) -> list[np.ndarray]:
        index, skeletons = self._skeletons
        return list(skeletons) if index == ctx.index else []

    def close(self) -> None:
        self.engine.close()


def _agree(skeleton: np.ndarray, keypoints: np.ndarray | None, tolerance: float) -> bool:
    """Whether a network skeleton (17, 3) and BlazePose keypoints (K >= 17, 3) are one person (pose_distance under
    tolerance; BlazePose's keypoints taken where their visibility is at least one half)."""
    return keypoints is not None and pose_distance(skeleton, keypoints, 0.0, 0.49) < tolerance


@register("segmenter", NAME)
class MediaPipeSegmenter(Segmenter):
    """BlazePose's segmentation on each person's isolated patch; people whose mask already came from the same
    engine (the MediaPipe detector) keep it."""

    def __init__(self, padding: float = 5.0, min_detection_confidence: float = 0.5, shared: dict | None = None):
        self.padding = padding
        self.engine = shared_engine(shared, min_detection_confidence=min_detection_confidence)

    def segment(self, ctx: FrameContext, people: list[Person]) -> list[Person]:
        out = []
        for i, person in enumerate(people):
            if person.mask is not None and person.sources.get("segmenter") == NAME:
                out.append(person)
                continue
            found = _patch_person(ctx, self.engine, person, people[:i] + people[i + 1:], self.padding, 0.5)
            updated = Person(person.box, person.score, person.keypoints, person.keypoints3d,
                             None if found is None else found.mask, None if found is None else found.mask_box,
                             dict(person.sources))
            if found is not None:
                updated.sources["segmenter"] = NAME
            out.append(updated)
        return out


@register("pose2d", NAME)
class MediaPipePose2D(PoseEstimator2D):
    """Keypoints (COCO-17 + feet) and metric 3D keypoints from BlazePose on the isolated patch of each person.

    patch_pass: "auto" re-runs BlazePose on the patch only when the person's keypoints did not come from it
    already (e.g. a tracker's predicted box, or another detector) or when the patch overlaps another person's
    box (so isolation changes the input); "always" and "never" force it. Without keypoints, "never" still runs
    the patch.
    """

    def __init__(self, patch_pass: str = "auto", padding: float = 5.0, min_detection_confidence: float = 0.5,
                 shared: dict | None = None):
        if patch_pass not in ("auto", "always", "never"):
            raise ValueError(f"patch_pass must be 'auto', 'always' or 'never', got {patch_pass!r}")
        self.patch_pass, self.padding = patch_pass, padding
        self.engine = shared_engine(shared, min_detection_confidence=min_detection_confidence)

    def estimate(self, ctx: FrameContext, people: list[Person]) -> list[Person | None]:
        out: list[Person | None] = []
        for i, person in enumerate(people):
            others = people[:i] + people[i + 1:]
            have = person.keypoints is not None and person.sources.get("pose2d") == NAME
            if have and self.patch_pass != "always":
                patch_box = process_box(person.box, ctx.size, self.padding)
                overlaps = any(iou(patch_box, o.box) > 0 for o in others)
                if self.patch_pass == "never" or not overlaps:
                    out.append(person)
                    continue
            found = _patch_person(ctx, self.engine, person, others, self.padding, 0.5)
            if found is None:
                # A re-run among more whitened people that finds nobody keeps the pose BlazePose gave before.
                out.append(person if have else None)
                continue
            sources = dict(person.sources)
            sources.update(pose2d=NAME)
            if person.mask is None or person.sources.get("segmenter") == NAME:
                sources["segmenter"] = NAME
                mask, mask_box = found.mask, found.mask_box
            else:
                mask, mask_box = person.mask, person.mask_box
            out.append(Person(found.box, found.score, found.keypoints,
                              found.keypoints3d, mask, mask_box, sources))
        return out
