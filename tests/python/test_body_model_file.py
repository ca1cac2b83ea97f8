"""Loading SMPL-layout files without chumpy, and the errors a user sees for bad files."""

import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse

from m3c.body import BodyModel, BodyModelFileError, load_model_file
from m3c.body.joint_names import SMPL_PARENTS
from m3c.body.layouts import to_smpl_layout
from m3c.body.model_file import BodyModelData
from m3c.body.synthetic import random_pose


def _official_dict(data, chumpy_cls):
    """The key layout of the official SMPL .pkl (v1.0/1.1): chumpy arrays and a scipy csc J_regressor."""
    def ch(x):
        obj = chumpy_cls.__new__(chumpy_cls)
        obj.__dict__.update({"x": np.asarray(x), "_dirty_vars": set(), "_itr": None})
        return obj

    V = data.num_vertices
    kintree = np.stack([np.asarray(data.parents, dtype=np.int64), np.arange(data.num_joints)])
    kintree[0, 0] = 4294967295
    return {
        "v_template": ch(data.v_template),
        "shapedirs": ch(data.shapedirs),
        "posedirs": data.posedirs.copy(),
        "J_regressor": scipy.sparse.csc_matrix(data.J_regressor),
        "J_regressor_prior": scipy.sparse.csc_matrix(data.J_regressor),
        "weights": ch(data.weights),
        "weights_prior": data.weights.copy(),
        "kintree_table": kintree,
        "f": data.faces.astype(np.uint32),
        "J": ch(data.J_regressor @ data.v_template),
        "vert_sym_idxs": np.arange(V),
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }


@pytest.fixture
def fake_smpl_pkl(tmp_path, synthetic_model_data):
    """Writes a pickle whose chumpy objects name the real chumpy module, then removes that module again, so the
    loader must cope without chumpy. Module names are rewritten to those numpy 1.x / old scipy wrote."""
    chumpy = types.ModuleType("chumpy")
    chumpy_ch = types.ModuleType("chumpy.ch")

    class Ch:
        pass

    Ch.__module__ = "chumpy.ch"
    Ch.__qualname__ = "Ch"
    chumpy_ch.Ch = Ch
    chumpy.ch = chumpy_ch
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = chumpy, chumpy_ch
    try:
        blob = pickle.dumps(_official_dict(synthetic_model_data, Ch), protocol=2)
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]
    assert b"chumpy.ch" in blob
    blob = blob.replace(b"numpy._core.multiarray", b"numpy.core.multiarray")
    blob = blob.replace(b"scipy.sparse._csc", b"scipy.sparse.csc")
    path = tmp_path / "basicModel_neutral_lbs_10_207_0_v1.0.0.pkl"
    path.write_bytes(blob)
    return path


def _assert_same(a: BodyModelData, b: BodyModelData):
    for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "parents", "faces"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key), err_msg=key)


def test_official_pickle_loads_without_chumpy(fake_smpl_pkl, synthetic_model_data):
    assert "chumpy" not in sys.modules
    data = load_model_file(fake_smpl_pkl)
    _assert_same(data, synthetic_model_data)
    assert data.parents[0] == -1 and data.parents.dtype == np.int64
    assert "chumpy" not in sys.modules


def test_npz_loads_and_num_betas_truncates(tmp_path, synthetic_model_data):
    d = synthetic_model_data
    kintree = np.stack([d.parents, np.arange(24)])
    path = tmp_path / "SMPL_NEUTRAL.npz"
    # smplx-style npz: posedirs already flattened to (3V, 207)
    np.savez(path, v_template=d.v_template, shapedirs=d.shapedirs, posedirs=d.posedirs.reshape(-1, 207),
             J_regressor=d.J_regressor, weights=d.weights, kintree_table=kintree, f=d.faces)
    _assert_same(load_model_file(path), d)
    assert load_model_file(path, num_betas=4).num_betas == 4
    assert load_model_file(path, num_betas=None).num_betas == 10
    with pytest.raises(BodyModelFileError, match="asked for 16 shape components, the file has 10"):
        load_model_file(path, num_betas=16)


def test_missing_file_says_where_to_get_smpl(tmp_path):
    with pytest.raises(FileNotFoundError, match=r"smpl\.is\.tue\.mpg\.de"):
        load_model_file(tmp_path / "SMPL_NEUTRAL.pkl")


def test_missing_keys_are_named(tmp_path, synthetic_model_data):
    path = tmp_path / "broken.npz"
    np.savez(path, v_template=synthetic_model_data.v_template)
    with pytest.raises(BodyModelFileError, match=r"missing keys \['shapedirs', 'posedirs'"):
        load_model_file(path)


