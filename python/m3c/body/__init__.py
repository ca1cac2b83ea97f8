"""Body models in SMPL layout: file loading, the C++-backed model, joint layouts, the shipped open model."""

from m3c.body.model import BodyModel, BodyOutput
from m3c.body.model_file import BodyModelData, BodyModelFileError, load_model_file, parse_model_arrays
from m3c.body.open_model import (OPEN_MODEL_NAME, default_body_model, load_body_model_data, open_body_model_data,
                                 open_body_model_path)

__all__ = ["BodyModel", "BodyOutput", "BodyModelData", "BodyModelFileError", "load_model_file",
           "parse_model_arrays", "OPEN_MODEL_NAME", "default_body_model", "load_body_model_data",
           "open_body_model_data", "open_body_model_path"]
