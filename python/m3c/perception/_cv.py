"""OpenCV, imported on first use with an error that says how to get it."""

from __future__ import annotations


def import_cv2():
    try:
        import cv2
    except ImportError as err:
        raise ImportError("this part of m3c.perception needs OpenCV's Python package: pip install 'm3c[perception]' "
                          "(MediaPipe brings opencv-contrib-python) or pip install opencv-python-headless") from err
    return cv2
