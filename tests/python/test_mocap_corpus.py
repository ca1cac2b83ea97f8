"""The fast retarget (checked against the inverse-kinematics retarget's shipped CMU clip) and `m3c data mocap`
(archives, folders, a bad file, the cache, the benchmark clips left out, the held-out split, determinism)."""

import json
import shutil
import tarfile

import numpy as np
import pytest

from m3c.body.joint_names import SMPL_JOINT_NAMES
from m3c.cli import main
from m3c.eval.benchmark import shipped_clip_paths
from m3c.eval.retarget import JOINT_MAPS, RetargetedMotion
from m3c.io.bvh import read_bvh
from m3c.mocap.corpus import foot_contacts, held_out, load_corpus
from m3c.mocap.fast_retarget import FastRetargetConfig, fast_retarget, fit_betas_to_bones
from test_eval_retarget import SHARED_MOCAP

needs_mocap = pytest.mark.skipif(not (SHARED_MOCAP / "cmu" / "131_01.bvh").is_file(),
                                 reason=f"the shared mocap clips are not at {SHARED_MOCAP}")


@needs_mocap
def test_fast_retarget_agrees_with_the_ik_retarget_on_the_shipped_clip(open_model):
    """The shipped cmu_131_01.npz is m3c eval retarget's fit of 131_01.bvh (BVH frames 1-993): the fast
    retarget, given the same metres per BVH unit, puts the joints where it does."""
    ref = RetargetedMotion.load(next(p for p in shipped_clip_paths() if p.name == "cmu_131_01.npz"))
    bvh = read_bvh(SHARED_MOCAP / "cmu" / "131_01.bvh")
    names = list(JOINT_MAPS["cmu_3dsmax"])
    # The IK retarget's metres per BVH unit: the distance its pelvis travels over the distance the BVH's hips
    # travel (120 fps -> 30 fps: every 4th BVH frame).
    ref_joints = open_model.joints(ref.pose(), ref.betas, ref.transl)
    pos = bvh.positions(slice(1, None))[::4, [bvh.index(JOINT_MAPS["cmu_3dsmax"][n]) for n in ("left_hip",
                                                                                               "right_hip")]]
    hips = pos.mean(axis=1)[: ref.num_frames]
    scale = float(np.linalg.norm(np.diff(ref_joints[:, 0], axis=0), axis=-1).sum()
                  / np.linalg.norm(np.diff(hips, axis=0), axis=-1).sum())
    assert 0.056 < scale < 0.07  # the IK retarget sized the performer up to the model (1/0.45 inch: 0.0564)
    fast = fast_retarget(open_model, bvh, None, FastRetargetConfig(scale=scale), frames=slice(1, None))
    assert fast.num_frames == ref.num_frames == 248
    assert fast.fit_error_mm.mean() < 15.0
    joints = open_model.joints(fast.pose(), fast.betas, fast.transl)
    dist = np.linalg.norm(joints - ref_joints, axis=-1) * 1000.0
    matched = [SMPL_JOINT_NAMES.index(n) for n in names]
    assert dist[:, matched].mean() < 40.0, dist[:, matched].mean(0)
    assert dist.mean() < 50.0
    # Both stand on the ground: the lowest joint per frame at about the same height.
    assert abs(np.median(joints[:, :, 1].min(1)) - np.median(ref_joints[:, :, 1].min(1))) < 0.03


@needs_mocap
def test_fast_retarget_bandai_clip_is_plausible(open_model):
    clip = fast_retarget(open_model, SHARED_MOCAP / "bandai_namco" / "dataset-1_walk_normal_001.bvh")
    assert clip.info["scale"] == 0.01  # centimetres, snapped
    assert clip.num_frames == 194      # 195 frames at 30 fps
    assert clip.fit_error_mm.mean() < 10.0
    joints = open_model.joints(clip.pose(), clip.betas, clip.transl)
    height = joints[:, 15, 1].mean() - joints[:, [10, 11], 1].min(1).mean()
    assert 1.35 < height < 1.85
    # The knees bend about their hinge (SMPL's x axis), not sideways.
    knees = clip.pose()[:, [4, 5]]
    assert np.abs(knees[..., 0]).mean() > 3 * np.abs(knees[..., 1]).mean()


def test_fit_betas_to_bones_recovers_the_lengths(open_model, rng):
    true = rng.normal(scale=1.0, size=open_model.num_betas)
    rest = open_model.joints(np.zeros((1, 24, 3)), true)[0]
    pairs = [("left_hip", "left_knee"), ("left_knee", "left_ankle"), ("left_shoulder", "left_elbow"),
             ("left_elbow", "left_wrist"), ("left_hip", "right_hip"), ("left_shoulder", "right_shoulder"),
             ("left_hip", "neck"), ("neck", "head"), ("left_ankle", "left_foot")]
    index = SMPL_JOINT_NAMES.index
    lengths = {p: float(np.linalg.norm(rest[index(p[0])] - rest[index(p[1])])) for p in pairs}
    betas = fit_betas_to_bones(open_model, lengths, prior=1e-4)
    fitted = open_model.joints(np.zeros((1, 24, 3)), betas)[0]
    for (a, b), length in lengths.items():
        got = np.linalg.norm(fitted[SMPL_JOINT_NAMES.index(a)] - fitted[SMPL_JOINT_NAMES.index(b)])
        assert abs(got - length) < 1e-3


