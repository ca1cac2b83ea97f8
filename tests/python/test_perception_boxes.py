"""Box processing, the pixels of a box, subject isolation and patch sampling (thesis 4.1.2, m3c.perception.boxes),
checked against hand-computed boxes and per-pixel brute force in the one pixel convention: pixel (i, j) has its
centre at (i, j) and is the square [i - 0.5, i + 0.5) x [j - 0.5, j + 0.5); a W x H frame spans
[-0.5, W - 0.5] x [-0.5, H - 0.5]."""

import numpy as np
import pytest

from m3c.perception import Person, crop, iou, iou_matrix, isolate, process_box
from m3c.perception.boxes import (WHITE, extract_patch, isolation_mask, mask_in_region, pixel_region,
                                  process_boxes)
from m3c.perception.mediapipe_pose import tight_box


def covers(box, i, j) -> bool:
    """The reference rule for the pixels of a box: pixel (i, j)'s square overlaps the box with positive area."""
    return min(box[2], i + 0.5) > max(box[0], i - 0.5) and min(box[3], j + 0.5) > max(box[1], j - 0.5)


@pytest.mark.parametrize("box, size, square, crop_box", [
    # Pad 5 -> (35, 25, 55, 55), 20 x 30 -> square side 30 around (45, 40); inside the frame.
    ((40, 30, 50, 50), (80, 100), (30, 25, 60, 55), (30, 25, 60, 55)),
    # Near the left edge: side 50 around (5, 30) -> x from -20, shifted onto the frame's edge -0.5.
    ((0, 10, 10, 50), (80, 100), (-0.5, 5, 49.5, 55), (-0.5, 5, 49.5, 55)),
    # Bottom-right corner: side 90 around (630, 440) -> shifted left and up onto the edges 639.5 and 479.5.
    ((620, 400, 640, 480), (480, 640), (549.5, 389.5, 639.5, 479.5), (549.5, 389.5, 639.5, 479.5)),
    # Larger than the frame in both directions (side 109): centred on the frame (centre 49.5, 39.5), then cropped.
    ((0, 0, 99, 79), (80, 100), (-5, -15, 104, 94), (-0.5, -0.5, 99.5, 79.5)),
    # Just fits the height (side 30 = H): shifted up by half a pixel onto [-0.5, 29.5].
    ((10, 5, 30, 25), (30, 200), (5, -0.5, 35, 29.5), (5, -0.5, 35, 29.5)),
])
def test_process_boxes_by_hand(box, size, square, crop_box):
    got_square, got_crop = process_boxes(np.array([box], float), size, padding=5.0)
    np.testing.assert_allclose(got_square[0], square, atol=1e-12)
    np.testing.assert_allclose(got_crop[0], crop_box, atol=1e-12)


def test_process_boxes_rejects_bad_input():
    with pytest.raises(ValueError, match="x1 >= x0"):
        process_boxes(np.array([[10, 10, 5, 20]]), (100, 100))
    with pytest.raises(ValueError, match="padding"):
        process_boxes(np.array([[0, 0, 5, 5]]), (100, 100), padding=-1.0)
    with pytest.raises(ValueError, match="frame_size"):
        process_boxes(np.array([[0, 0, 5, 5]]), (0, 100))


def test_process_box_is_the_pixels_of_the_cropped_square():
    # 40 x 100 box in the middle of a 480 x 640 frame: padded to 50 x 110, squared to (265, 195, 375, 305), whose
    # edges halve the pixels 265, 375 (x) and 195, 305 (y): pixels 265..375 x 195..305.
    np.testing.assert_array_equal(process_box([300, 200, 340, 300], (480, 640), padding=5), [265, 195, 376, 306])
    # Squared to x -35..75, shifted onto the frame's edge: (-0.5, 5, 109.5, 115) -> pixels 0..109 x 5..115.
    np.testing.assert_array_equal(process_box([0, 10, 40, 110], (480, 640), padding=5), [0, 5, 110, 116])
    out = process_box([10, 0, 60, 470], (480, 640), padding=5)  # 480 px tall after padding: fits exactly
    np.testing.assert_array_equal(out, [0, 0, 480, 480])
    np.testing.assert_array_equal(process_box([0, 0, 640, 100], (480, 640), padding=5), [0, 0, 640, 480])
    # A fractional box: padded (5.3, 15.7, 35.2, 65.1), side 49.4 around x 20.25 -> x from -4.45, shifted to -0.5:
    # the square (-0.5, 15.7, 48.9, 65.1) covers pixels 0..49 x 16..65.
    np.testing.assert_array_equal(process_box([10.3, 20.7, 30.2, 60.1], (480, 640), padding=5), [0, 16, 50, 66])


