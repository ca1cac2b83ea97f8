"""docs/images/rig_mixamo.png: a result's motion retargeted onto the Mixamo skeleton (`--rig mixamo`),
rendered by Blender itself (bpy headless, Cycles on the CPU): the rig's GLB (T reference pose, `standard`
smoothing) imported into Blender, its T rest pose (the performer's bone lengths) and a few frames of the
motion side by side (each turned so that its hips' left-right line lies across the view), the skinned mesh
translucent over the bones (octahedra: body bones orange, finger bones blue), and a close-up of the T pose's
left hand and its finger bones.

    PYTHONPATH=python python3 tools/render_rig.py OUT_DIR [--rig mixamo] [--png docs/images/rig_mixamo.png]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import cv2
import numpy as np
from m3c.export import export_results, load_source
from m3c.export.blender import run_blender
from m3c.io.atomic import atomic_path

HAND_BONE = {"mixamo": "mixamorig:LeftHand", "ue5": "hand_l", "unity": "LeftHand", "rigify": "DEF-hand.L",
             "smpl": "left_wrist"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder")
    parser.add_argument("--rig", default="mixamo", choices=sorted(HAND_BONE))
    parser.add_argument("--png", default="docs/images/rig_mixamo.png")
    parser.add_argument("--keys", type=int, default=4, help="frames of the motion shown beside the rest pose")
    parser.add_argument("--size", default="900x420", help="the full view's width x height (pixels)")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    source = load_source(args.folder)
    track = source.tracks[0]
    n = len(track.frames)
    # Key 0 is the T reference pose; the motion's keys follow (1 .. n), the shown ones spread over the track.
    keys = [0] + [1 + int(k) for k in np.linspace(0.1 * (n - 1), 0.9 * (n - 1), args.keys).round()]
    with tempfile.TemporaryDirectory(prefix="m3c-rig-render-") as tmp:
        glb, = export_results(args.folder, "glb", Path(tmp) / "rig", tracks=[track.track_id], rig=args.rig,
                              smoothing="standard", reference_pose="tpose")
        png = Path(tmp) / "rig.png"
        run_blender("rig", glb, repr(source.fps), ",".join(map(str, keys)), png, HAND_BONE[args.rig], width,
                    height)
        full, hand = cv2.imread(str(png)), cv2.imread(f"{png}.hand.png")
    image = np.concatenate([full, np.full((height, 6, 3), 255, np.uint8), hand], axis=1)
    caption = (f"{args.rig} rig in Blender: T rest pose, then {args.keys} of {n} frames "
               f"(track {track.track_id}); right: the left hand's finger bones")
    cv2.putText(image, caption, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (40, 40, 40), 1, cv2.LINE_AA)
    out = Path(args.png)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp_png:
        from PIL import Image

        # A 256-colour palette keeps the picture small (the README's images stay under 300 KB).
        Image.fromarray(image[:, :, ::-1]).quantize(256, dither=Image.Dither.NONE).save(tmp_png, format="PNG",
                                                                                          optimize=True)
    print(out, f"{out.stat().st_size // 1024} KB")


if __name__ == "__main__":
    main()
