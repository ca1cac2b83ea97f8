"""Reading SMPL-layout body model files: official SMPL/SMPL-H/SMPL-X .pkl (without chumpy) and .npz, and
M3C's own model files (same keys, .npz). Everything is returned as plain float64/int numpy arrays."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from m3c.body.joint_names import SMPL_PARENTS
from m3c.io import safe_pickle

OBTAIN_HINT = (
    "SMPL model files are licensed and cannot ship with M3C: register at https://smpl.is.tue.mpg.de and "
    "pass the downloaded SMPL_NEUTRAL.pkl / .npz, or use M3C's open body model (no file needed)."
)
REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")
# M3C's own model files carry this key (format version). In them, an absent 'posedirs' means no pose blend
# shapes (zeros), and 'model_name' names the model. Files without it (SMPL's) must have every required key.
M3C_FORMAT_KEY = "m3c_model_format"
M3C_FORMAT_VERSION = 1


class BodyModelFileError(ValueError):
    """A body model file is missing keys or holds arrays of inconsistent shapes."""


@dataclass(frozen=True)
class BodyModelData:
    """SMPL-layout arrays. V vertices, J joints, B shape components.

    v_template: V x 3; shapedirs: V x 3 x B; posedirs: V x 3 x 9(J-1); J_regressor: J x V (dense);
    weights: V x J; parents: J (parents[0] = -1); faces: F x 3.
    """

    v_template: np.ndarray
    shapedirs: np.ndarray
    posedirs: np.ndarray
    J_regressor: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    faces: np.ndarray
    name: str = "unnamed"
    gender: str = "neutral"
    # Named vertex ids for keypoints that are not joints (nose, eyes, ears, toes, heels), when the file has them.
    keypoint_vertex_ids: dict = field(default_factory=dict)

    @property
    def num_vertices(self) -> int:
        return self.v_template.shape[0]

    @property
    def num_joints(self) -> int:
        return self.parents.shape[0]

    @property
    def num_betas(self) -> int:
        return self.shapedirs.shape[2]


class _ChumpyStandIn:
    """Takes the place of chumpy.Ch objects while unpickling; chumpy keeps the array in state['x']."""

    def __init__(self, *args, **kwargs):
        self._state = None

    def __setstate__(self, state):
        self._state = state

    def to_array(self) -> np.ndarray:
        state = self._state
        if isinstance(state, dict) and "x" in state:
            return np.asarray(state["x"])
        raise BodyModelFileError("a chumpy object in the file holds no array (no 'x' in its state)")


# What a body-model pickle needs: numpy arrays, scipy.sparse matrices (SMPL's J_regressor), plain containers;
# chumpy objects (SMPL's .pkl pickles chumpy.Ch) become inert stand-ins (m3c.io.safe_pickle).
_MODEL_GLOBALS = {**safe_pickle.DATA_GLOBALS, **safe_pickle.SPARSE_GLOBALS}


def _to_dense(value, key: str) -> np.ndarray:
    if isinstance(value, _ChumpyStandIn):
        value = value.to_array()
    if hasattr(value, "toarray"):  # scipy.sparse
        value = value.toarray()
    try:
        return np.asarray(value)
    except Exception as err:  # pragma: no cover - defensive: an unexpected object type
        raise BodyModelFileError(f"key '{key}' is not an array ({type(value).__name__})") from err


def _read_raw(path: Path) -> dict:
    suffix = path.suffix.lower()
    if suffix == ".pkl":
        try:
            raw = safe_pickle.load_restricted(path, _MODEL_GLOBALS, source=f"body model {path}",
                                              stand_ins={"chumpy": _ChumpyStandIn}, encoding="latin1")
        except safe_pickle.UnsafePickleError as err:
            raise BodyModelFileError(str(err)) from None
        except Exception as err:
            raise BodyModelFileError(f"{path} is not a readable body model pickle: {err}") from err
        if not isinstance(raw, dict):
            raise BodyModelFileError(f"{path} holds a {type(raw).__name__}, expected a dict of model arrays")
        return raw
    if suffix == ".npz":
        try:
            archive = np.load(path, allow_pickle=False)
        except Exception as err:
            raise BodyModelFileError(f"{path} is not a readable .npz file: {err}") from err
        raw = {}
        for key in archive.files:
            try:
                raw[key] = archive[key]
            except ValueError:
                continue  # object arrays (names, metadata) are not needed and are never unpickled
        return raw
    raise BodyModelFileError(f"{path}: unknown body model format '{suffix}', expected .pkl or .npz")


def _vertex_major(array: np.ndarray, key: str, num_vertices: int, columns: int | None) -> np.ndarray:
    """Brings shapedirs/posedirs to (V, 3, C) from (V, 3, C), (3V, C) or (C, 3V)."""
    if array.ndim == 3 and array.shape[:2] == (num_vertices, 3):
        out = array
    elif array.ndim == 2 and array.shape[0] == 3 * num_vertices:
        out = array.reshape(num_vertices, 3, -1)
    elif array.ndim == 2 and array.shape[1] == 3 * num_vertices:
        out = array.T.reshape(num_vertices, 3, -1)
    else:
        raise BodyModelFileError(
            f"'{key}' has shape {array.shape}; expected ({num_vertices}, 3, C), ({3 * num_vertices}, C) "
            f"or (C, {3 * num_vertices})"
        )
    if columns is not None and out.shape[2] != columns:
        raise BodyModelFileError(f"'{key}' has {out.shape[2]} components, expected {columns}")
    return out


def parse_model_arrays(raw: dict, num_betas: int | None = 10, name: str = "unnamed") -> BodyModelData:
    """Validates and normalises a dict of SMPL-layout arrays (file keys) into BodyModelData."""
    m3c_file = M3C_FORMAT_KEY in raw
    if m3c_file:
        version = int(np.asarray(raw[M3C_FORMAT_KEY]))
        if version > M3C_FORMAT_VERSION:
            raise BodyModelFileError(f"{name}: M3C model format {version} is newer than this M3C reads "
                                     f"({M3C_FORMAT_VERSION}); update M3C")
        if "model_name" in raw:
            name = str(np.asarray(raw["model_name"]))
    missing = [k for k in REQUIRED_KEYS if k not in raw and not (m3c_file and k == "posedirs")]
    if missing:
        raise BodyModelFileError(
            f"{name}: missing keys {missing}; a SMPL-layout model needs {list(REQUIRED_KEYS)}, found {sorted(raw)}"
        )
    v_template = _to_dense(raw["v_template"], "v_template").astype(np.float64)
    if v_template.ndim != 2 or v_template.shape[1] != 3 or v_template.shape[0] < 1:
        raise BodyModelFileError(f"{name}: 'v_template' must be (V, 3), got {v_template.shape}")
    V = v_template.shape[0]
    kintree = _to_dense(raw["kintree_table"], "kintree_table")
    if kintree.ndim != 2 or kintree.shape[0] != 2:
        raise BodyModelFileError(f"{name}: 'kintree_table' must be (2, J), got {kintree.shape}")
    parents = kintree[0].astype(np.int64)
    parents[0] = -1  # files store 2**32 - 1 for the root
    J = parents.shape[0]
    if np.any(parents[1:] < 0) or np.any(parents[1:] >= np.arange(1, J)):
        raise BodyModelFileError(f"{name}: kintree_table parents must come before their children: {parents}")

    shapedirs = _vertex_major(_to_dense(raw["shapedirs"], "shapedirs"), "shapedirs", V, None).astype(np.float64)
    if num_betas is not None:
        if num_betas > shapedirs.shape[2]:
            raise BodyModelFileError(
                f"{name}: asked for {num_betas} shape components, the file has {shapedirs.shape[2]}"
            )
        shapedirs = shapedirs[:, :, :num_betas]
    if "posedirs" in raw:
        posedirs = _vertex_major(_to_dense(raw["posedirs"], "posedirs"), "posedirs", V, 9 * (J - 1))
        posedirs = posedirs.astype(np.float64)
    else:  # only M3C files get here: no pose blend shapes
        posedirs = np.zeros((V, 3, 9 * (J - 1)))
    J_regressor = _to_dense(raw["J_regressor"], "J_regressor").astype(np.float64)
    if J_regressor.shape != (J, V):
        raise BodyModelFileError(f"{name}: 'J_regressor' must be ({J}, {V}), got {J_regressor.shape}")
    weights = _to_dense(raw["weights"], "weights").astype(np.float64)
    if weights.shape != (V, J):
        raise BodyModelFileError(f"{name}: 'weights' must be ({V}, {J}), got {weights.shape}")
    faces = _to_dense(raw["f"], "f").astype(np.int64)
    if faces.size and (faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or faces.max() >= V):
        raise BodyModelFileError(f"{name}: 'f' must be (F, 3) vertex indices below {V}, got {faces.shape}")
    for key, arr in (("v_template", v_template), ("shapedirs", shapedirs), ("posedirs", posedirs),
                     ("J_regressor", J_regressor), ("weights", weights)):
        if not np.all(np.isfinite(arr)):
            raise BodyModelFileError(f"{name}: '{key}' contains NaN or Inf")

    keypoint_ids = {}
    if "keypoint_names" in raw and "keypoint_vertex_ids" in raw:
        names = [str(n) for n in np.asarray(raw["keypoint_names"]).reshape(-1).tolist()]
        ids = np.asarray(raw["keypoint_vertex_ids"])
        integers = ids.dtype.kind in "iu" and ids.shape == (len(names),)
        if not integers or (ids.size and (ids.min() < 0 or ids.max() >= V)):
            got = f"values {ids.min()}..{ids.max()}" if integers else f"dtype {ids.dtype}, shape {ids.shape}"
            raise BodyModelFileError(f"{name}: 'keypoint_vertex_ids' must be {len(names)} integer vertex indices "
                                     f"(one per keypoint name) in [0, {V}), got {got}")
        keypoint_ids = dict(zip(names, ids.astype(int).tolist()))
    gender = str(np.asarray(raw["gender"])) if "gender" in raw else "neutral"
    return BodyModelData(v_template, shapedirs, posedirs, J_regressor, weights, parents,
                         faces.astype(np.int32), name=name, gender=gender, keypoint_vertex_ids=keypoint_ids)


def load_model_file(path: str | Path, num_betas: int | None = 10) -> BodyModelData:
    """Loads a SMPL-layout model file (.pkl or .npz). num_betas keeps the first shape components (None: all)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"body model file not found: {path}. {OBTAIN_HINT}")
    raw = _read_raw(path)
    data = parse_model_arrays(raw, num_betas=num_betas, name=path.name)
    if data.num_joints == 24 and tuple(data.parents.tolist()) != SMPL_PARENTS:
        raise BodyModelFileError(f"{path.name}: 24 joints but not SMPL's kinematic tree: {data.parents.tolist()}")
    return data