def test_pixel_region_against_brute_force(rng):
    height, width = 12, 16
    for _ in range(200):
        box = np.sort(rng.uniform(-3, 19, size=(2, 2)), axis=0).T.reshape(4)[[0, 2, 1, 3]]
        x0, y0, x1, y1 = pixel_region(box, (height, width))
        got = np.zeros((height, width), bool)
        got[y0:y1, x0:x1] = True
        expected = np.array([[covers(box, i, j) for i in range(width)] for j in range(height)])
        np.testing.assert_array_equal(got, expected)


def test_a_masks_tight_box_holds_exactly_its_pixels():
    """The convention end to end: a mask's tight box (mediapipe_pose.tight_box) covers its pixels and no more."""
    mask = np.zeros((30, 40), bool)
    mask[7:19, 11:23] = True  # rows 7..18, columns 11..22: frame pixels x 111..122, y 207..218
    box = tight_box(np.zeros((21, 3)), mask, np.array([100, 200, 140, 230]), (480, 640))
    np.testing.assert_array_equal(box, [110.5, 206.5, 122.5, 218.5])
    assert pixel_region(box, (480, 640)) == (111, 207, 123, 219)


def test_iou_against_pixel_counting(rng):
    boxes = np.round(np.sort(rng.uniform(0, 50, size=(12, 2, 2)), axis=2).reshape(12, 4)[:, [0, 2, 1, 3]])
    def pixels(b):
        grid = np.zeros((60, 60), bool)
        grid[int(b[1]):int(b[3]), int(b[0]):int(b[2])] = True
        return grid
    m = iou_matrix(boxes, boxes[::-1])
    for i, a in enumerate(boxes):
        for j, b in enumerate(boxes[::-1]):
            pa, pb = pixels(a), pixels(b)
            union = (pa | pb).sum()
            expected = (pa & pb).sum() / union if union else 0.0
            assert m[i, j] == pytest.approx(expected)
            assert iou(a, b) == pytest.approx(expected)


def test_isolate_whitens_other_boxes_except_the_focus_mask():
    frame = np.full((100, 100, 3), 7, np.uint8)
    patch_box = np.array([10, 10, 90, 90])
    patch = crop(frame, patch_box)
    focus = np.zeros((80, 80), bool)
    focus[30:50, 30:50] = True  # the focused person reaches into the neighbour's box here
    # neighbour: frame [40, 120) -> patch [30, 80)
    out = isolate(patch, patch_box, [20, 20, 60, 60], [[40, 40, 120, 120]], focus)
    expected = np.full((80, 80, 3), 7, np.uint8)
    region = np.zeros((80, 80), bool)
    region[30:80, 30:80] = True
    expected[region & ~focus] = WHITE
    np.testing.assert_array_equal(out, expected)
    np.testing.assert_array_equal(patch, 7)  # the input is untouched


def test_isolate_with_neighbour_masks_whitens_only_their_pixels():
    patch = np.zeros((20, 20, 3), np.uint8)
    other = np.zeros((20, 20), bool)
    other[0:5, 0:5] = True
    out = isolate(patch, [0, 0, 20, 20], [12, 12, 20, 20], [[0, 0, 10, 10]], None, [other])
    assert (out[0:5, 0:5] == WHITE).all() and (out[5:10, 5:10] == 0).all()


