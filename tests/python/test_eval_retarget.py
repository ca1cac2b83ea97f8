"""BVH reading (hand-computed forward kinematics) and retargeting (a BVH written from the body model itself,
whose joints the fit must recover)."""

import os
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from m3c.body import default_body_model
from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.eval.retarget import (JOINT_MAPS, RetargetConfig, RetargetedMotion, detect_joint_map,
                               levenberg_marquardt, retarget)
from m3c.io.bvh import BVHError, read_bvh


def _shared_mocap() -> Path:
    """../shared/data/mocap beside the checkout (or a worktree's parent), or $M3C_SHARED_DATA/mocap."""
    if os.environ.get("M3C_SHARED_DATA"):
        return Path(os.environ["M3C_SHARED_DATA"]) / "mocap"
    root = Path(__file__).resolve().parents[2]
    for base in (root.parent, root.parent.parent):
        if (base / "shared" / "data" / "mocap").is_dir():
            return base / "shared" / "data" / "mocap"
    return root.parent / "shared" / "data" / "mocap"


SHARED_MOCAP = _shared_mocap()

TWO_JOINTS = """HIERARCHY
ROOT Root
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Child
  {
    OFFSET 0 0 1
    CHANNELS 3 Zrotation Xrotation Yrotation
    End Site
    {
      OFFSET 0 2 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.5
1 2 3 90 90 0 0 0 0
0 0 0 0 0 0 90 0 0
"""


def test_bvh_forward_kinematics_hand_computed(tmp_path):
    path = tmp_path / "two.bvh"
    path.write_text(TWO_JOINTS)
    bvh = read_bvh(path)
    assert bvh.names == ["Root", "Child", "Child_end"]
    assert bvh.fps == pytest.approx(2.0)
    pos = bvh.positions()
    # Frame 0: R_root = Rz(90) Rx(90) (intrinsic, listed order). Rx(90) takes (0,0,1) to (0,-1,0), Rz(90)
    # takes
    # that to (1,0,0): the child sits at (1,2,3) + (1,0,0). (Extrinsic order would give (1,2,3) + (0,-1,0).)
    np.testing.assert_allclose(pos[0, 0], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(pos[0, 1], [2, 2, 3], atol=1e-12)
    # The end site (0,2,0) under R_root alone: Rx(90) (0,2,0) = (0,0,2), Rz(90) (0,0,2) = (0,0,2).
    np.testing.assert_allclose(pos[0, 2], [2, 2, 5], atol=1e-12)
    # Frame 1: the child rotates Rz(90): its end site (0,2,0) goes to (-2,0,0).
    np.testing.assert_allclose(pos[1, 2], [-2, 0, 1], atol=1e-12)


def test_bvh_position_channels_replace_the_offset(tmp_path):
    text = TWO_JOINTS.replace("CHANNELS 3 Zrotation", "CHANNELS 6 Xposition Yposition Zposition Zrotation")
    text = text.replace("1 2 3 90 90 0 0 0 0", "0 0 0 0 0 0 0 0 5 0 0 0").replace(
        "0 0 0 0 0 0 90 0 0", "0 0 0 0 0 0 0 0 5 0 0 0")
    path = tmp_path / "pos.bvh"
    path.write_text(text)
    np.testing.assert_allclose(read_bvh(path).positions()[0, 1], [0, 0, 5])  # not 0 0 6


def test_bvh_errors_name_the_problem(tmp_path):
    path = tmp_path / "bad.bvh"
    path.write_text(TWO_JOINTS.replace("Frames: 2", "Frames: 3"))
    with pytest.raises(BVHError, match="promises 3 frames"):
        read_bvh(path)
    path.write_text(TWO_JOINTS.replace("Zrotation Xrotation Yrotation\n    End",
                                       "Zrotation Wrotation Yrotation\n    End"))
    with pytest.raises(BVHError, match="unknown channels"):
        read_bvh(path)
    with pytest.raises(FileNotFoundError):
        read_bvh(tmp_path / "missing.bvh")


def write_model_bvh(path, model, pose, transl, fps, units_per_metre=100.0, z_up=False):
    """A BVH with the body model's own skeleton (joint names SMPL's), posed by `pose`: its joints coincide
    with the model's joints, so a retarget must reproduce them."""
    rest = model.joints(np.zeros((1, 24, 3)), np.zeros(model.num_betas))[0]
    parents = np.asarray(model.parents)
    children = {j: [c for c in range(24) if parents[c] == j] for j in range(24)}
    to_file = Rotation.from_euler("x", 90, degrees=True) if z_up else Rotation.identity()  # y-up -> z-up

    lines = ["HIERARCHY"]

    def emit(j, depth):
        pad = "  " * depth
        offset = rest[j] - (rest[parents[j]] if parents[j] >= 0 else 0.0)
        offset = to_file.apply(offset) * units_per_metre
        kind = "ROOT" if parents[j] < 0 else "JOINT"
        lines.append(f"{pad}{kind} {SMPL_JOINT_NAMES[j]}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {offset[0]:.6f} {offset[1]:.6f} {offset[2]:.6f}")
        channels = "6 Xposition Yposition Zposition Zrotation Xrotation Yrotation" if parents[j] < 0 else \
            "3 Zrotation Xrotation Yrotation"
        lines.append(f"{pad}  CHANNELS {channels}")
        for c in children[j]:
            emit(c, depth + 1)
        if not children[j]:
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET 0 0 0", pad + "  }"])
        lines.append(pad + "}")

    emit(0, 0)
    lines += ["MOTION", f"Frames: {len(pose)}", f"Frame Time: {1.0 / fps:.8f}"]
    order = []

    def collect(j):
        order.append(j)
        for c in children[j]:
            collect(c)

    collect(0)
    for f in range(len(pose)):
        row = []
        for j in order:
            r = Rotation.from_rotvec(pose[f, j])
            if j == 0:
                root_pos = to_file.apply(transl[f] + rest[0]) * units_per_metre
                row += list(root_pos)
                r = to_file * r * to_file.inv()
            else:
                r = to_file * r * to_file.inv()
            row += list(r.as_euler("ZXY", degrees=True))
        lines.append(" ".join(f"{v:.6f}" for v in row))
    path.write_text("\n".join(lines) + "\n")


