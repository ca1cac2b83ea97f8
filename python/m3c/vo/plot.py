"""Camera-trajectory plots (matplotlib, the 'viz' extra)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from m3c.io import atomic_path


def _pyplot():
    try:
        import matplotlib
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError(
            "plotting needs matplotlib: pip install 'm3c[viz]' (or pip install matplotlib)") from e
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_trajectories(path: str | Path, panels: list[dict], title: str | None = None) -> None:
    """Writes a PNG with one top-view (x-z) and one side-view (z-y) row per panel.

    Each panel: {'title': str, 'curves': [(label, world_from_cam (T, 4, 4)), ...]}. World axes are OpenCV's
    (x right, y down, z forward of the first camera); the side view plots -y so up is up.
    The file is written atomically (temporary file + rename).
    """
    plt = _pyplot()
    fig, axes = plt.subplots(len(panels), 2, figsize=(10, 4.2 * len(panels)), squeeze=False)
    for row, panel in enumerate(panels):
        top, side = axes[row]
        for i, (label, poses) in enumerate(panel["curves"]):
            c = np.asarray(poses)[:, :3, 3]
            top.plot(c[:, 0], c[:, 2], ".-", ms=2, lw=1, label=label)
            side.plot(c[:, 2], -c[:, 1], ".-", ms=2, lw=1, label=label)
            if i == 0:  # start of the first curve
                top.plot(c[:1, 0], c[:1, 2], "ko", ms=4)
                side.plot(c[:1, 2], -c[:1, 1], "ko", ms=4)
        top.set_xlabel("x (right)")
        top.set_ylabel("z (forward)")
        side.set_xlabel("z (forward)")
        side.set_ylabel("-y (up)")
        top.set_title(f"{panel['title']}: top view", fontsize=10)
        side.set_title(f"{panel['title']}: side view", fontsize=10)
        for ax in (top, side):
            ax.set_aspect("equal", adjustable="datalim")
            ax.grid(True, alpha=0.3)
            ax.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
