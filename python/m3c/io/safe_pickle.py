"""The one way M3C reads pickles it is handed (body-model .pkl, 3DPW sequence files, torch checkpoints).

A pickle is a program: every global it names is looked up and may be called. Files from strangers are read
here against exact (module, name) allow-lists: no prefix matches, no dotted names (pickle protocol 4 resolves
`a.b` by attribute lookup, which walks from any allowed object into its module's globals), and every allowed
entry maps to an object chosen here, never to whatever the file's module path resolves to. A refused file
raises UnsafePickleError naming the file and the global.

Torch checkpoints go through torch's own weights-only unpickler (torch.load(weights_only=True)), with the few
containers official checkpoints pickle besides tensors registered by exact name as plain containers.
"""

from __future__ import annotations

import codecs
import io
import os
import pickle
import re
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np


class UnsafePickleError(ValueError):
    """A pickle names a global that the kind of file it claims to be never needs; nothing of it was run."""


def _latin1_encode(text: str, encoding: str = "latin1", errors: str = "strict") -> bytes:
    """_codecs.encode as protocol-2 pickles use it (bytes written as latin1 text), limited to that codec: an
    arbitrary codec name would import an encodings module of the file's choosing."""
    if codecs.lookup(encoding).name != "iso8859-1":
        raise UnsafePickleError(f"a pickle asks _codecs.encode for codec {encoding!r}; only latin1 rebuilds bytes")
    return codecs.encode(text, "latin1", errors)


def _numpy_core(module: str):
    import importlib

    try:  # numpy 2 moved numpy.core to numpy._core
        return importlib.import_module(f"numpy._core.{module}")
    except ImportError:
        return importlib.import_module(f"numpy.core.{module}")


def _numpy_reconstruct():
    return _numpy_core("multiarray")._reconstruct


def _numpy_scalar():
    return _numpy_core("multiarray").scalar


def _numpy_frombuffer():
    return _numpy_core("numeric")._frombuffer


# Arrays, scalars and dtypes as numpy 1.x (numpy.core) and 2.x (numpy._core) write them, protocols 0-5.
NUMPY_GLOBALS: dict[tuple[str, str], Callable[[], Any]] = {
    ("numpy", "ndarray"): lambda: np.ndarray,
    ("numpy", "dtype"): lambda: np.dtype,
    **{(m, "_reconstruct"): _numpy_reconstruct for m in ("numpy.core.multiarray", "numpy._core.multiarray")},
    **{(m, "scalar"): _numpy_scalar for m in ("numpy.core.multiarray", "numpy._core.multiarray")},
    **{(m, "_frombuffer"): _numpy_frombuffer for m in ("numpy.core.numeric", "numpy._core.numeric")},
}
# Plain containers and the bytes helper of protocol-2 pickles. Python 2 names (__builtin__, copy_reg) too.
BUILTIN_GLOBALS: dict[tuple[str, str], Callable[[], Any]] = {
    **{(m, n): (lambda n=n: getattr(__import__("builtins"), n))
       for m in ("builtins", "__builtin__") for n in ("object", "set", "frozenset", "complex", "slice")},
    ("_codecs", "encode"): lambda: _latin1_encode,
    ("collections", "OrderedDict"): lambda: __import__("collections").OrderedDict,
}


def _copyreg_reconstructor():
    """copyreg._reconstructor(cls, base, state), limited to what protocol-2 pickles of plain objects use:
    cls from this allow-list (the unpickler already refused any other), base object or a builtin container."""
    import copyreg

    def reconstructor(cls, base, state):
        if base not in (object, dict, list, set):
            raise UnsafePickleError(f"a pickle rebuilds {cls!r} on base {base!r}, which a data file never needs")
        return copyreg._reconstructor(cls, base, state)

    return reconstructor


COPYREG_GLOBALS: dict[tuple[str, str], Callable[[], Any]] = {
    (m, "_reconstructor"): _copyreg_reconstructor for m in ("copyreg", "copy_reg")}


def _sparse(name: str) -> Callable[[], Any]:
    def get():
        import scipy.sparse

        return getattr(scipy.sparse, name)

    return get


# scipy.sparse matrices as old (scipy.sparse.csc) and new (scipy.sparse._csc) scipy write them.
SPARSE_GLOBALS: dict[tuple[str, str], Callable[[], Any]] = {
    (f"scipy.sparse{sep}{kind}", f"{kind}_matrix"): _sparse(f"{kind}_matrix")
    for kind in ("csc", "csr", "coo") for sep in (".", "._")}
SPARSE_GLOBALS.update({("scipy.sparse", f"{k}_matrix"): _sparse(f"{k}_matrix") for k in ("csc", "csr", "coo")})


