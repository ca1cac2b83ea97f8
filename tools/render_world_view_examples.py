"""The documentation's pictures of the chase world view: a frame of a run's world.mp4, and planted against
sliding feet on two synthetic walkers (the same walk; in the second the feet never hold still).

    python tools/render_world_view_examples.py OUT_DIR       # OUT_DIR: an `m3c run` of the bundled clip
"""

from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "python"))

from test_viz_chase import chase, walker  # noqa: E402  (the tests' synthetic walker)


def main() -> None:
    images = ROOT / "docs" / "images"
    if len(sys.argv) > 1:
        capture = cv2.VideoCapture(str(Path(sys.argv[1]) / "world.mp4"))
        capture.set(cv2.CAP_PROP_POS_FRAMES, 170)
        ok, frame = capture.read()
        if not ok:
            raise SystemExit(f"{sys.argv[1]}/world.mp4 has no frame 170")
        cv2.imwrite(str(images / "world_chase.jpg"), frame, [cv2.IMWRITE_JPEG_QUALITY, 88])
    faces = np.zeros((0, 3), np.int32)
    pictures = []
    for slide, label in ((False, "planted feet: a row of steps"), (True, "sliding feet: a smear")):
        _, frames = chase([walker(slide=slide)])
        image = frames.frame(149, [], faces)
        cv2.putText(image, label, (14, 60), cv2.FONT_HERSHEY_SIMPLEX, 0.8, (30, 30, 160), 2, cv2.LINE_AA)
        pictures.append(cv2.resize(image, (480, 270), interpolation=cv2.INTER_AREA))
    cv2.imwrite(str(images / "world_chase_sliding.jpg"), np.hstack(pictures), [cv2.IMWRITE_JPEG_QUALITY, 88])


if __name__ == "__main__":
    main()
