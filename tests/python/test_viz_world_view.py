"""The world view's camera path: one polyline per frame, drawn as the per-segment reference draws it."""

import cv2
import numpy as np

from m3c.viz.scene import WorldView


def _reference_path(view: WorldView, image: np.ndarray, points: np.ndarray, colour) -> None:
    """The drawing written out: the points in front of the view camera, rounded, joined segment by segment."""
    uv, z = view.project(points)
    kept = [tuple(int(round(c)) for c in p) for p, d in zip(uv, z) if d > 0.05 and np.isfinite(p).all()]
    for p, q in zip(kept[:-1], kept[1:]):
        cv2.line(image, p, q, colour, 2, cv2.LINE_AA)


def _covered(image: np.ndarray) -> np.ndarray:
    return (image < 250).any(axis=2)


def test_camera_path_drawing_matches_the_segment_by_segment_reference():
    rng = np.random.default_rng(0)
    t = np.linspace(0.0, 20.0, 3000)
    path = np.stack([3 * np.cos(t), 1.5 + 0.1 * np.sin(3 * t), 3 * np.sin(t) + 0.2 * t], axis=1)
    path[::7] += rng.normal(scale=0.002, size=path[::7].shape)
    path[100:200] = path[100]  # a camera at rest: repeated pixels
    path[500] = np.nan  # a frame without a camera
    view = WorldView(rng.normal(size=(50, 3)), path[np.isfinite(path).all(axis=1)], 0.0)
    behind = view.pose[:3, 3] - 0.5 * view.pose[:3, 2]  # behind the view camera: skipped by both
    path = np.vstack([path[:1000], behind, path[1000:]])
    for colour in ((40, 40, 40), (150, 150, 150)):
        reference = np.full((view.height, view.width, 3), 250, np.uint8)
        drawn = reference.copy()
        _reference_path(view, reference, path, colour)
        view._draw_path(drawn, path, colour)
        a, b = _covered(reference), _covered(drawn)
        assert a.sum() > 2000
        assert (a & b).sum() / (a | b).sum() > 0.99
        # Only anti-aliased edges differ (the reference blends each segment's ends twice where segments meet).
        assert np.abs(reference.astype(int) - drawn.astype(int)).mean() < 0.5


def test_camera_path_of_fewer_than_two_points_draws_nothing():
    view = WorldView(np.zeros((1, 3)), np.array([[0.0, 1.5, -3.0]]), 0.0)
    image = np.full((view.height, view.width, 3), 250, np.uint8)
    view._draw_path(image, np.array([[0.0, 1.5, -3.0]]), (40, 40, 40))
    view._draw_path(image, np.zeros((0, 3)), (40, 40, 40))
    assert (image == 250).all()
