"""docs/images/rig_mixamo.png: a result's motion retargeted onto the Mixamo skeleton (`--rig mixamo`), drawn
with matplotlib: the rig's rest pose (T pose, the performer's bone lengths) with its bone names, and the
retargeted skeleton at a few frames along its metric world path, planted (foot-locked) feet marked.

    PYTHONPATH=python python3 tools/render_rig.py OUT_DIR [--rig mixamo] [--png docs/images/rig_mixamo.png]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from m3c.export import load_source  # noqa: E402
from m3c.export.rig_files import track_rig_motion  # noqa: E402

LABELS = ("Hips", "Spine2", "Head", "LeftShoulder", "LeftHand", "LeftUpLeg", "LeftLeg", "LeftFoot")


def _bones(ax, points, parents, colour, width=1.6):
    for b, p in enumerate(parents):
        if p >= 0:
            ax.plot(*points[[p, b]].T, color=colour, lw=width, solid_capstyle="round")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("folder")
    parser.add_argument("--rig", default="mixamo")
    parser.add_argument("--png", default="docs/images/rig_mixamo.png")
    parser.add_argument("--keys", type=int, default=6, help="frames drawn along the path")
    args = parser.parse_args()
    source = load_source(args.folder)
    track = source.tracks[0]
    motion = track_rig_motion(source, track, args.rig, smoothing="standard")
    names = [n.split(":")[-1] for n in motion.names]
    fig = plt.figure(figsize=(12, 5.2))
    rest = fig.add_subplot(1, 3, 1, projection="3d")
    heads = motion.rest_positions[:, [0, 2, 1]]   # matplotlib's z up: (x, z, y) of y-up points
    _bones(rest, heads, motion.parents, "0.2")
    rest.scatter(*heads.T, s=6, color="tab:red")
    for name in LABELS:
        if name in names:
            b = names.index(name)
            rest.text(*heads[b], " " + name, fontsize=6)
    rest.set_title(f"{args.rig} rest pose (T), the performer's bone lengths", fontsize=9)
    rest.view_init(elev=0, azim=-90)
    _square(rest, heads)
    rest.set_yticks([])   # the depth axis, seen end on

    path = fig.add_subplot(1, 3, (2, 3), projection="3d")
    world = motion.world_positions[:, :, [0, 2, 1]]
    keys = np.linspace(0, len(world) - 1, args.keys).round().astype(int)
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(keys)))
    feet = [names.index("LeftFoot"), names.index("RightFoot")]
    for k, colour in zip(keys, colours):
        _bones(path, world[k], motion.parents, colour)
        for side, b in enumerate(feet):
            if motion.planted[k, side]:
                path.scatter(*world[k, b], s=22, color="k", marker="s")
    path.plot(*world[:, names.index("Hips")].T, color="0.5", lw=0.8, ls="--")
    path.set_title(f"retargeted motion, {len(keys)} of {len(world)} frames (world metres; squares: locked "
                   "feet)", fontsize=9)
    travel = world[-1, names.index("Hips")] - world[0, names.index("Hips")]
    path.view_init(elev=0, azim=np.degrees(np.arctan2(travel[1], travel[0])) - 90.0)   # side on to the path
    _square(path, world[keys].reshape(-1, 3))
    (path.set_xticks if abs(travel[1]) > abs(travel[0]) else path.set_yticks)([])   # the depth axis
    fig.tight_layout()
    Path(args.png).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.png, dpi=110)
    print(args.png)


def _square(ax, points):
    lo, hi = points.min(axis=0), points.max(axis=0)
    centre, half = (lo + hi) / 2, (hi - lo).max() / 2
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    ax.set_box_aspect((1, 1, 1))
    ax.set_proj_type("ortho")
    ax.set_xlabel("x")
    ax.set_ylabel("z")
    ax.set_zlabel("y (up)")


if __name__ == "__main__":
    main()
