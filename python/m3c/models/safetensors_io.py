"""The safetensors file format, read and written with numpy (no extra dependency).

Layout (https://huggingface.co/docs/safetensors): an unsigned 64-bit little-endian header length N; N bytes
of UTF-8 JSON mapping each tensor name to {"dtype", "shape", "data_offsets": [begin, end]} (offsets into
the data buffer that follows) plus an optional "__metadata__" of string -> string; then the raw little-endian,
C-order data. Writers here pad the header with spaces to a multiple of 8 and order tensors by decreasing
element size, so every tensor starts aligned to its element size.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path
from typing import Mapping

import numpy as np

from m3c.io import atomic_path

_DTYPES = {
    "F64": np.dtype("<f8"), "F32": np.dtype("<f4"), "F16": np.dtype("<f2"),
    "I64": np.dtype("<i8"), "I32": np.dtype("<i4"), "I16": np.dtype("<i2"), "I8": np.dtype("i1"),
    "U8": np.dtype("u1"), "BOOL": np.dtype("?"),
}
_LABELS = {("f", 8): "F64", ("f", 4): "F32", ("f", 2): "F16", ("i", 8): "I64", ("i", 4): "I32",
           ("i", 2): "I16", ("i", 1): "I8", ("u", 1): "U8", ("b", 1): "BOOL"}
_MAX_HEADER = 100 * 1024 * 1024


class SafetensorsError(ValueError):
    """A file that is not valid safetensors, or tensors that cannot be stored."""


def _dtype_label(array: np.ndarray, name: str) -> str:
    label = _LABELS.get((array.dtype.kind, array.dtype.itemsize))
    if label is None:
        raise SafetensorsError(f"tensor '{name}' has dtype {array.dtype}, which is not stored here "
                               f"(use one of {', '.join(_DTYPES)})")
    return label


def write_atomic(path: str | os.PathLike, payload: bytes) -> None:
    """Writes bytes to `path` through a temporary file in the same folder and a rename: readers see the old
    file or the new one, never half of one."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(payload)


def encode_safetensors(tensors: Mapping[str, np.ndarray], metadata: Mapping[str, str] | None = None) -> bytes:
    """The bytes of a safetensors file holding `tensors` (name -> array) and string `metadata`."""
    arrays = {}
    for name, value in tensors.items():
        if not isinstance(name, str) or not name or name == "__metadata__":
            raise SafetensorsError(f"invalid tensor name {name!r}")
        array = np.asarray(value)  # (ascontiguousarray would turn 0-d into 1-d; tobytes copies C-order)
        arrays[name] = (array, _dtype_label(array, name))
    order = sorted(arrays, key=lambda k: (-arrays[k][0].dtype.itemsize, k))
    header: dict = {}
    if metadata:
        bad = [k for k, v in metadata.items() if not isinstance(k, str) or not isinstance(v, str)]
        if bad:
            raise SafetensorsError(f"metadata must map strings to strings; offending keys: {bad}")
        header["__metadata__"] = dict(metadata)
    offset = 0
    chunks = []
    for name in order:
        array, label = arrays[name]
        data = array.astype(_DTYPES[label], copy=False).tobytes(order="C")
        header[name] = {"dtype": label, "shape": list(array.shape), "data_offsets": [offset, offset + len(data)]}
        chunks.append(data)
        offset += len(data)
    text = json.dumps(header, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 8)
    return struct.pack("<Q", len(text)) + text + b"".join(chunks)


def write_safetensors(path: str | os.PathLike, tensors: Mapping[str, np.ndarray],
                      metadata: Mapping[str, str] | None = None) -> None:
    """Writes a safetensors file atomically."""
    write_atomic(path, encode_safetensors(tensors, metadata))


def read_safetensors(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict[str, str]]:
    """(tensors, metadata) of a safetensors file; the arrays are native-endian copies."""
    path = Path(path)
    try:
        blob = path.read_bytes()
    except FileNotFoundError:
        raise SafetensorsError(f"{path}: no such file") from None
    if len(blob) < 8:
        raise SafetensorsError(f"{path}: too short for a safetensors file ({len(blob)} bytes)")
    (size,) = struct.unpack("<Q", blob[:8])
    if size > min(_MAX_HEADER, len(blob) - 8):
        raise SafetensorsError(f"{path}: header length {size} exceeds the file")
    try:
        header = json.loads(blob[8:8 + size].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise SafetensorsError(f"{path}: header is not JSON ({err})") from err
    if not isinstance(header, dict):
        raise SafetensorsError(f"{path}: header is not a JSON object")
    metadata = header.pop("__metadata__", None) or {}
    data = memoryview(blob)[8 + size:]
    tensors = {}
    for name, info in header.items():
        try:
            dtype = _DTYPES[info["dtype"]]
            shape = tuple(int(s) for s in info["shape"])
            begin, end = (int(v) for v in info["data_offsets"])
        except (KeyError, TypeError, ValueError) as err:
            raise SafetensorsError(f"{path}: bad entry for tensor '{name}': {info!r}") from err
        count = int(np.prod(shape, dtype=np.int64))
        if not 0 <= begin <= end <= len(data) or end - begin != count * dtype.itemsize:
            raise SafetensorsError(f"{path}: tensor '{name}' offsets {begin}..{end} do not fit shape {shape} "
                                   f"{info['dtype']} in a {len(data)}-byte buffer")
        tensors[name] = np.frombuffer(data[begin:end], dtype=dtype).reshape(shape).astype(dtype.newbyteorder("="))
    return tensors, dict(metadata)


__all__ = ["SafetensorsError", "encode_safetensors", "read_safetensors", "write_atomic", "write_safetensors"]