def test_foot_contacts_from_height_and_speed():
    T = 30
    joints = np.zeros((T, 24, 3))
    joints[:, 7, 1] = 0.08                                   # left ankle planted
    joints[:, 8, 1] = 0.08 + np.linspace(0, 0.15, T)        # right ankle lifting (0.15 m/s)
    joints[:, 10, 2] = np.linspace(0, 1.5, T)               # left toe sliding at 1.5 m/s
    joints[:, 11, 1] = 0.02
    c = foot_contacts(joints, 30.0, height=0.06, speed=0.3)
    assert c[:, 0].all() and c[:, 3].all()
    assert not c[:, 2].any()
    assert c[:3, 1].all() and not c[-10:, 1].any()


def test_held_out_split_is_a_stable_hash():
    names = [f"clip_{i}" for i in range(2000)]
    chosen = [n for n in names if held_out(n, 10.0)]
    assert 150 < len(chosen) < 250
    assert chosen == [n for n in names if held_out(n, 10.0)]
    assert not any(held_out(n, 0.0) for n in names) and all(held_out(n, 100.0) for n in names)


@needs_mocap
def test_data_mocap_cli(tmp_path, capsys):
    src = tmp_path / "src"
    (src / "walks").mkdir(parents=True)
    bandai = SHARED_MOCAP / "bandai_namco"
    # Copies under new names (the originals are benchmark clips, always left out), one inside an archive.
    shutil.copy(bandai / "dataset-2_run_normal_001.bvh", src / "walks" / "run_a.bvh")
    shutil.copy(SHARED_MOCAP / "cmu" / "131_01.bvh", src / "walks" / "benchmark_named.bvh")
    shutil.copy(bandai / "dataset-1_walk_normal_001.bvh", src / "walks" / "dataset-1_walk_normal_001.bvh")
    (src / "walks" / "broken.bvh").write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0\n")
    with tarfile.open(tmp_path / "pack.tar.xz", "w:xz") as tar:
        tar.add(bandai / "dataset-2_walk_normal_002.bvh", arcname="pack/data/walk_b.bvh")
    out = tmp_path / "corpus"
    args = ["data", "mocap", str(src), str(tmp_path / "pack.tar.xz"), "--out", str(out), "--held-out", "50",
            "--exclude", str(src / "walks" / "benchmark_named.bvh")]
    assert main(args) == 0
    printed = capsys.readouterr()
    assert "2 clips" in printed.out and "1 failed" in printed.out
    assert "2 benchmark clips left out" in printed.out
    assert "walks__broken" in printed.out and "FAILED" in printed.err
    index = json.loads((out / "index.json").read_text())
    assert sorted(index["clips"]) == ["pack__pack__data__walk_b", "walks__run_a"]
    assert index["failed"]["walks__broken"]["error"].startswith("BVHError")
    assert sorted(index["excluded_benchmark_clips"]) == ["walks__benchmark_named",
                                                          "walks__dataset-1_walk_normal_001"]
    assert "share of frames: pelvis_below_0.6m 0.00%" in printed.out
    assert index["coverage"]["frames"] == index["frames"]
    assert 0.0 < index["coverage"]["both_feet_off_ground"] < 0.5
    split = json.loads((out / "split.json").read_text())
    assert sorted(split["train"] + split["held_out"]) == sorted(index["clips"])
    assert split["held_out"] == sorted(c for c in index["clips"] if held_out(c, 50.0))
    with np.load(out / "clips" / "walks__run_a.npz") as z:
        assert z["pose"].shape == (67, 24, 3) and z["pose"].dtype == np.float32
        assert z["transl"].shape == (67, 3) and z["betas"].shape == (10,) and z["contacts"].shape == (67, 4)
        assert float(z["fps"]) == 30.0 and "non-commercial" in str(z["licence"])
        first = {k: z[k] for k in z.files}
    with np.load(out / "clips" / "pack__pack__data__walk_b.npz") as z:
        assert 0.3 < z["contacts"].mean() < 0.8       # a walker's feet are planted about half the time
    stamp = (out / "clips" / "walks__run_a.npz").stat().st_mtime_ns
    # A second run reuses every finished clip; a fresh folder gives the same arrays (deterministic).
    assert main(args + ["--quiet"]) == 0
    assert (out / "clips" / "walks__run_a.npz").stat().st_mtime_ns == stamp
    assert main(["data", "mocap", str(src / "walks" / "run_a.bvh"), "--out", str(tmp_path / "again"),
                 "--quiet"]) == 0
    with np.load(tmp_path / "again" / "clips" / "run_a.npz") as z:
        for key in ("pose", "transl", "betas", "contacts"):
            np.testing.assert_array_equal(z[key], first[key])
    clips = load_corpus(out)
    assert len(clips) == 2 and {str(c["clip"]) for c in clips} == set(index["clips"])
    capsys.readouterr()
    assert main(["data", "mocap", str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