class RestrictedUnpickler(pickle.Unpickler):
    """Resolves exactly the (module, name) pairs of `allowed` (values: factories of the object to use), and
    modules listed in `stand_ins` (module name's first component -> class) to that class; refuses the rest."""

    def __init__(self, file, allowed: Mapping[tuple[str, str], Callable[[], Any]], source: str,
                 stand_ins: Mapping[str, type] | None = None, **kwargs):
        super().__init__(file, **kwargs)
        self._allowed = allowed
        self._stand_ins = stand_ins or {}
        self._source = source

    def find_class(self, module: str, name: str):
        factory = self._allowed.get((module, name))
        if factory is not None and "." not in name:
            return factory()
        stand_in = self._stand_ins.get(module.split(".")[0])
        if stand_in is not None:  # the class is ours, whatever name the file gives
            return stand_in
        raise UnsafePickleError(
            f"{self._source}: refused: the pickle references the global {module}.{name}, which this kind of file "
            "never needs; nothing from it was run. Use a file from the original source, or convert it on a "
            "trusted machine (e.g. to .npz)")

    def persistent_load(self, pid):
        raise UnsafePickleError(f"{self._source}: refused: the pickle asks for a persistent object ({pid!r}); "
                                "this kind of file has none")


def load_restricted(data: bytes | os.PathLike | str, allowed: Mapping[tuple[str, str], Callable[[], Any]],
                    source: str | None = None, stand_ins: Mapping[str, type] | None = None,
                    encoding: str = "ASCII") -> Any:
    """Unpickles `data` (bytes, or the path of a file) resolving only the globals of `allowed`."""
    if isinstance(data, (bytes, bytearray)):
        blob, where = bytes(data), source or "pickle"
    else:
        path = Path(data)
        blob, where = path.read_bytes(), source or str(path)
    return RestrictedUnpickler(io.BytesIO(blob), allowed, where, stand_ins=stand_ins, encoding=encoding).load()


DATA_GLOBALS = {**NUMPY_GLOBALS, **BUILTIN_GLOBALS, **COPYREG_GLOBALS}


# Torch checkpoints ----------------------------------------------------------------------------------------------
# The configuration containers official checkpoints pickle next to their tensors (HMR 2.0's and VPoser v2's
# Lightning files: Lightning's hyper-parameter dict, yacs' CfgNode; older Lightning's argparse Namespace), by exact
# name. Each is rebuilt as a collections.OrderedDict, the one container torch's weights-only loader both fills
# item by item and gives attributes (BUILD): the items and the attributes come back, none of the class's code runs.
CHECKPOINT_STAND_INS = (
    "pytorch_lightning.utilities.parsing.AttributeDict",
    "lightning_fabric.utilities.data.AttributeDict",
    "lightning.fabric.utilities.data.AttributeDict",
    "yacs.config.CfgNode",
    "argparse.Namespace",
)


def _torch_safe_globals() -> list:
    from collections import OrderedDict

    import numpy.dtypes

    extra: list = [(OrderedDict, name) for name in CHECKPOINT_STAND_INS]
    # numpy arrays and scalars in checkpoint metadata, and numpy 2's DType classes (numpy.dtypes.Float32DType).
    extra += [(factory(), f"{module}.{name}") for (module, name), factory in NUMPY_GLOBALS.items()]
    extra += [(getattr(numpy.dtypes, n), f"numpy.dtypes.{n}") for n in dir(numpy.dtypes) if n.endswith("DType")]
    return extra


_GLOBAL_IN_ERROR = re.compile(r"GLOBAL ([\w.]+)|unrecognized function ([^\s]+)")


def load_torch_checkpoint(path: os.PathLike | str) -> Any:
    """torch.load(path, weights_only=True) onto the CPU, with the stand-ins above. A file that needs anything
    else raises UnsafePickleError naming the global and the file."""
    import torch

    with torch.serialization.safe_globals(_torch_safe_globals()):
        try:
            return torch.load(path, map_location="cpu", weights_only=True)
        except pickle.UnpicklingError as err:
            text = str(err)
            found = _GLOBAL_IN_ERROR.search(text)
            what = next((g for g in found.groups() if g), None) if found else None
            # torch's message: a boilerplate paragraph, then the reason
            reason = next((line.strip() for line in text.splitlines()[1:]
                           if line.strip() and not line.startswith(("Please file", "Check the documentation"))),
                          text.splitlines()[0] if text else "")
            raise UnsafePickleError(
                f"{path}: refused: the checkpoint references "
                + (f"the global {what}, which no checkpoint M3C loads needs" if what else "what a checkpoint of "
                   "tensors never needs")
                + f"; nothing from it was run (torch's weights-only loader: {reason[:300]}). Use the file from its "
                "original source, or re-save its state dict with torch.save(model.state_dict(), ...) on a "
                "trusted machine") from None


__all__ = ["BUILTIN_GLOBALS", "CHECKPOINT_STAND_INS", "COPYREG_GLOBALS", "DATA_GLOBALS", "NUMPY_GLOBALS",
           "RestrictedUnpickler", "SPARSE_GLOBALS", "UnsafePickleError", "load_restricted", "load_torch_checkpoint"]
