"""M3C's shipped open body model (MakeHuman hm08, CC0) in SMPL layout.

Everything here uses only the file inside the package; the rebuild test at the end needs the MakeHuman assets
(../shared/data/body_model/makehuman) and skips without them.
"""

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

import m3c
from m3c.body import (OPEN_MODEL_NAME, BodyModel, BodyModelFileError, default_body_model, load_model_file,
                      open_body_model_data, open_body_model_path, parse_model_arrays)
from m3c.body.joint_names import KEYPOINT_VERTEX_NAMES, SMPL_JOINT_NAMES, SMPL_PARENTS
from m3c.body.reference import lbs

J = {name: k for k, name in enumerate(SMPL_JOINT_NAMES)}
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def data():
    return open_body_model_data()


@pytest.fixture(scope="module")
def model(data):
    return BodyModel(data)


def pose_from(degrees: dict) -> np.ndarray:
    pose = np.zeros((24, 3))
    for name, value in degrees.items():
        pose[J[name]] = np.radians(value)
    return pose


# Mid-stride with arms swinging down by the sides (y up, facing +z, left = +x).
WALK = pose_from({
    "pelvis": (0, 10, 0), "spine1": (5, 0, 0), "spine2": (3, 5, 0), "spine3": (2, 5, 0), "head": (-5, -10, 0),
    "left_hip": (-30, 0, 3), "left_knee": (15, 0, 0), "left_ankle": (10, 0, 0),
    "right_hip": (20, 0, -3), "right_knee": (45, 0, 0), "right_ankle": (-15, 0, 0),
    "left_collar": (0, 0, -5), "right_collar": (0, 0, 5),
    "left_shoulder": (-25, 0, -75), "right_shoulder": (25, 0, 75),
    "left_elbow": (0, -30, 0), "right_elbow": (0, 20, 0), "left_wrist": (0, 0, -10), "right_wrist": (0, 0, 10),
})


def standing_height(model, betas) -> float:
    vertices = model.forward(np.zeros((1, 24, 3)), betas).vertices[0]
    return float(np.ptp(vertices[:, 1]))


