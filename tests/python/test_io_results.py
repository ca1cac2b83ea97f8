"""Result-file schema and reproducible .npz writing."""

import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from m3c.io.npz import save_npz_reproducible, write_npz
from m3c.io.results import ARRAYS, check_arrays, schema_markdown

OUTPUTS_PAGE = Path(__file__).resolve().parents[2] / "docs" / "outputs.md"  # the results.npz reference


def test_docs_document_the_current_schema():
    assert schema_markdown() in OUTPUTS_PAGE.read_text()


def test_check_arrays():
    arrays = {name: np.zeros(1, {"str": "<U3", "bool": bool}.get(dtype, dtype))
              for name, (_, dtype, _) in ARRAYS.items()}
    check_arrays(arrays)
    with pytest.raises(ValueError, match="missing \\['fps'\\]"):
        check_arrays({k: v for k, v in arrays.items() if k != "fps"})
    with pytest.raises(ValueError, match="extra \\['bonus'\\]"):
        check_arrays(dict(arrays, bonus=np.zeros(1)))
    with pytest.raises(ValueError, match="valid has dtype float64"):
        check_arrays(dict(arrays, valid=np.zeros(1)))


def test_npz_bytes_do_not_depend_on_time(tmp_path, monkeypatch):
    arrays = {"scalar": np.float32(2.5), "matrix": np.arange(6.0).reshape(2, 3).T, "text": np.array(["a", "bc"])}
    write_npz(tmp_path / "a.npz", arrays)
    later = time.time() + 86400.0  # a day later: any time stamp in the file would differ
    monkeypatch.setattr(time, "time", lambda: later)
    save_npz_reproducible(tmp_path / "b.npz", arrays)
    with zipfile.ZipFile(tmp_path / "stamped.zip", "w") as archive:
        archive.writestr("x", b"x")  # a member stamped with the (patched) clock
    monkeypatch.undo()
    with zipfile.ZipFile(tmp_path / "stamped.zip") as archive:  # so the patched clock did reach zipfile
        assert archive.getinfo("x").date_time[:3] == time.localtime(later)[:3]
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    loaded = np.load(tmp_path / "b.npz")
    assert loaded["scalar"].shape == () and loaded["scalar"] == np.float32(2.5)
    np.testing.assert_array_equal(loaded["matrix"], arrays["matrix"])
    np.testing.assert_array_equal(loaded["text"], arrays["text"])
    with pytest.raises(ValueError, match="dtype object"):
        write_npz(tmp_path / "c.npz", {"bad": np.array([{}], dtype=object)})
