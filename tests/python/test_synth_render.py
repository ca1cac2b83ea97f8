"""The synthetic-video rasteriser (m3c._core RenderFrame/Texture) against independent numpy references."""

import numpy as np
import pytest
from m3c import _core
from m3c.body import default_body_model
from m3c.viz.raster import Buffers, rasterize


def _mips(texture: np.ndarray) -> list[np.ndarray]:
    levels = [texture.astype(np.float64)]
    while levels[-1].shape[0] > 1 or levels[-1].shape[1] > 1:
        t = levels[-1]
        h, w = max(1, t.shape[0] // 2), max(1, t.shape[1] // 2)
        sy, sx = t.shape[0] // h, t.shape[1] // w
        levels.append(t.reshape(h, sy, w, sx, 3).mean(axis=(1, 3)))
    return levels


def _bilinear(level: np.ndarray, u: float, v: float) -> np.ndarray:
    h, w = level.shape[:2]
    x, y = u - 0.5, v - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    ax, ay = x - x0, y - y0
    i0, j0 = int(x0) % w, int(y0) % h
    i1, j1 = (i0 + 1) % w, (j0 + 1) % h
    top = level[j0, i0] * (1 - ax) + level[j0, i1] * ax
    bottom = level[j1, i0] * (1 - ax) + level[j1, i1] * ax
    return top * (1 - ay) + bottom * ay


def _trilinear(levels, u, v, footprint):
    lod = np.clip(np.log2(max(footprint, 1.0)), 0, len(levels) - 1)
    l0 = int(np.floor(lod))
    t = lod - l0
    a = _bilinear(levels[l0], u / 2**l0, v / 2**l0)
    if t > 0 and l0 + 1 < len(levels):
        a = (1 - t) * a + t * _bilinear(levels[l0 + 1], u / 2 ** (l0 + 1), v / 2 ** (l0 + 1))
    return a


def test_texture_trilinear_matches_numpy():
    rng = np.random.default_rng(0)
    image = rng.uniform(size=(32, 64, 3)).astype(np.float32)
    texture = _core.Texture(image)
    levels = _mips(image)
    assert texture.num_levels == len(levels) == 7
    for _ in range(300):
        u, v = rng.uniform(-100, 100, size=2)
        footprint = float(np.exp(rng.uniform(-1, 5)))
        np.testing.assert_allclose(
            texture.sample(u, v, footprint), _trilinear(levels, u, v, footprint), atol=1e-5
        )


def test_texture_rejects_sides_that_are_not_powers_of_two():
    with pytest.raises(ValueError, match="powers of two"):
        _core.Texture(np.zeros((30, 64, 3), np.float32))


def test_coverage_and_depth_match_the_numpy_rasteriser():
    model = default_body_model()
    rng = np.random.default_rng(1)
    pose = 0.3 * rng.normal(size=(1, model.num_joints, 3))
    verts = model.forward(pose, np.zeros(model.num_betas)).vertices[0]
    verts = verts - verts.mean(axis=0) + np.array([0.05, 0.1, 2.5])
    faces = np.asarray(model.faces, dtype=np.int32)
    K = np.array([300.0, 310.0, 159.5, 119.5])
    for cull in (True, False):
        frame = _core.RenderFrame(320, 240, np.zeros(3, np.float32))
        frame.draw_coloured(
            K, verts, faces, np.ones((len(faces), 3), np.float32), np.array([0, 0, -1.0]), id=7, cull=cull
        )
        ref = Buffers.empty(320, 240)
        rasterize(ref, 0, verts, faces, K, cull=cull)
        assert (ref.mesh >= 0).sum() > 500
        np.testing.assert_array_equal(frame.ids >= 0, ref.mesh >= 0)
        assert set(np.unique(frame.ids)) == {-1, 7}
        covered = ref.mesh >= 0
        np.testing.assert_allclose(frame.depth[covered], ref.depth[covered], rtol=1e-6)


def test_plane_behind_the_camera_is_clipped_and_exact():
    # A ground plane y = 1.5 below the camera (y down) from z = -10 to z = 50: it reaches behind the camera.
    K = np.array([200.0, 200.0, 99.5, 74.5])
    corners = np.array([[-30, 1.5, -10], [30, 1.5, -10], [-30, 1.5, 50], [30, 1.5, 50]], dtype=np.float64)
    faces = np.array([[0, 2, 1], [1, 2, 3]], np.int32)
    texture = _core.Texture(np.full((4, 4, 3), 0.5, np.float32))
    uv = corners[:, [0, 2]] * 10.0
    frame = _core.RenderFrame(200, 150, np.zeros(3, np.float32))
    frame.draw_textured(K, corners, faces, texture, uv, np.array([0, -1.0, 0]), ambient=0.2, id=3, near=0.1)
    v, u = np.mgrid[0:150, 0:200].astype(np.float64)
    ray_y = (v - K[3]) / K[1]
    z = np.where(ray_y > 0, 1.5 / np.where(ray_y > 0, ray_y, 1), np.inf)
    x = (u - K[2]) / K[0] * z
    expected = (ray_y > 0) & (z <= 50) & (z >= 0.1) & (np.abs(x) <= 30)
    # Pixels within half a pixel of the far edge may go either way.
    edge = np.abs((K[1] * 1.5 / 50 + K[3]) - v) < 1.0
    np.testing.assert_array_equal((frame.ids == 3)[~edge], expected[~edge])
    np.testing.assert_allclose(frame.depth[expected & ~edge], z[expected & ~edge], rtol=1e-5)
    # A uniform texture, light from straight above the plane's visible side: shade = ambient + (1 - ambient).
    np.testing.assert_allclose(frame.rgb[expected & ~edge], 0.5, atol=1e-5)


def test_fronto_parallel_texture_at_one_texel_per_pixel():
    rng = np.random.default_rng(2)
    image = rng.uniform(size=(64, 64, 3)).astype(np.float32)
    K = np.array([100.0, 100.0, 31.5, 31.5])
    z = 2.0
    # A square facing the camera covering pixels 0..63 (centres at integers): texel centre i + 0.5 at pixel i.
    half = 32 * z / K[0]
    corners = np.array([[-half, -half, z], [half, -half, z], [-half, half, z], [half, half, z]])
    uv = np.array([[0, 0], [64, 0], [0, 64], [64, 64]], dtype=np.float64)
    frame = _core.RenderFrame(64, 64, np.zeros(3, np.float32))
    frame.draw_textured(
        K,
        corners,
        np.array([[0, 2, 1], [1, 2, 3]], np.int32),
        _core.Texture(image),
        uv,
        np.array([0, 0, -1.0]),
        ambient=0.3,
    )
    np.testing.assert_allclose(frame.rgb, image, atol=1e-4)


def test_bad_input_is_a_clear_error():
    frame = _core.RenderFrame(16, 16, np.zeros(3, np.float32))
    K = np.array([10.0, 10.0, 8.0, 8.0])
    verts = np.array([[0, 0, 1.0], [1, 0, 1], [0, 1, 1]])
    with pytest.raises(ValueError, match="outside"):
        frame.draw_coloured(
            K, verts, np.array([[0, 1, 5]], np.int32), np.ones((1, 3), np.float32), np.array([0, 0, -1.0])
        )
    with pytest.raises(ValueError, match="face_rgb"):
        frame.draw_coloured(
            K, verts, np.array([[0, 1, 2]], np.int32), np.ones((2, 3), np.float32), np.array([0, 0, -1.0])
        )
    with pytest.raises(ValueError, match="vertices"):
        frame.draw_coloured(
            K,
            verts[:, :2],
            np.array([[0, 1, 2]], np.int32),
            np.ones((1, 3), np.float32),
            np.array([0, 0, -1.0]),
        )


def test_a_glossy_floor_mirrors_what_stands_on_it():
    """A red box 0.4-0.8 m above a grey floor: with gloss g the floor pixels where the box's mirror image
    (y -> -y) projects take g of the box's colour, the rest of the floor and the box itself are unchanged."""
    from m3c.camera import project, to_camera
    from m3c.synth.render import Renderer, TexturedMesh
    from m3c.synth.world import box_mesh

    grey = np.full((8, 8, 3), 0.5, np.float32)
    red = np.zeros((8, 8, 3), np.float32)
    red[..., 0] = 1.0
    floor = TexturedMesh(np.array([[-20, 0, -5], [20, 0, -5], [-20, 0, 40], [20, 0, 40]], np.float64),
                         np.array([[0, 2, 1], [1, 2, 3]], np.int32), np.zeros((4, 2)), 0, False, ground=True)
    box = box_mesh(np.array([0.0, 4.0]), np.array([0.6, 0.4, 0.6]), 0.0, 1)
    box.vertices = box.vertices + np.array([0.0, 0.4, 0.0])  # floating 0.4 m above the floor
    # Camera 1.5 m up at z = 0 looking along +z, tilted 20 degrees down (OpenCV axes: y down).
    tilt = np.radians(20.0)
    c, s = np.cos(tilt), np.sin(tilt)
    R = np.array([[-1.0, 0, 0], [0, -c, -s], [0, -s, c]]).T  # columns: the camera's x, y, z in the world
    world_from_cam = np.eye(4)
    world_from_cam[:3, :3], world_from_cam[:3, 3] = R, [0.0, 1.5, 0.0]
    K = np.array([150.0, 150.0, 79.5, 59.5])
    renderer = Renderer([grey, red], 160, 120, supersample=1, ambient=1.0)
    matte = renderer.render(world_from_cam, K, [box, floor], [])
    glossy = renderer.render(world_from_cam, K, [box, floor], [], gloss=0.3)

    def pixel(point):
        u, v = project(to_camera(np.asarray(point, np.float64)[None], world_from_cam), K)[0]
        return int(round(v)), int(round(u))

    box_px, mirror_px = pixel([0.0, 0.6, 4.0]), pixel([0.0, -0.6, 4.0])
    np.testing.assert_array_equal(glossy.image[box_px], matte.image[box_px])  # the box: not a floor pixel
    assert matte.ids[mirror_px] == -1 and np.isfinite(matte.depth[mirror_px])
    # Its mirror image on the floor: 0.7 grey + 0.3 red (BGR order), to a rounding level.
    expected = 0.7 * matte.image[mirror_px].astype(float) + 0.3 * np.array([0.0, 0.0, 255.0])
    np.testing.assert_allclose(glossy.image[mirror_px].astype(float), expected, atol=2.0)
    # Far from the mirror image the floor is as it was (the sky is not mirrored onto it).
    far = pixel([1.5, 0.0, 6.0])
    np.testing.assert_array_equal(glossy.image[far], matte.image[far])
    changed = np.any(glossy.image != matte.image, axis=-1)
    assert changed.sum() < 0.2 * changed.size and changed[mirror_px]
