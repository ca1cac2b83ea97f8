"""Renders a result folder's GLB export as Blender imports it (docs/images/export_glb_blender.jpg).

    python tools/render_glb_in_blender.py OUT_DIR [--frame K] [--out docs/images/export_glb_blender.jpg]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2

from m3c.export import export_results, load_source
from m3c.export.blender import render_glb


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--frame", type=int, help="processed frame to show (default: the middle one)")
    parser.add_argument("--out", default="docs/images/export_glb_blender.jpg")
    args = parser.parse_args()
    source = load_source(args.folder)
    frame = source.num_frames // 2 if args.frame is None else args.frame
    with tempfile.TemporaryDirectory() as tmp:
        glb, = export_results(args.folder, "glb", Path(tmp) / "scene.glb")
        png = render_glb(glb, Path(tmp) / "render.png", source.fps, frame)
        cv2.imwrite(args.out, cv2.imread(str(png)), [cv2.IMWRITE_JPEG_QUALITY, 88])
    print(args.out)


if __name__ == "__main__":
    main()
