"""The numpy rasteriser against hand-checked cases: which pixels a triangle covers, edge ownership, depth along
pixel rays, occlusion, back-face culling, and shading direction."""

import numpy as np

from m3c.viz.raster import Buffers, Mesh, rasterize, render, vertex_normals

# Unit focal length at the origin: a camera-frame point (x, y, 1) projects to pixel (x, y).
UNIT = (1.0, 1.0, 0.0, 0.0)


def covered(buffers):
    ys, xs = np.nonzero(buffers.mesh >= 0)
    return sorted(zip(xs.tolist(), ys.tolist()))


def test_single_triangle_pixels_by_hand():
    # Triangle (0.5, 0.5), (6.5, 0.5), (0.5, 4.5) at depth 1: pixel centres (x, y) with x >= 1, y >= 1 and
    # (x - 0.5) / 6 + (y - 0.5) / 4 < 1 (none lies exactly on the slanted edge).
    buffers = Buffers.empty(10, 8)
    vertices = np.array([[0.5, 0.5, 1.0], [6.5, 0.5, 1.0], [0.5, 4.5, 1.0]])
    rasterize(buffers, 0, vertices, np.array([[0, 1, 2]]), UNIT, cull=False)
    expected = [(x, y) for y in range(8) for x in range(10)
                if x >= 1 and y >= 1 and (x - 0.5) / 6 + (y - 0.5) / 4 < 1]
    assert covered(buffers) == sorted(expected)
    assert len(expected) == 12  # rows y=1: x 1..5, y=2: 1..4, y=3: 1..2, y=4: x 1
    np.testing.assert_allclose(buffers.depth[buffers.mesh >= 0], 1.0)
    # Barycentric coordinates reproduce the pixel position.
    for x, y in expected:
        b = buffers.bary[y, x]
        np.testing.assert_allclose(b @ vertices[:, :2], [x, y], atol=1e-12)


def test_shared_edge_pixels_are_covered_once():
    # A square split along its diagonal, with pixel centres exactly on every edge (integer corners).
    vertices = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 1.0], [4.0, 4.0, 1.0], [0.0, 4.0, 1.0]])
    counts = np.zeros((6, 6), int)
    for face in ([0, 1, 2], [0, 2, 3]):
        buffers = Buffers.empty(6, 6)
        rasterize(buffers, 0, vertices, np.array([face]), UNIT, cull=False)
        counts += buffers.mesh >= 0
    # The square [0, 4] x [0, 4] holds 5 x 5 centres; top-left rule: edges x = 0 and y = 0 are owned, x = 4 and
    # y = 4 are not, so 4 x 4 pixels are covered, each exactly once (the diagonal included).
    assert counts.max() == 1
    assert counts.sum() == 16 and counts[:4, :4].all()


def test_depth_is_exact_on_a_slanted_plane():
    # Plane z = 2 + 0.5 x (camera frame); the pixel ray through (u, v) meets it at z = 2 / (1 - 0.5 u).
    xs = np.array([-1.0, 1.0, -1.0])
    ys = np.array([-1.0, -1.0, 1.0])
    z = 2 + 0.5 * xs
    K = (40.0, 40.0, 20.0, 20.0)
    buffers = Buffers.empty(40, 40)
    rasterize(buffers, 0, np.stack([xs, ys, z], 1), np.array([[0, 1, 2]]), K, cull=False)
    ys_px, xs_px = np.nonzero(buffers.mesh >= 0)
    assert len(xs_px) > 100
    u = (xs_px - 20.0) / 40.0  # normalised ray x / z
    np.testing.assert_allclose(buffers.depth[ys_px, xs_px], 2 / (1 - 0.5 * u), rtol=1e-12)