def distance_to_segments(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Distance of every point to its nearest segment (P x S)."""
    axis = ends - starts
    t = np.einsum("psc,sc->ps", points[:, None] - starts[None], axis) / np.einsum("sc,sc->s", axis, axis)
    closest = starts[None] + np.clip(t, 0.0, 1.0)[..., None] * axis[None]
    return np.linalg.norm(points[:, None] - closest, axis=2).min(axis=1)


# -- the file -------------------------------------------------------------------------------------------------
def test_ships_inside_the_package_with_its_licence():
    path = open_body_model_path()
    package = Path(m3c.__file__).resolve().parent
    assert package in path.resolve().parents
    assert path.stat().st_size < 5_000_000
    assert (path.parent / "LICENSE.ASSETS.md").read_text().startswith("# Creative Commons CC0 1.0 Universal")
    note = (path.parent / "m3c_open_body.md").read_text()
    assert "CC0" in note and "a8bc2d54" in note
    with np.load(path) as archive:
        assert str(archive["licence"]) == "CC0-1.0"
        assert "MakeHuman" in str(archive["origin"])


def test_loads_through_the_smpl_loader(data):
    assert data.name == OPEN_MODEL_NAME
    assert load_model_file(open_body_model_path()).name == OPEN_MODEL_NAME
    V = data.num_vertices
    assert (data.num_joints, data.num_betas) == (24, 10)
    assert tuple(data.parents.tolist()) == SMPL_PARENTS
    assert data.v_template.shape == (V, 3) and data.v_template.dtype == np.float64
    assert data.shapedirs.shape == (V, 3, 10)
    assert data.posedirs.shape == (V, 3, 207) and not data.posedirs.any()  # no pose blend shapes
    assert data.J_regressor.shape == (24, V) and data.weights.shape == (V, 24)
    np.testing.assert_allclose(data.J_regressor.sum(axis=1), 1.0, atol=1e-6)
    assert data.J_regressor.min() >= 0.0
    np.testing.assert_allclose(data.weights.sum(axis=1), 1.0, atol=1e-6)
    assert data.weights.min() >= 0.0
    assert data.faces.shape[1] == 3 and data.faces.min() == 0 and data.faces.max() == V - 1
    assert len(np.unique(data.faces)) == V  # body vertices only: every vertex is on the surface
    assert sorted(data.keypoint_vertex_ids) == sorted(KEYPOINT_VERTEX_NAMES)


def test_default_body_model_is_the_open_model_when_no_file_is_configured(data):
    model = default_body_model()
    assert model.data.name == OPEN_MODEL_NAME
    np.testing.assert_array_equal(model.data.v_template, data.v_template)


def test_missing_posedirs_means_zeros_only_in_m3c_files(data):
    raw = {"v_template": data.v_template, "shapedirs": data.shapedirs, "J_regressor": data.J_regressor,
           "weights": data.weights, "kintree_table": np.stack([data.parents, np.arange(24)]), "f": data.faces}
    with pytest.raises(BodyModelFileError, match="posedirs"):
        parse_model_arrays(raw)  # an SMPL file without posedirs is broken
    compact = parse_model_arrays({**raw, "m3c_model_format": np.asarray(1), "model_name": np.asarray("x")})
    assert compact.name == "x" and compact.posedirs.shape == (data.num_vertices, 3, 207)
    assert not compact.posedirs.any()
    with pytest.raises(BodyModelFileError, match="newer"):
        parse_model_arrays({**raw, "m3c_model_format": np.asarray(99)})


# -- skinning ---------------------------------------------------------------------------------------------------
def test_cpp_skinning_matches_numpy_reference(data, model):
    rng = np.random.default_rng(7)
    pose = 0.4 * rng.standard_normal((3, 24, 3))
    pose[0] = WALK
    betas = rng.standard_normal((3, 10))
    transl = rng.standard_normal((3, 3))
    out = model.forward(pose, betas, transl)
    ref_vertices, ref_joints = lbs(data, pose, betas, transl)
    np.testing.assert_allclose(out.vertices, ref_vertices, rtol=0, atol=1e-10)
    np.testing.assert_allclose(out.joints, ref_joints, rtol=0, atol=1e-10)


def test_rest_pose_matches_smpl_conventions(model):
    out = model.forward(np.zeros((1, 24, 3)), np.zeros(10))
    joints, vertices = out.joints[0], out.vertices[0]
    np.testing.assert_allclose(joints[J["pelvis"]], 0.0, atol=1e-6)  # pelvis at the origin
    assert joints[J["head"], 1] > joints[J["neck"], 1] > joints[J["pelvis"], 1] > joints[J["left_knee"], 1]  # y up
    assert joints[J["left_shoulder"], 0] > 0.1 and joints[J["right_shoulder"], 0] < -0.1  # left = +x
    nose = vertices[model.keypoint_vertex_ids()["nose"]]
    assert nose[2] > joints[J["head"], 2] + 0.05  # faces +z
    # T-pose: shoulder -> elbow -> wrist -> hand horizontal along +-x; legs nearly vertical.
    for side, sign in (("left", 1.0), ("right", -1.0)):
        chain = joints[[J[f"{side}_{n}"] for n in ("shoulder", "elbow", "wrist", "hand")]]
        directions = np.diff(chain, axis=0)
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        np.testing.assert_allclose(directions, np.tile([sign, 0.0, 0.0], (3, 1)), atol=1e-3)
        for a, b in (("hip", "knee"), ("knee", "ankle")):
            d = joints[J[f"{side}_{b}"]] - joints[J[f"{side}_{a}"]]
            assert np.degrees(np.arccos(-d[1] / np.linalg.norm(d))) < 10.0
    # Mirror symmetric: every joint's mirror image is its opposite joint.
    mirror = [SMPL_JOINT_NAMES.index(n.replace("left", "@").replace("right", "left").replace("@", "right"))
              for n in SMPL_JOINT_NAMES]
    np.testing.assert_allclose(joints[mirror] * [-1, 1, 1], joints, atol=1e-4)


# -- anthropometry -----------------------------------------------------------------------------------------------
def test_standing_height_and_limb_lengths_are_human(model):
    out = model.forward(np.zeros((1, 24, 3)), np.zeros(10))
    joints, vertices = out.joints[0], out.vertices[0]
    height = float(np.ptp(vertices[:, 1]))
    assert 1.55 < height < 1.85
    arm_span = float(np.ptp(vertices[:, 0]))
    assert 0.93 < arm_span / height < 1.07  # arm span is close to stature

    def length(a, b):
        return np.linalg.norm(joints[J[a]] - joints[J[b]]) / height

    # Segment lengths as fractions of stature (Drillis, Contini & Bluestein 1964: thigh 0.245, shank 0.246,
    # upper arm 0.186, forearm 0.146, shoulder width 0.259 (biacromial)), allowing for where joint centres sit.
    for side in ("left", "right"):
        assert 0.20 < length(f"{side}_hip", f"{side}_knee") < 0.29
        assert 0.20 < length(f"{side}_knee", f"{side}_ankle") < 0.29
        assert 0.13 < length(f"{side}_shoulder", f"{side}_elbow") < 0.22
        assert 0.11 < length(f"{side}_elbow", f"{side}_wrist") < 0.18
    assert 0.17 < length("left_shoulder", "right_shoulder") < 0.28
    assert 0.07 < length("left_hip", "right_hip") < 0.16
    assert 0.27 < length("pelvis", "neck") < 0.38
    # Feet on a floor below the ankles, heads above the neck.
    assert 0.04 < joints[J["left_ankle"], 1] - vertices[:, 1].min() < 0.12
    assert 0.15 < vertices[:, 1].max() - joints[J["neck"], 1] < 0.35


def test_first_shape_component_changes_height_monotonically(model):
    values = np.linspace(-3.0, 3.0, 13)
    heights = []
    for value in values:
        betas = np.zeros(10)
        betas[0] = value
        heights.append(standing_height(model, betas))
    heights = np.asarray(heights)
    assert np.all(np.diff(heights) > 0.0)
    assert 1.4 < heights[0] and heights[-1] < 2.1 and heights[-1] - heights[0] > 0.3


def test_shape_components_are_orthogonal_and_ordered_by_variance(data):
    dirs = data.shapedirs.reshape(-1, 10)
    gram = dirs.T @ dirs
    norms = np.sqrt(np.diag(gram))
    assert np.all(np.diff(norms) <= 0.0)
    cosines = gram / np.outer(norms, norms)
    np.testing.assert_allclose(cosines, np.eye(10), atol=1e-3)


# -- posing -------------------------------------------------------------------------------------------------------
def test_walking_pose_has_no_exploded_vertices(model):
    betas_list = (np.zeros(10), np.r_[2.0, -1.5, 1.0, np.zeros(7)], np.r_[-2.0, 1.5, -1.0, np.zeros(7)])
    for betas in betas_list:
        out = model.forward(WALK[None], betas)
        joints, vertices = out.joints[0], out.vertices[0]
        children = np.arange(1, 24)
        parents = np.asarray(SMPL_PARENTS)[1:]
        distance = distance_to_segments(vertices, joints[parents], joints[children])
        assert distance.max() < 0.3, f"a vertex is {distance.max():.2f} m from every bone at betas {betas[:3]}"
        # The walking pose moved the limbs: a wrong weight would leave vertices behind in the T-pose.
        rest = model.forward(np.zeros((1, 24, 3)), betas).vertices[0]
        hands = [model.keypoint_vertex_ids()["left_hand"], model.keypoint_vertex_ids()["right_hand"]]
        assert np.all(vertices[hands, 1] < rest[hands, 1] - 0.4)


def test_keypoint_vertices_sit_where_coco_expects_them(model):
    out = model.forward(np.zeros((1, 24, 3)), np.zeros(10))
    v, joints = out.vertices[0], out.joints[0]
    kp = {name: v[i] for name, i in model.keypoint_vertex_ids().items()}
    assert abs(kp["nose"][0]) < 1e-3 and kp["nose"][2] > kp["left_eye"][2] > kp["left_ear"][2]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        assert 0.02 < sign * kp[f"{side}_eye"][0] < 0.05
        assert sign * kp[f"{side}_ear"][0] > sign * kp[f"{side}_eye"][0] + 0.03
        assert abs(kp[f"{side}_eye"][1] - kp[f"{side}_ear"][1]) < 0.05
        assert kp[f"{side}_heel"][2] < joints[J[f"{side}_ankle"], 2] < kp[f"{side}_big_toe"][2]
        assert sign * kp[f"{side}_small_toe"][0] > sign * kp[f"{side}_big_toe"][0]
        for name in ("heel", "big_toe", "small_toe"):
            assert kp[f"{side}_{name}"][1] < v[:, 1].min() + 0.04  # on the sole
        assert sign * kp[f"{side}_hand"][0] > sign * joints[J[f"{side}_hand"], 0] + 0.05  # the middle fingertip
    coco = model.keypoints(model.coco17_regressor(), np.zeros((1, 24, 3)), np.zeros(10))[0]
    np.testing.assert_allclose(coco[0], kp["nose"], atol=1e-12)
    np.testing.assert_allclose(coco[5], joints[J["left_shoulder"]], atol=1e-12)


# -- rebuilding from the assets ----------------------------------------------------------------------------------
def _load_builder():
    spec = importlib.util.spec_from_file_location("build_open_body_model", REPO / "tools" / "build_open_body_model.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up there
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_rebuild_from_makehuman_assets_reproduces_the_shipped_file():
    builder = _load_builder()
    assets = builder.default_assets()
    if not (assets / "base.obj").is_file():
        pytest.skip(f"MakeHuman hm08 assets not found at {assets} (../shared/data/body_model/makehuman); "
                    "the shipped model file is tested above")
    arrays, report = builder.build(assets, verbose=False)
    # The joint regressor reproduces the MakeHuman skeleton's joints (from its joint vertex groups).
    assert report["mean_shape_joint_error"] < 1e-4
    assert report["component_joint_error"].max() < 0.012  # metres per unit beta
    assert report["explained_variance"].sum() > 0.99
    with np.load(open_body_model_path()) as shipped:
        assert sorted(shipped.files) == sorted(arrays)
        for key in arrays:
            if arrays[key].dtype.kind == "f":
                np.testing.assert_allclose(shipped[key], arrays[key], rtol=0, atol=2e-5, err_msg=key)
            else:
                np.testing.assert_array_equal(shipped[key], arrays[key], err_msg=key)
