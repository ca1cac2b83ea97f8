"""The camera-trajectory plot (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m3c.viz.scene import track_colour


def camera_trajectory_plot(path: str | Path, world_from_cam: np.ndarray, fps: float,
                           people: list[tuple[int, np.ndarray]], title: str = "") -> None:
    """Top view (x, z) of the camera path coloured by time, with each person's root path, and the camera's height
    and the distance it travelled over time. people: (track id, root positions (n, 3) in the world)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    centres = world_from_cam[:, :3, 3]
    t = np.arange(len(centres)) / fps
    fig, (top, side) = plt.subplots(1, 2, figsize=(11, 4.6), gridspec_kw={"width_ratios": [1.25, 1]})
    for track_id, roots in people:
        top.plot(roots[:, 0], roots[:, 2], color=track_colour(track_id), lw=1.5, label=f"person {track_id}")
    points = top.scatter(centres[:, 0], centres[:, 2], c=t, cmap="viridis", s=8, zorder=3)
    top.plot(centres[:, 0], centres[:, 2], color="0.3", lw=0.8, zorder=2)
    top.scatter(*centres[0, [0, 2]], marker="o", s=60, facecolor="none", edgecolor="k", zorder=4, label="camera start")
    # Viewing direction every second.
    step = max(int(round(fps)), 1)
    forward = world_from_cam[::step, :3, 2]
    top.quiver(centres[::step, 0], centres[::step, 2], forward[:, 0], forward[:, 2], angles="xy", color="0.25",
               width=0.003, scale=12, zorder=3)
    top.set_aspect("equal", adjustable="datalim")
    top.invert_xaxis()  # seen from above (y towards the viewer): +x to the left, as the first camera sees it
    top.set_xlabel("x (m)")
    top.set_ylabel("z (m)")
    top.set_title("seen from above")
    top.grid(alpha=0.3)
    top.legend(loc="best", fontsize=8)
    fig.colorbar(points, ax=top, label="time (s)")
    travelled = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(centres, axis=0), axis=1))]
    side.plot(t, centres[:, 1], label="camera height y (m)")
    side.plot(t, travelled, label="distance travelled (m)")
    side.set_xlabel("time (s)")
    side.grid(alpha=0.3)
    side.legend(fontsize=8)
    side.set_title("camera over time")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
