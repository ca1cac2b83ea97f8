"""A small CPU triangle rasteriser in numpy: depth-tested, perspective-correct, Lambert + Blinn-Phong shading.

Conventions: camera frame OpenCV (x right, y down, z forward), intrinsics (fx, fy, cx, cy), pixel (i, j)'s centre
at image coordinates (i, j) (OpenCV's convention, the one projections and keypoints use). A pixel is covered by a
triangle when its centre lies inside; centres exactly on an edge belong to the triangle whose edge is a top or
left edge, so triangles sharing an edge cover each pixel once. Depth is interpolated as 1/z (exact for the
triangle's plane along each pixel ray). Triangles with a vertex closer than `near` are skipped (no clipping).

All triangles of one mesh are rasterised together: every candidate pixel of every triangle's bounding box is
tested at once, then the nearest fragment per pixel wins (a sort by pixel and depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from m3c.camera import project as project_pinhole

MAX_FRAGMENTS = 4_000_000  # candidate pixels tested per batch (memory bound)


@dataclass
class Mesh:
    """A triangle mesh in the camera frame: vertices (V, 3) metres, faces (F, 3) vertex ids.
    colour (3,) RGB in [0, 1], or face_colours (F, 3). smooth: shade with interpolated vertex normals (else face
    normals). cull: skip triangles facing away (for closed meshes whose faces wind counter-clockwise seen from
    outside, as SMPL's)."""

    vertices: np.ndarray
    faces: np.ndarray
    colour: np.ndarray = field(default_factory=lambda: np.array([0.7, 0.7, 0.7]))
    face_colours: np.ndarray | None = None
    smooth: bool = True
    cull: bool = True


@dataclass
class Buffers:
    """Per-pixel results of rasterisation: depth (H, W) (inf where empty), mesh (H, W) index (-1 = empty),
    face (H, W), bary (H, W, 3) perspective-correct barycentric coordinates."""

    depth: np.ndarray
    mesh: np.ndarray
    face: np.ndarray
    bary: np.ndarray

    @classmethod
    def empty(cls, width: int, height: int) -> "Buffers":
        return cls(np.full((height, width), np.inf), np.full((height, width), -1, np.int32),
                   np.full((height, width), -1, np.int64), np.zeros((height, width, 3)))


def project(vertices: np.ndarray, intrinsics) -> np.ndarray:
    """(V, 3) camera-frame points -> (V, 3) (u, v, z)."""
    return np.concatenate([project_pinhole(vertices, intrinsics), vertices[:, 2:]], axis=1)


def rasterize(buffers: Buffers, mesh_index: int, vertices: np.ndarray, faces: np.ndarray, intrinsics,
              near: float = 0.05, cull: bool = True) -> None:
    """Draws one mesh into `buffers` with a depth test against what is already there."""
    height, width = buffers.depth.shape
    uvz = project(np.asarray(vertices, dtype=np.float64), intrinsics)
    faces = np.asarray(faces, dtype=np.int64)
    tri = uvz[faces]  # (F, 3, 3)
    keep = (tri[:, :, 2] > near).all(axis=1) & np.isfinite(tri).all(axis=(1, 2))
    a, b, c = tri[:, 0, :2], tri[:, 1, :2], tri[:, 2, :2]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    keep &= area != 0
    if cull:
        # A face whose right-hand normal points at the camera (n_z < 0 in x-right, y-down, z-forward
        # coordinates) has a negative signed area in the image.
        keep &= area < 0
    ids = np.flatnonzero(keep)
    if len(ids) == 0:
        return
    lo = np.ceil(tri[ids, :, :2].min(axis=1)).astype(np.int64)
    hi = np.floor(tri[ids, :, :2].max(axis=1)).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [width - 1, height - 1])
    w = np.maximum(hi[:, 0] - lo[:, 0] + 1, 0)
    h = np.maximum(hi[:, 1] - lo[:, 1] + 1, 0)
    count = w * h
    nonempty = count > 0
    ids, lo, w, count = ids[nonempty], lo[nonempty], w[nonempty], count[nonempty]
    # Batches of triangles with at most MAX_FRAGMENTS candidate pixels (a huge triangle gets its own batch).
    ends = np.cumsum(count)
    start = 0
    while start < len(ids):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + MAX_FRAGMENTS, side="right")), start + 1)
        _rasterize_batch(buffers, mesh_index, tri, area, ids[start:stop], lo[start:stop], w[start:stop],
                         count[start:stop])
        start = stop