@pytest.fixture(scope="module")
def open_model():
    return default_body_model()


@pytest.mark.parametrize("z_up", [False, True])
def test_retarget_recovers_the_model_own_motion(tmp_path, open_model, z_up):
    rng = np.random.default_rng(7)
    n, fps = 9, 60.0
    pose = np.zeros((n, 24, 3))
    pose[:, 0] = Rotation.from_euler("y", np.linspace(0, 2.5, n)[:, None]).as_rotvec()  # turning on the spot
    base = 0.4 * rng.normal(size=(23, 3))
    pose[:, 1:] = base + 0.2 * np.sin(np.linspace(0, 3, n))[:, None, None] * rng.normal(size=(23, 3))
    transl = np.stack([np.linspace(0, 1, n), np.full(n, 0.9), np.zeros(n)], axis=1)
    path = tmp_path / "self.bvh"
    write_model_bvh(path, open_model, pose, transl, fps, z_up=z_up)
    joint_map = {name: name for name in JOINT_MAPS["cmu_motionbuilder"]}  # the same 16 joints, SMPL names
    # z-up: the scale from limb lengths alone (exact for identical skeletons); y-up: then refined by the
    # search.
    config = RetargetConfig(fps=fps / 2, up_axis="z" if z_up else "y", pose_prior=1e-3, temporal=1e-3,
                            refine_scale=not z_up)
    result = retarget(open_model, path, joint_map, config)

    assert result.num_frames == (n - 1) // 2 + 1  # resampled from 60 to 30 fps
    assert result.info["scale"] == pytest.approx(0.01, rel=1e-6 if z_up else 2e-3)  # cm to metres
    assert np.abs(result.betas).max() < 0.05
    assert result.fit_error_mm.max() < 3.0
    # The fitted joints are the source joints (shifted onto the ground); every 2nd source frame is an output
    # frame.
    ids = [SMPL_JOINT_NAMES.index(k) for k in joint_map]
    truth = open_model.joints(pose[::2], np.zeros(open_model.num_betas), transl[::2])[:, ids]
    fitted = open_model.joints(result.pose(), result.betas, result.transl)[:, ids]
    shift = np.median((fitted - truth).reshape(-1, 3), axis=0)
    assert abs(shift[0]) < 2e-3 and abs(shift[2]) < 2e-3  # only the ground shift, along y
    assert np.linalg.norm(fitted - truth - shift, axis=-1).max() < 6e-3
    # Ground: the lowest mesh point of most frames at y = 0.
    lowest = open_model.forward(result.pose(), result.betas, result.transl).vertices[:, :, 1].min(axis=1)
    assert np.quantile(lowest, 0.1) == pytest.approx(0.0, abs=1e-9)