def test_inconsistent_shapes_are_named(tmp_path, synthetic_model_data):
    d = synthetic_model_data
    path = tmp_path / "bad.npz"
    np.savez(path, v_template=d.v_template, shapedirs=d.shapedirs, posedirs=d.posedirs,
             J_regressor=d.J_regressor[:, :-1], weights=d.weights, kintree_table=np.stack([d.parents, d.parents]),
             f=d.faces)
    with pytest.raises(BodyModelFileError, match=r"'J_regressor' must be \(24, 576\)"):
        load_model_file(path)


def test_garbage_and_unknown_formats(tmp_path):
    junk = tmp_path / "model.pkl"
    junk.write_bytes(b"not a pickle at all")
    with pytest.raises(BodyModelFileError, match="not a readable body model pickle"):
        load_model_file(junk)
    other = tmp_path / "model.obj"
    other.write_text("v 0 0 0\n")
    with pytest.raises(BodyModelFileError, match="unknown body model format"):
        load_model_file(other)


def test_pickle_cannot_run_code(tmp_path):
    class Evil:
        def __reduce__(self):
            import os

            return (os.system, ("echo pwned",))

    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": Evil()}, protocol=2))
    with pytest.raises(BodyModelFileError, match="refused: the pickle references the global posix.system"):
        load_model_file(path)


def _smplh_like(base: BodyModelData, rng) -> BodyModelData:
    """A 52-joint SMPL-H-layout model: five 3-joint fingers under each wrist."""
    parents = list(SMPL_PARENTS[:22])
    for wrist, start in ((20, 22), (21, 37)):
        for finger in range(5):
            b = start + 3 * finger
            parents += [wrist, b, b + 1]
    V = base.num_vertices
    weights = np.zeros((V, 52))
    weights[:, :22] = base.weights[:, :22]
    for side, start in ((22, 22), (23, 37)):  # spread the hand weights over the fingers
        weights[:, start:start + 15] = base.weights[:, [side]] * rng.dirichlet(np.ones(15), size=V)
    regressor = np.zeros((52, V))
    regressor[:22] = base.J_regressor[:22]
    for side, start in ((22, 22), (23, 37)):
        for k in range(15):
            regressor[start + k] = base.J_regressor[side]
    posedirs = 1e-3 * rng.normal(size=(V, 3, 9 * 51))
    return BodyModelData(base.v_template, base.shapedirs, posedirs, regressor, weights, np.asarray(parents),
                         base.faces, name="smplh-like")


def test_smplh_reduces_to_smpl_layout_exactly_for_flat_hands(synthetic_model_data):
    rng = np.random.default_rng(0)
    smplh = _smplh_like(synthetic_model_data, rng)
    reduced = to_smpl_layout(smplh)
    assert reduced.num_joints == 24 and tuple(reduced.parents) == SMPL_PARENTS
    np.testing.assert_allclose(reduced.weights.sum(1), smplh.weights.sum(1), atol=1e-12)
    np.testing.assert_allclose(reduced.J_regressor.sum(1), 1.0, atol=1e-12)
    body_pose = random_pose(3, seed=3)
    body_pose[:, 22:] = 0.0
    full_pose = np.zeros((3, 52, 3))
    full_pose[:, :22] = body_pose[:, :22]
    betas = rng.normal(size=10)
    full = BodyModel(smplh).forward(full_pose, betas)
    small = BodyModel(reduced).forward(body_pose, betas)
    np.testing.assert_allclose(small.vertices, full.vertices, atol=1e-10)
    np.testing.assert_allclose(small.joints[:, :22], full.joints[:, :22], atol=1e-10)


def test_cli_converts_chumpy_pickle_to_plain_npz(fake_smpl_pkl, tmp_path, synthetic_model_data, capsys):
    from m3c.cli import main

    out = tmp_path / "converted" / "SMPL_NEUTRAL.npz"
    assert main(["body", "convert", str(fake_smpl_pkl), str(out)]) == 0
    _assert_same(load_model_file(out), synthetic_model_data)
    assert main(["body", "info", str(out)]) == 0
    assert "576 vertices, 24 joints, 10 shape components" in capsys.readouterr().out
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temp files left behind


def test_cli_reports_missing_file_with_exit_code_2(tmp_path, capsys):
    from m3c.cli import main

    assert main(["body", "info", str(tmp_path / "nope.pkl")]) == 2
    assert "body model file not found" in capsys.readouterr().err


def test_atomic_write_leaves_nothing_on_failure(tmp_path):
    from m3c.io import atomic_path

    target = tmp_path / "result.npz"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed mid-write")
    assert list(tmp_path.iterdir()) == []
