"""Body models in SMPL layout: file loading, the C++-backed model, joint layouts."""

from m3c.body.model import BodyModel, BodyOutput
from m3c.body.model_file import BodyModelData, BodyModelFileError, load_model_file, parse_model_arrays

__all__ = ["BodyModel", "BodyOutput", "BodyModelData", "BodyModelFileError", "load_model_file",
           "parse_model_arrays"]
