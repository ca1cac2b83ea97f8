"""Reproducible .npz files: the same arrays always give the same bytes.

np.savez stamps every member with the current time, so two runs that compute identical arrays write different
files. These writers fix the zip timestamps and the member order, which lets a resumed run be compared byte for
byte with an uninterrupted one, and lets a cache entry's digest identify its content.
"""

from __future__ import annotations

import zipfile
from pathlib import Path

import numpy as np

from m3c.io.atomic import atomic_path

_EPOCH = (1980, 1, 1, 0, 0, 0)  # the earliest time a zip header can hold


def write_npz(path: str | Path, arrays: dict, compress: bool = False) -> None:
    """Writes `arrays` (name -> array) to `path` (not atomically; see save_npz_reproducible). Members are written
    in the dict's order, as `<name>.npy`, readable by np.load. Object arrays are refused (np.load would need
    allow_pickle to read them back)."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=method, allowZip64=True) as archive:
        for name, value in arrays.items():
            array = np.asanyarray(value)
            if array.dtype.hasobject:
                raise ValueError(f"array {name!r} has dtype object; store numbers or fixed-width strings")
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH)
            info.compress_type = method
            info.external_attr = 0o644 << 16
            with archive.open(info, "w", force_zip64=True) as member:
                # (np.ascontiguousarray would turn a 0-d array into a 1-d one)
                np.lib.format.write_array(member, np.asarray(array, order="C"), allow_pickle=False)


def save_npz_reproducible(path: str | Path, arrays: dict, compress: bool = False) -> None:
    """write_npz through a temporary file renamed over `path`: readers see the old file or the complete new one."""
    with atomic_path(path, suffix=".npz") as tmp:
        write_npz(tmp, arrays, compress=compress)
