"""The static world of a synthetic sequence: a textured ground large enough for the whole sequence, boxes, walls
and pillars at several depths (parallax for the visual odometry) and a far backdrop closing the horizon.

Textures are procedural (seeded): multi-scale coloured noise, bricks, paving and poster-like patches, so that
every surface has corners a tracker can follow; they repeat (periodic noise) and are mip-mapped by the renderer.
Objects keep clear of the people's paths, the camera's path and the lines of sight from the camera to the people.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter

from m3c.synth.render import TexturedMesh

TEXTURE_SIZE = 512
GROUND_TILE = 2.0  # metres per ground tile (one texture per tile, several textures mixed)
GROUND_TEXEL = GROUND_TILE / TEXTURE_SIZE
OBJECT_TEXEL = 0.006  # metres per texel on boxes and walls
BACKDROP_TEXEL = 0.03


@dataclass
class StaticScene:
    meshes: list[TexturedMesh]
    textures: list[np.ndarray]  # (S, S, 3) float32 RGB in [0, 1]
    bounds: np.ndarray  # (2, 2) ground extent [[x_min, z_min], [x_max, z_max]]
    objects: list[dict]  # what was placed (kind, centre, size, yaw), for the record
    gloss: float = 0.0  # the floor's reflectance (GLOSS on a glossy floor)


# Textures ---------------------------------------------------------------------------------------------------
def _noise(rng, size: int, sigmas=(24.0, 8.0, 2.5, 1.0), weights=(1.0, 0.7, 0.45, 0.3)) -> np.ndarray:
    """Periodic multi-scale noise (size, size), zero mean, unit std."""
    out = np.zeros((size, size))
    for sigma, weight in zip(sigmas, weights):
        layer = gaussian_filter(rng.standard_normal((size, size)), sigma, mode="wrap")
        out += weight * layer / layer.std()
    return out / out.std()


def _tint(base, variation, field) -> np.ndarray:
    return np.clip(
        np.asarray(base)[None, None] + variation * field[..., None] * np.array([1.0, 0.95, 0.9]), 0, 1
    )


def _ground_texture(rng, size: int) -> np.ndarray:
    base = rng.choice([[0.45, 0.42, 0.38], [0.36, 0.40, 0.30], [0.50, 0.48, 0.46], [0.42, 0.36, 0.30]])
    base = np.asarray(base) * rng.uniform(0.85, 1.15)
    tex = _tint(base, 0.09, _noise(rng, size))
    # Pebbles: small bright and dark spots (corners at every scale the camera sees the ground at).
    spots = gaussian_filter(rng.standard_normal((size, size)), 1.2, mode="wrap")
    tex = np.clip(tex + 0.12 * (spots / spots.std())[..., None].clip(-2, 2) * 0.5, 0, 1)
    return tex.astype(np.float32)


def _plain_texture(rng, size: int) -> np.ndarray:
    """A sports hall's floor: one colour (blue, green or wood), a faint sheen of 1% and no pebbles: almost nothing
    for the odometry to track."""
    base = rng.choice([[0.20, 0.35, 0.62], [0.25, 0.50, 0.33], [0.62, 0.47, 0.30]]) * rng.uniform(0.9, 1.1)
    return _tint(base, 0.01, _noise(rng, size, sigmas=(48.0, 24.0), weights=(1.0, 0.5))).astype(np.float32)


FLOORS = ("textured", "plain", "glossy")
GLOSS = 0.3  # reflectance of a glossy floor: the plain one, polished (m3c.synth.render.Renderer.render)


def _brick_texture(rng, size: int) -> np.ndarray:
    rows, cols = int(rng.choice([8, 16])), int(rng.choice([4, 8]))
    h, w = size // rows, size // cols
    base = np.asarray(rng.choice([[0.55, 0.30, 0.22], [0.62, 0.55, 0.45], [0.45, 0.45, 0.48]]))
    tex = np.empty((size, size, 3))
    for r in range(rows):
        shift = (w // 2) * (r % 2)
        for c in range(cols + 1):
            colour = np.clip(base * rng.uniform(0.75, 1.2) + rng.normal(0, 0.03, 3), 0, 1)
            x0 = c * w - shift
            for x in range(x0, x0 + w):
                tex[r * h : (r + 1) * h, x % size] = colour
    mortar = np.zeros((size, size), bool)
    mortar[np.arange(size) % h < 2] = True
    for r in range(rows):
        shift = (w // 2) * (r % 2)
        cols_at = (np.arange(size) + shift) % w < 2
        mortar[r * h : (r + 1) * h, cols_at] = True
    tex[mortar] = [0.78, 0.76, 0.72]
    return np.clip(tex + 0.05 * _noise(rng, size, (6.0, 1.5), (1.0, 0.6))[..., None], 0, 1).astype(np.float32)


def _patch_texture(rng, size: int) -> np.ndarray:
    """Painted wood or concrete with poster-like rectangles of other colours."""
    base = np.asarray(
        rng.choice([[0.60, 0.50, 0.35], [0.55, 0.57, 0.60], [0.30, 0.45, 0.55], [0.65, 0.62, 0.50]])
    )
    tex = _tint(base, 0.07, _noise(rng, size))
    for _ in range(int(rng.integers(6, 14))):
        w, h = rng.integers(size // 10, size // 3, size=2)
        x, y = rng.integers(0, size, size=2)
        colour = rng.uniform(0.1, 0.95, 3)
        xs, ys = (np.arange(x, x + w) % size), (np.arange(y, y + h) % size)
        tex[np.ix_(ys, xs)] = colour
    return np.clip(tex + 0.04 * _noise(rng, size, (3.0, 1.0), (1.0, 0.7))[..., None], 0, 1).astype(np.float32)


def _backdrop_texture(rng, size: int) -> np.ndarray:
    """A far facade or tree line: large blobs and windows of varied colours."""
    field = _noise(rng, size, (40.0, 12.0, 4.0), (1.0, 0.6, 0.4))
    tex = _tint(np.asarray(rng.choice([[0.35, 0.45, 0.30], [0.55, 0.50, 0.45]])), 0.12, field)
    step = size // 16
    for y in range(step // 2, size - step, step):
        for x in range(step // 2, size - step, step):
            if rng.uniform() < 0.35:
                tex[y : y + step // 2, x : x + step // 2] = rng.uniform(0.15, 0.8, 3)
    return tex.astype(np.float32)


# Geometry ---------------------------------------------------------------------------------------------------
def _quad(corner, edge_u, edge_v, texel: float, texture: int, cull: bool) -> TexturedMesh:
    """A rectangle corner + a edge_u + b edge_v (a, b in [0, 1]), facing edge_u x edge_v."""
    corner, edge_u, edge_v = (np.asarray(v, dtype=np.float64) for v in (corner, edge_u, edge_v))
    vertices = np.stack([corner, corner + edge_u, corner + edge_v, corner + edge_u + edge_v])
    lu, lv = np.linalg.norm(edge_u) / texel, np.linalg.norm(edge_v) / texel
    uv = np.array([[0.0, 0.0], [lu, 0.0], [0.0, lv], [lu, lv]])
    return TexturedMesh(vertices, np.array([[0, 1, 2], [1, 3, 2]], np.int32), uv, texture, cull)


def _merge(quads: list[TexturedMesh]) -> TexturedMesh:
    vertices, faces, uv, offset = [], [], [], 0
    for q in quads:
        vertices.append(q.vertices)
        faces.append(q.faces + offset)
        uv.append(q.uv)
        offset += len(q.vertices)
    return TexturedMesh(
        np.concatenate(vertices),
        np.concatenate(faces).astype(np.int32),
        np.concatenate(uv),
        quads[0].texture,
        quads[0].cull,
    )


def box_mesh(centre_xz, size, yaw: float, texture: int, texel: float = OBJECT_TEXEL) -> TexturedMesh:
    """A closed box standing on the ground (no bottom): size (width x, height y, depth z) before the yaw about
    +y; faces wound so that their right-hand normals point outwards."""
    sx, sy, sz = (float(v) for v in size)
    c, s = np.cos(yaw), np.sin(yaw)
    ax = np.array([c, 0.0, -s])
    az = np.array([s, 0.0, c])
    ay = np.array([0.0, 1.0, 0.0])
    centre = np.array([centre_xz[0], sy / 2, centre_xz[1]])
    half = {"x": ax * sx / 2, "y": ay * sy / 2, "z": az * sz / 2}
    faces = []
    # (outward normal, edge_u, edge_v) with edge_u x edge_v along the normal.
    for normal, eu, ev in (
        (half["y"], 2 * half["z"], 2 * half["x"]),
        (half["x"], 2 * half["y"], 2 * half["z"]),
        (-half["x"], 2 * half["z"], 2 * half["y"]),
        (half["z"], 2 * half["x"], 2 * half["y"]),
        (-half["z"], 2 * half["y"], 2 * half["x"]),
    ):
        faces.append(_quad(centre + normal - eu / 2 - ev / 2, eu, ev, texel, texture, True))
    return _merge(faces)


def _segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=-1)


def make_scene(
    rng,
    people_xz: np.ndarray,
    camera_xz: np.ndarray,
    sight_lines: list[tuple[np.ndarray, np.ndarray]],
    num_boxes: int = 8,
    num_pillars: int = 3,
    num_walls: int = 2,
    margin: float = 18.0,
    floor: str = "textured",
) -> StaticScene:
    """people_xz (N, 2) and camera_xz (M, 2): ground positions to keep clear; sight_lines: (camera, target) xz
    segments no object may block. The ground covers everything within `margin` metres, closed by a backdrop.
    floor: "textured" (mixed pebbly tiles), "plain" (_plain_texture, one for every tile) or "glossy" (the plain
    one mirroring the scene with reflectance GLOSS)."""
    if floor not in FLOORS:
        raise ValueError(f"floor must be one of {', '.join(FLOORS)}, got {floor!r}")
    textures = [_ground_texture(rng, TEXTURE_SIZE) for _ in range(4)]
    if floor in ("plain", "glossy"):
        textures = [_plain_texture(rng, TEXTURE_SIZE)] * 4
    first_object = len(textures)
    textures += [_patch_texture(rng, TEXTURE_SIZE) for _ in range(3)] + [_brick_texture(rng, TEXTURE_SIZE)]
    backdrop = len(textures)
    textures.append(_backdrop_texture(rng, TEXTURE_SIZE))

    used = np.concatenate([people_xz, camera_xz])
    lo = np.floor((used.min(axis=0) - margin) / GROUND_TILE) * GROUND_TILE
    hi = np.ceil((used.max(axis=0) + margin) / GROUND_TILE) * GROUND_TILE
    meshes = []  # objects, ground, backdrop
    tiles = {k: [] for k in range(first_object)}
    for x in np.arange(lo[0], hi[0], GROUND_TILE):
        for z in np.arange(lo[1], hi[1], GROUND_TILE):
            k = int(rng.integers(first_object))
            tiles[k].append(
                _quad([x, 0.0, z], [0, 0, GROUND_TILE], [GROUND_TILE, 0, 0], GROUND_TEXEL, k, True)
            )
    ground = [_merge(q) for q in tiles.values() if q]
    for mesh in ground:
        mesh.ground = True

    # Objects: boxes, pillars and walls, within 8 m of the action, clear of paths and sight lines.
    centre = people_xz.mean(axis=0)
    objects = []
    wanted = [("box", num_boxes), ("pillar", num_pillars), ("wall", num_walls)]
    for kind, count in wanted:
        placed, tries = 0, 0
        while placed < count and tries < 400:
            tries += 1
            if kind == "box":
                size = np.array([rng.uniform(0.4, 1.4), rng.uniform(0.4, 1.6), rng.uniform(0.4, 1.4)])
            elif kind == "pillar":
                size = np.array([rng.uniform(0.3, 0.5), rng.uniform(2.5, 3.5), rng.uniform(0.3, 0.5)])
            else:
                size = np.array([rng.uniform(3.0, 6.0), rng.uniform(1.8, 2.6), 0.25])
            radius = 0.5 * np.hypot(size[0], size[2])
            at = centre + rng.uniform(-9.0, 9.0, size=2)
            clear = radius + (0.8 if kind != "wall" else 1.5)
            if np.min(np.linalg.norm(people_xz - at, axis=-1)) < clear:
                continue
            if np.min(np.linalg.norm(camera_xz - at, axis=-1)) < clear + 0.5:
                continue
            if any(_segment_distance(at[None], a, b)[0] < radius + 0.3 for a, b in sight_lines):
                continue
            if any(np.linalg.norm(at - o["centre"]) < radius + o["radius"] + 0.3 for o in objects):
                continue
            yaw = float(rng.uniform(0, np.pi))
            texture = first_object + (3 if kind == "wall" else int(rng.integers(3)))
            meshes.append(box_mesh(at, size, yaw, texture))
            objects.append({"kind": kind, "centre": at, "size": size, "yaw": yaw, "radius": radius})
            placed += 1

    meshes += ground  # after the objects, before the backdrop: near to far for the renderer
    # Backdrop: four inward-facing walls at the edge of the ground, tall enough to fill the horizon.
    height = 12.0
    (x0, z0), (x1, z1) = lo, hi
    up = np.array([0.0, height, 0.0])
    for corner, edge in (
        ([x0, 0, z0], [x1 - x0, 0, 0]),
        ([x1, 0, z0], [0, 0, z1 - z0]),
        ([x1, 0, z1], [x0 - x1, 0, 0]),
        ([x0, 0, z1], [0, 0, z0 - z1]),
    ):
        meshes.append(_quad(corner, up, edge, BACKDROP_TEXEL, backdrop, False))
    return StaticScene(meshes, textures, np.stack([lo, hi]), objects, GLOSS if floor == "glossy" else 0.0)
