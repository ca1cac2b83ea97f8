#!/usr/bin/env python3
"""Renders M3C's open body model in its rest pose and in a few poses and shapes (the README picture).

    python tools/render_body_model.py [--model PATH] [--out docs/images/open_body_model.png]

Needs matplotlib (pip install "m3c[viz]"). Meshes are drawn with flat shading and the painter's algorithm
(triangles sorted back to front), orthographic, so no 3D toolkit is involved. Poses are SMPL axis-angle
vectors posed by the C++ core (m3c.body.BodyModel.forward).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "python"))

from m3c.body import BodyModel  # noqa: E402
from m3c.body.joint_names import SMPL_JOINT_NAMES  # noqa: E402
from m3c.body.open_model import open_body_model_data  # noqa: E402
from m3c.body.model_file import load_model_file  # noqa: E402

J = {name: k for k, name in enumerate(SMPL_JOINT_NAMES)}


def pose_from(rotations: dict) -> np.ndarray:
    """SMPL pose (24 x 3 axis-angle) from {joint name: (rx, ry, rz) in degrees}."""
    pose = np.zeros((24, 3))
    for name, degrees in rotations.items():
        pose[J[name]] = np.radians(degrees)
    return pose


ARMS_DOWN = {"left_shoulder": (0, 0, -70), "right_shoulder": (0, 0, 70)}
# Mid-stride: left leg forward, right leg pushing off, arms swinging opposite (y up, facing +z, left = +x;
# a negative x rotation at the hip swings the leg forward, a positive one at the knee bends it).
WALK = {
    "left_hip": (-25, 0, 0), "left_knee": (8, 0, 0), "left_ankle": (5, 0, 0),
    "right_hip": (15, 0, 0), "right_knee": (30, 0, 0), "right_ankle": (-5, 0, 0),
    "left_shoulder": (-20, 0, -72), "right_shoulder": (20, 0, 72),
    "left_elbow": (0, -25, 0), "right_elbow": (0, 10, 0), "spine1": (4, 0, 0), "pelvis": (0, 8, 0),
}
WAVE = {
    "right_shoulder": (0, 0, -15), "right_elbow": (0, 0, -95), "left_shoulder": (0, 0, -70),
    "left_elbow": (0, -20, 0), "head": (0, -15, 8), "spine2": (0, 0, 4), "left_hip": (0, 0, 4),
}
SQUAT = {
    "left_hip": (-95, 0, -10), "right_hip": (-95, 0, 10), "left_knee": (110, 0, 0), "right_knee": (110, 0, 0),
    "left_ankle": (-10, 0, 0), "right_ankle": (-10, 0, 0), "spine1": (20, 0, 0), "spine2": (10, 0, 0),
    "left_shoulder": (-60, 0, -40), "right_shoulder": (-60, 0, 40),
}
RUN = {
    "left_hip": (-50, 0, 0), "left_knee": (60, 0, 0), "left_ankle": (10, 0, 0),
    "right_hip": (15, 0, 0), "right_knee": (85, 0, 0), "right_ankle": (20, 0, 0),
    "left_shoulder": (35, 0, -75), "right_shoulder": (-45, 0, 75),
    "left_elbow": (0, -80, 0), "right_elbow": (0, 85, 0), "spine1": (10, 0, 0), "spine2": (5, 0, 0),
}
SIT = {
    "left_hip": (-90, 0, 0), "right_hip": (-90, 0, 0), "left_knee": (90, 0, 0), "right_knee": (90, 0, 0),
    "left_shoulder": (0, 0, -75), "right_shoulder": (0, 0, 75), "left_elbow": (0, -60, 0),
    "right_elbow": (0, 60, 0),
}


def view_rotation(azimuth_deg: float, elevation_deg: float = 0.0) -> np.ndarray:
    """Camera-from-body rotation for an orthographic view: azimuth about y (0 = looking at the front)."""
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    yaw = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
    pitch = np.array([[1, 0, 0], [0, np.cos(e), -np.sin(e)], [0, np.sin(e), np.cos(e)]])
    return pitch @ yaw


def draw_mesh(ax, vertices: np.ndarray, faces: np.ndarray, rotation: np.ndarray, offset=(0.0, 0.0),
              color=(0.72, 0.78, 0.88)):
    """Flat-shaded orthographic drawing: the camera looks down -z of rotation @ v (x right, y up)."""
    from matplotlib.collections import PolyCollection

    v = vertices @ rotation.T
    tri = v[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
    facing = normal[:, 2] > 0  # back faces are hidden behind front faces of a closed body anyway
    light = np.array([-0.4, 0.5, 0.77])
    light /= np.linalg.norm(light)
    shade = 0.35 + 0.65 * np.clip(normal @ light, 0.0, 1.0)
    order = np.argsort(tri[:, :, 2].mean(axis=1))
    order = order[facing[order]]
    colors = np.clip(np.outer(shade[order], color), 0, 1)
    polys = tri[order][:, :, :2] + np.asarray(offset)
    ax.add_collection(PolyCollection(polys, facecolors=colors, edgecolors=colors, linewidths=0.15))


def render(model: BodyModel, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    zeros = np.zeros(model.num_betas)
    poses = []  # (title, vertices, joints or None, azimuth)
    rest = model.forward(np.zeros((1, 24, 3)), zeros)
    poses.append(("rest pose, beta = 0", rest.vertices[0], rest.joints[0], 0.0))
    poses.append(("rest pose, side", rest.vertices[0], rest.joints[0], 90.0))
    for title, rotations, azimuth in (("walking", WALK, 40.0), ("running", RUN, 70.0), ("waving", WAVE, -20.0),
                                      ("squat", SQUAT, 50.0), ("sitting", SIT, 60.0)):
        posed = model.forward(pose_from(rotations)[None], zeros)
        poses.append((title, posed.vertices[0], None, azimuth))
    shapes = []
    arms_down = pose_from(ARMS_DOWN)[None]
    for b in range(3):
        for value in (-2.0, 2.0):
            betas = zeros.copy()
            betas[b] = value
            shaped = model.forward(arms_down, betas)
            shapes.append((f"beta[{b}] = {value:+.0f}", shaped.vertices[0], None, 0.0))
    shapes.insert(0, ("beta = 0", model.forward(arms_down, zeros).vertices[0], None, 0.0))

    columns = max(len(poses), len(shapes))
    fig, axes = plt.subplots(2, columns, figsize=(1.9 * columns, 5.6))
    for row, panels in enumerate((poses, shapes)):
        for ax in axes[row]:
            ax.axis("off")
        for ax, (title, vertices, joints, azimuth) in zip(axes[row], panels):
            feet = vertices[:, 1].min()
            centre = np.array([vertices[:, 0].mean(), feet, vertices[:, 2].mean()])
            rotation = view_rotation(azimuth)
            draw_mesh(ax, vertices - centre, model.faces, rotation)
            if joints is not None:
                j = (joints - centre) @ rotation.T
                ax.scatter(j[:, 0], j[:, 1], s=5, c="crimson", zorder=3)
            ax.set_title(title, fontsize=9)
            ax.set_xlim(-0.9, 0.9)
            ax.set_ylim(-0.05, 1.95)
            ax.set_aspect("equal")
    fig.suptitle(f"{model.data.name}: open (CC0) SMPL-layout body model built from MakeHuman hm08 assets\n"
                 f"{model.num_vertices} vertices, SMPL's 24 joints (red), {model.num_betas} shape components; "
                 "poses are SMPL axis-angle vectors", fontsize=10)
    fig.tight_layout(h_pad=1.2, w_pad=0.1)
    out.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=out.parent, suffix=".png")
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110)
        os.chmod(tmp, 0o644)  # mkstemp makes it private
        os.replace(tmp, out)
    except BaseException:
        os.unlink(tmp)
        raise
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", type=Path, default=None, help="model file (default: the shipped open model)")
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "images" / "open_body_model.png")
    args = parser.parse_args(argv)
    data = load_model_file(args.model) if args.model else open_body_model_data()
    render(BodyModel(data), args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
