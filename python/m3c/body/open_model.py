"""M3C's open body model: SMPL layout (24 joints, 10 shape components), built from the CC0 MakeHuman hm08 assets
by tools/build_open_body_model.py and shipped inside the package, so M3C runs without the licensed SMPL files.

It has the same kinematic tree, joint order and names and the same T rest pose conventions as SMPL (y up, facing
+z, pelvis at the origin), so SMPL pose parameters drive it; its shape space and mesh (13380 vertices) are its
own, and it has no pose blend shapes. See data/m3c_open_body.md.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from m3c.body.model_file import BodyModelData, load_model_file

OPEN_MODEL_NAME = "m3c-open-hm08"
OPEN_MODEL_FILE = "m3c_open_body.npz"


def open_body_model_path() -> Path:
    """Path of the shipped model file (python/m3c/body/data/m3c_open_body.npz)."""
    path = Path(str(resources.files("m3c.body") / "data" / OPEN_MODEL_FILE))
    if not path.is_file():
        raise FileNotFoundError(
            f"M3C's open body model is missing from the installation ({path}); reinstall m3c, or rebuild it with "
            "python tools/build_open_body_model.py <MakeHuman hm08 assets>"
        )
    return path


def open_body_model_data(num_betas: int | None = 10) -> BodyModelData:
    """The open model's arrays (float64), named OPEN_MODEL_NAME."""
    return load_model_file(open_body_model_path(), num_betas=num_betas)


def load_body_model_data(path: str | Path | None = None, num_betas: int | None = 10,
                         smpl_layout: bool = True) -> BodyModelData:
    """The configured body model: the file at `path` (SMPL/SMPL-H/SMPL-X .pkl/.npz or an M3C model file), or the
    open model when no file is configured (path None). BodyModelData.name records which model it is;
    smpl_layout reduces SMPL-H/SMPL-X to SMPL's 24 joints."""
    if path is None:
        return open_body_model_data(num_betas=num_betas)
    from m3c.body.layouts import to_smpl_layout

    data = load_model_file(path, num_betas=num_betas)
    return to_smpl_layout(data) if smpl_layout else data


def default_body_model(path: str | Path | None = None, num_betas: int | None = 10):
    """A BodyModel (C++ core) of the configured file, or of the open model when path is None."""
    from m3c.body.model import BodyModel

    return BodyModel(load_body_model_data(path, num_betas=num_betas))
