"""Box processing and subject isolation (thesis 4.1.2), checked against hand-computed boxes and brute force."""

import numpy as np
import pytest

from m3c.perception import Person, crop, iou, iou_matrix, isolate, process_box
from m3c.perception.boxes import WHITE


def test_process_box_pads_squares_and_keeps_the_centre():
    # 40 x 100 box in the middle of a 480 x 640 frame: padded to 50 x 110, squared to 110 x 110 around its centre.
    out = process_box([300, 200, 340, 300], (480, 640), padding=5)
    np.testing.assert_array_equal(out, [265, 195, 375, 305])


def test_process_box_shifts_inside_the_frame():
    out = process_box([0, 10, 40, 110], (480, 640), padding=5)  # would start at x = -40 after squaring
    np.testing.assert_array_equal(out, [0, 5, 110, 115])
    assert out[2] - out[0] == out[3] - out[1]
    out = process_box([620, 400, 640, 480], (480, 640), padding=5)  # bottom-right corner
    np.testing.assert_array_equal(out, [550, 390, 640, 480])


def test_process_box_crops_what_is_larger_than_the_frame():
    out = process_box([10, 0, 60, 470], (480, 640), padding=5)  # 480 px tall after padding: fits exactly
    assert out[3] - out[1] == 480 and out[1] == 0
    out = process_box([0, 0, 640, 100], (480, 640), padding=5)  # 650 wide: cropped to the frame's width and height
    np.testing.assert_array_equal(out, [0, 0, 640, 480])


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
    out = isolate(patch, patch_box, [[40, 40, 120, 120]], focus)  # neighbour: frame [40, 120) -> patch [30, 80)
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
    out = isolate(patch, [0, 0, 20, 20], [[0, 0, 10, 10]], None, [other])
    assert (out[0:5, 0:5] == WHITE).all() and (out[5:10, 5:10] == 0).all()


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