def test_retarget_rejects_unknown_skeletons(tmp_path, open_model):
    path = tmp_path / "two.bvh"
    path.write_text(TWO_JOINTS)
    with pytest.raises(ValueError, match="no known joint naming"):
        detect_joint_map(read_bvh(path))
    with pytest.raises(ValueError, match="SMPL joint names"):
        retarget(open_model, path, {"Root": "Root"})


def test_levenberg_marquardt_matches_scipy_on_a_curve_fit():
    t = np.linspace(0, 3, 40)
    y = 2.0 * np.exp(-1.3 * t) + 0.5 * np.sin(2.0 * t)

    def fun(p):
        a, b, c = p
        r = a * np.exp(-b * t) + c * np.sin(2.0 * t) - y
        J = np.stack([np.exp(-b * t), -a * t * np.exp(-b * t), np.sin(2.0 * t)], axis=1)
        return r, J

    from scipy.optimize import least_squares

    ref = least_squares(lambda p: fun(p)[0], [1.0, 0.5, 0.0], jac=lambda p: fun(p)[1], xtol=1e-14, ftol=1e-14).x
    np.testing.assert_allclose(levenberg_marquardt(fun, np.array([1.0, 0.5, 0.0]), 100), ref, atol=1e-8)
    np.testing.assert_allclose(ref, [2.0, 1.3, 0.5], atol=1e-8)


def test_retargeted_motion_round_trips(tmp_path):
    motion = RetargetedMotion(30.0, np.ones((4, 3)), np.zeros((4, 3)), np.zeros((4, 23, 3)), np.zeros(10),
                              np.zeros(4), "x.bvh", "m3c-open-hm08")
    motion.save(tmp_path / "m.npz")
    back = RetargetedMotion.load(tmp_path / "m.npz")
    assert back.fps == 30.0 and back.source == "x.bvh" and back.transl.dtype == np.float64
    np.testing.assert_array_equal(back.transl, motion.transl)


@pytest.mark.skipif(not (SHARED_MOCAP / "cmu" / "131_01.bvh").is_file(),
                    reason="needs ../shared/data/mocap (the CMU clips are not part of the repository)")
def test_retarget_real_cmu_clip(open_model):
    # Every 4th BVH frame of the first 4 s (120 fps; the file's frame time is 0.0083333 s), output at 10 fps.
    result = retarget(open_model, SHARED_MOCAP / "cmu" / "131_01.bvh", frames=slice(1, 482, 4),
                      config=RetargetConfig(fps=10.0, refine_scale=False))
    assert detect_joint_map(read_bvh(SHARED_MOCAP / "cmu" / "131_01.bvh")) == "cmu_3dsmax"
    assert result.num_frames == 40
    assert np.median(result.fit_error_mm) < 20.0  # different skeletons: cm-level agreement