def _rasterize_batch(buffers, mesh_index, tri, area, ids, lo, w, count) -> None:
    height, width = buffers.depth.shape
    owner = np.repeat(np.arange(len(ids)), count)
    offset = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    px = lo[owner, 0] + offset % w[owner]
    py = lo[owner, 1] + offset // w[owner]
    face = ids[owner]
    t = tri[face]
    sign = np.sign(area[face])
    # Edge functions, made positive inside whatever the winding: e_k is opposite vertex k.
    weights = []
    for k in range(3):
        p, q = t[:, (k + 1) % 3, :2], t[:, (k + 2) % 3, :2]
        dx, dy = (q[:, 0] - p[:, 0]) * sign, (q[:, 1] - p[:, 1]) * sign
        e = dx * (py - p[:, 1]) - dy * (px - p[:, 0])
        top_left = (dy < 0) | ((dy == 0) & (dx > 0))
        weights.append((e, (e > 0) | ((e == 0) & top_left)))
    inside = weights[0][1] & weights[1][1] & weights[2][1]
    if not inside.any():
        return
    e = np.stack([weights[k][0][inside] for k in range(3)], axis=1)
    t, face = t[inside], face[inside]
    px, py = px[inside], py[inside]
    screen = e / e.sum(axis=1, keepdims=True)  # screen-space barycentrics
    inv_z = (screen / t[:, :, 2]).sum(axis=1)
    depth = 1.0 / inv_z
    bary = screen / t[:, :, 2] * depth[:, None]  # perspective-correct
    pixel = py * width + px
    order = np.lexsort((depth, pixel))
    pixel, depth = pixel[order], depth[order]
    first = np.r_[True, pixel[1:] != pixel[:-1]]
    pixel, depth, order = pixel[first], depth[first], order[first]
    flat_depth = buffers.depth.reshape(-1)
    nearer = depth < flat_depth[pixel]
    pixel, depth, order = pixel[nearer], depth[nearer], order[nearer]
    flat_depth[pixel] = depth
    buffers.mesh.reshape(-1)[pixel] = mesh_index
    buffers.face.reshape(-1)[pixel] = face[order]
    buffers.bary.reshape(-1, 3)[pixel] = bary[order]


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (V, 3), unit length (zero for unused vertices)."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    out = np.stack([np.bincount(f.reshape(-1), np.repeat(n[:, d], 3), minlength=len(v)) for d in range(3)], axis=1)
    length = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, length, out=np.zeros_like(out), where=length > 0)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


# Light from above-left of the camera, pointing from the surface to the light (camera frame).
LIGHT = np.array([-0.35, -0.6, -1.0]) / np.linalg.norm([-0.35, -0.6, -1.0])


def shade(buffers: Buffers, meshes: list[Mesh], ambient: float = 0.35, specular: float = 0.15) -> np.ndarray:
    """RGB float image (H, W, 3) in [0, 1] of the rasterised meshes (zero where empty)."""
    height, width = buffers.depth.shape
    image = np.zeros((height, width, 3))
    for index, mesh in enumerate(meshes):
        covered = buffers.mesh == index
        if not covered.any():
            continue
        face = buffers.face[covered]
        faces = np.asarray(mesh.faces, dtype=np.int64)
        if mesh.smooth:
            vn = vertex_normals(mesh.vertices, faces)
            normal = np.einsum("nk,nkd->nd", buffers.bary[covered], vn[faces[face]])
        else:
            normal = face_normals(mesh.vertices, faces)[face]
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        # Position along the pixel ray, for the view direction.
        position = np.einsum("nk,nkd->nd", buffers.bary[covered], np.asarray(mesh.vertices)[faces[face]])
        view = -position / np.maximum(np.linalg.norm(position, axis=1, keepdims=True), 1e-12)
        normal = np.where((normal * view).sum(axis=1, keepdims=True) < 0, -normal, normal)  # two-sided
        diffuse = np.clip(normal @ LIGHT, 0.0, 1.0)
        half = LIGHT + view
        half /= np.maximum(np.linalg.norm(half, axis=1, keepdims=True), 1e-12)
        spec = specular * np.clip((normal * half).sum(axis=1), 0.0, 1.0) ** 32
        base = mesh.face_colours[face] if mesh.face_colours is not None else np.broadcast_to(mesh.colour, (len(face), 3))
        image[covered] = np.clip(base * (ambient + (1 - ambient) * diffuse)[:, None] + spec[:, None], 0.0, 1.0)
    return image


def render(meshes: list[Mesh], intrinsics, width: int, height: int, background: np.ndarray | None = None,
           alpha: float = 1.0, near: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Renders meshes (camera frame) over `background` (BGR uint8 H x W x 3, or black). Returns (BGR uint8 image,
    depth (H, W) with inf where nothing was drawn)."""
    buffers = Buffers.empty(width, height)
    for index, mesh in enumerate(meshes):
        rasterize(buffers, index, mesh.vertices, mesh.faces, intrinsics, near=near, cull=mesh.cull)
    rgb = shade(buffers, meshes)
    out = np.zeros((height, width, 3), np.uint8) if background is None else background.copy()
    covered = buffers.mesh >= 0
    bgr = rgb[covered][:, ::-1] * 255.0
    out[covered] = np.clip(alpha * bgr + (1 - alpha) * out[covered], 0, 255).round().astype(np.uint8)
    return out, buffers.depth
