"""A picture of `m3c view` on a result folder, taken in headless Chromium (docs/images/viewer.jpg).

    python tools/screenshot_viewer.py OUT_DIR [--frame K] [--out docs/images/viewer.jpg]
"""

from __future__ import annotations

import argparse
import tempfile
import threading
from pathlib import Path

import cv2

from m3c.viz.browser import free_port, screenshot_page
from m3c.viz.viewer import serve

# viser notes software WebGL in a toast over the scene; the picture is about the scene.
HIDE_NOTICES = "document.querySelectorAll('.mantine-Notification-root').forEach(e => e.remove())"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--frame", type=int, default=60)
    parser.add_argument("--out", default="docs/images/viewer.jpg")
    args = parser.parse_args()
    port, stop, up = free_port(), threading.Event(), threading.Event()

    def ready(viewer):
        viewer.set_frame(args.frame)
        viewer._initial_view(args.frame)
        up.set()

    thread = threading.Thread(target=serve, args=(args.folder,), kwargs=dict(port=port, stop=stop, ready=ready))
    thread.start()
    try:
        up.wait(120)
        with tempfile.TemporaryDirectory() as tmp:
            png = screenshot_page(f"http://127.0.0.1:{port}", Path(tmp) / "view.png", 1400, 800, wait_s=10.0,
                                  script=HIDE_NOTICES)
            cv2.imwrite(args.out, cv2.imread(str(png)), [cv2.IMWRITE_JPEG_QUALITY, 88])
    finally:
        stop.set()
        thread.join()
    print(args.out)


if __name__ == "__main__":
    main()