def test_nearer_triangle_wins_in_either_order():
    far = np.array([[-1.0, -1.0, 5.0], [1.0, -1.0, 5.0], [0.0, 1.0, 5.0]])
    near = far * np.array([1.0, 1.0, 0.5])  # same pixels, half the depth
    faces = np.array([[0, 1, 2]])
    for order in ((far, near), (near, far)):
        buffers = Buffers.empty(21, 21)
        for index, vertices in enumerate(order):
            rasterize(buffers, index, vertices, faces, (10.0, 10.0, 10.0, 10.0), cull=False)
        hit = buffers.mesh >= 0
        nearest = 0 if order[0] is near else 1
        assert (buffers.mesh[hit] == nearest).all()
        np.testing.assert_allclose(buffers.depth[hit], 2.5)


def test_back_faces_are_culled_and_near_plane_skips():
    # Counter-clockwise seen from the camera = normal towards the camera: kept; the reverse winding is culled.
    vertices = np.array([[-1.0, -1.0, 3.0], [0.0, 1.0, 3.0], [1.0, -1.0, 3.0]])
    normal = np.cross(vertices[1] - vertices[0], vertices[2] - vertices[0])
    assert normal[2] < 0  # this winding faces the camera
    K = (10.0, 10.0, 10.0, 10.0)
    front, back = Buffers.empty(21, 21), Buffers.empty(21, 21)
    rasterize(front, 0, vertices, np.array([[0, 1, 2]]), K, cull=True)
    rasterize(back, 0, vertices, np.array([[0, 2, 1]]), K, cull=True)
    assert (front.mesh >= 0).sum() > 10 and (back.mesh >= 0).sum() == 0
    behind = Buffers.empty(21, 21)
    rasterize(behind, 0, vertices * np.array([1, 1, 0.01]), np.array([[0, 1, 2]]), K, near=0.05)
    assert (behind.mesh >= 0).sum() == 0


def test_huge_triangle_is_split_into_batches(monkeypatch):
    import m3c.viz.raster as raster

    vertices = np.array([[-10.0, -10.0, 1.0], [10.0, -10.0, 1.0], [0.0, 10.0, 1.0]])
    full = Buffers.empty(30, 30)
    rasterize(full, 0, vertices, np.array([[0, 1, 2], [0, 1, 2]]), (1.0, 1.0, 15.0, 15.0), cull=False)
    monkeypatch.setattr(raster, "MAX_FRAGMENTS", 50)
    small = Buffers.empty(30, 30)
    rasterize(small, 0, vertices, np.array([[0, 1, 2], [0, 1, 2]]), (1.0, 1.0, 15.0, 15.0), cull=False)
    np.testing.assert_array_equal(full.mesh, small.mesh)
    np.testing.assert_array_equal(full.depth, small.depth)


def test_shading_is_brighter_facing_the_light_and_composites_over_background():
    # Two squares facing the camera; one tilted away from the light (which comes from above-left).
    square = np.array([[-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [1.0, 1.0, 0.0], [-1.0, 1.0, 0.0]])
    faces = np.array([[0, 3, 2], [0, 2, 1]])
    facing = square + [-1.5, 0, 6]
    tilt = np.radians(60)
    rot = np.array([[np.cos(tilt), 0, np.sin(tilt)], [0, 1, 0], [-np.sin(tilt), 0, np.cos(tilt)]])
    tilted = square @ rot.T + [1.5, 0, 6]
    background = np.full((60, 80, 3), 7, np.uint8)
    image, depth = render([Mesh(facing, faces, np.array([1.0, 1.0, 1.0]), smooth=False),
                           Mesh(tilted, faces, np.array([1.0, 1.0, 1.0]), smooth=False)],
                          (60.0, 60.0, 40.0, 30.0), 80, 60, background=background)
    assert (image[~np.isfinite(depth)] == 7).all()
    assert np.isfinite(depth[25:35, 20:30]).all() and np.isfinite(depth[25:35, 53:57]).all()
    left = image[25:35, 20:30].mean()
    right = image[25:35, 53:57].mean()
    assert left > right + 20  # the face turned away from the light is darker


def test_vertex_normals_of_a_closed_mesh_point_outwards():
    # Tetrahedron with outward (counter-clockwise from outside) faces.
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    n = vertex_normals(v, f)
    centre = v.mean(axis=0)
    assert (np.einsum("ij,ij->i", n, v - centre) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)