def test_isolation_mask_against_brute_force(rng):
    """The whitening rule pixel by pixel: in another person's box (and its mask where given), not in the focused
    person's mask (or, without one, its tight box), over a region that is not at the frame's origin."""
    region = (5, 3, 35, 25)
    h, w = 22, 30
    for trial in range(20):
        corners = np.sort(rng.uniform(0, 40, size=(4, 2, 2)), axis=1)
        boxes = corners.transpose(0, 2, 1).reshape(4, 4)[:, [0, 2, 1, 3]]
        focus_box, others = boxes[0], boxes[1:]
        focus_mask = rng.uniform(size=(h, w)) > 0.5 if trial % 2 else None
        other_masks = [rng.uniform(size=(h, w)) > 0.3 if k != 1 else None for k in range(3)] if trial % 3 else None
        got = isolation_mask(region, focus_box, others, focus_mask, other_masks)
        expected = np.zeros((h, w), bool)
        for r in range(h):
            for c in range(w):
                i, j = region[0] + c, region[1] + r  # frame pixel
                whiten = any(covers(b, i, j) and (other_masks is None or other_masks[k] is None or other_masks[k][r, c])
                             for k, b in enumerate(others))
                kept = covers(focus_box, i, j) if focus_mask is None else focus_mask[r, c]
                expected[r, c] = whiten and not kept
        np.testing.assert_array_equal(got, expected)
    with pytest.raises(ValueError, match="focus_mask"):
        isolation_mask(region, focus_box, others, np.zeros((3, 3), bool))
    with pytest.raises(ValueError, match="one entry per other box"):
        isolation_mask(region, focus_box, others, None, [None])


def test_extract_patch_samples_the_square_in_the_pixel_convention():
    # Each frame pixel holds its centre's coordinate, u + 100 v (u = i, v = j): a linear image, which bilinear
    # sampling reproduces exactly, so a patch pixel shows the coordinate of its own centre.
    ys, xs = np.mgrid[0:60, 0:80].astype(np.float32)
    frame = np.repeat((xs + 100 * ys)[..., None], 3, axis=2)
    square = np.array([10.0, 20.0, 42.0, 52.0])  # side 32 -> 16 px patch: 2 frame pixels per patch pixel
    patch = extract_patch(frame, square, 16)
    k = np.arange(16)
    # The square's edges are the patch's edges: patch pixel k's centre is at x0 + (k + 0.5) side / size.
    u = square[0] + (k + 0.5) * 2
    v = square[1] + (k + 0.5) * 2
    np.testing.assert_allclose(patch[..., 0], u[None, :] + 100 * v[:, None], rtol=1e-5)
    # One frame pixel per patch pixel on a square along pixel edges: the patch is the frame's pixels themselves.
    np.testing.assert_array_equal(extract_patch(frame, [9.5, 19.5, 25.5, 35.5], 16), frame[20:36, 10:26])
    # Outside the frame is white.
    outside = extract_patch(frame, np.array([-40.0, -40.0, 0.0, 0.0]), 8)
    assert (outside == 255).all()


def test_mask_in_region_against_brute_force(rng):
    """A mask placed at a frame pixel, read over another index range: frame pixel by frame pixel."""
    for _ in range(30):
        mask = rng.uniform(size=rng.integers(1, 9, size=2)) > 0.5
        origin = rng.integers(-5, 15, size=2)
        x0, y0 = rng.integers(-5, 15, size=2)
        region = (x0, y0, x0 + rng.integers(0, 12), y0 + rng.integers(0, 12))
        got = mask_in_region(mask, origin, region)
        expected = np.zeros((region[3] - region[1], region[2] - region[0]), bool)
        for r in range(expected.shape[0]):
            for c in range(expected.shape[1]):
                i, j = region[0] + c - origin[0], region[1] + r - origin[1]  # the mask's pixel there
                expected[r, c] = 0 <= j < mask.shape[0] and 0 <= i < mask.shape[1] and mask[j, i]
        np.testing.assert_array_equal(got, expected)


def test_person_mask_resampling():
    mask = np.zeros((4, 6), bool)
    mask[1, 2] = True
    p = Person([0, 0, 10, 10], 0.9, mask=mask, mask_box=[10, 20, 16, 24])
    full = p.full_mask((30, 30))
    assert full.sum() == 1 and full[21, 12]
    np.testing.assert_array_equal(p.mask_in([12, 21, 14, 23]), [[True, False], [False, False]])
    with pytest.raises(ValueError, match="mask_box's size"):
        Person([0, 0, 1, 1], 1.0, mask=mask, mask_box=[0, 0, 5, 5])
    with pytest.raises(ValueError, match="keypoints"):
        Person([0, 0, 1, 1], 1.0, keypoints=np.zeros((16, 3)))
