"""The safetensors writer/reader (checked against a hand parser of the documented format) and the export of
HuMoR and VPoser weights with their manifest."""

import json
import os
import struct

import numpy as np
import pytest
import torch

from m3c.models import export as ex
from m3c.models.humor import HumorModel
from m3c.models.safetensors_io import (SafetensorsError, encode_safetensors, read_safetensors,
                                       write_safetensors)
from m3c.models.vposer import VPoserV1, VPoserV2


def parse_by_hand(blob):
    """The documented format, independently: u64 LE header size, JSON header, raw little-endian data."""
    (n,) = struct.unpack("<Q", blob[:8])
    header = json.loads(blob[8:8 + n])
    meta = header.pop("__metadata__", {})
    data = blob[8 + n:]
    kinds = {"F64": "<f8", "F32": "<f4", "F16": "<f2", "I64": "<i8", "I32": "<i4", "U8": "u1", "BOOL": "?"}
    out = {k: np.frombuffer(data[v["data_offsets"][0]:v["data_offsets"][1]], kinds[v["dtype"]]).reshape(tuple(v["shape"]))
           for k, v in header.items()}
    return n, header, out, meta


def sample_tensors():
    rng = np.random.default_rng(0)
    return {
        "b.weight": rng.normal(size=(4, 3)).astype(np.float32),
        "a.double": rng.normal(size=(2, 2, 2)),
        "c.index": np.arange(5, dtype=np.int64),
        "d.mask": np.array([True, False, True]),
        "e.half": rng.normal(size=3).astype(np.float16),
        "f.scalar": np.float64(2.5),
        "g.bigendian": np.arange(3, dtype=">f8"),
    }


def test_encoding_follows_the_format():
    tensors = sample_tensors()
    blob = encode_safetensors(tensors, {"note": "x"})
    n, header, parsed, meta = parse_by_hand(blob)
    assert n % 8 == 0 and meta == {"note": "x"}
    for k, v in tensors.items():
        np.testing.assert_array_equal(parsed[k], v)
        assert parsed[k].shape == np.shape(v)
    # The buffer is covered exactly once and every tensor is aligned to its element size.
    spans = sorted(tuple(v["data_offsets"]) for v in header.values())
    assert spans[0][0] == 0 and spans[-1][1] == len(blob) - 8 - n
    assert all(a[1] == b[0] for a, b in zip(spans, spans[1:]))
    for k, v in header.items():
        assert v["data_offsets"][0] % parsed[k].dtype.itemsize == 0
    assert header["g.bigendian"]["dtype"] == "F64"


def test_roundtrip_and_atomic_write(tmp_path, monkeypatch):
    path = tmp_path / "w.safetensors"
    tensors = sample_tensors()
    write_safetensors(path, tensors, {"k": "v"})
    back, meta = read_safetensors(path)
    assert meta == {"k": "v"} and set(back) == set(tensors)
    for k, v in tensors.items():
        np.testing.assert_array_equal(back[k], v)
    # A failure while replacing leaves the old file intact and no temporary behind.
    before = path.read_bytes()

    def failing_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", failing_replace)
    with pytest.raises(OSError, match="disk full"):
        write_safetensors(path, {"x": np.zeros(2)})
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["w.safetensors"]


def test_reader_rejects_broken_files(tmp_path):
    path = tmp_path / "bad.safetensors"
    path.write_bytes(b"\x05")
    with pytest.raises(SafetensorsError, match="too short"):
        read_safetensors(path)
    path.write_bytes(struct.pack("<Q", 1000) + b"{}")
    with pytest.raises(SafetensorsError, match="exceeds"):
        read_safetensors(path)
    header = json.dumps({"t": {"dtype": "F32", "shape": [4], "data_offsets": [0, 8]}}).encode()
    path.write_bytes(struct.pack("<Q", len(header)) + header + b"\0" * 8)
    with pytest.raises(SafetensorsError, match="do not fit shape"):
        read_safetensors(path)
    with pytest.raises(SafetensorsError, match="dtype complex128"):
        encode_safetensors({"c": np.zeros(2, dtype=complex)})
    with pytest.raises(SafetensorsError, match="no such file"):
        read_safetensors(tmp_path / "nothing.safetensors")


def test_export_from_official_files(tmp_path):
    torch.manual_seed(0)
    humor = HumorModel()
    ckpt_path = tmp_path / "best_model.pth"
    torch.save({"model": {"module." + k: v for k, v in humor.state_dict().items()}, "epoch": 1}, ckpt_path)
    vposer = VPoserV1()
    vp_path = tmp_path / "TR00_E096.pt"
    torch.save(vposer.state_dict(), vp_path)
    out = tmp_path / "export"
    assert ex.main(["--out", str(out), "--humor", str(ckpt_path), "--vposer", str(vp_path)]) == 0

    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["format"] == "m3c-weights" and manifest["format_version"] == 1
    entry = manifest["models"]["humor"]
    assert entry["networks"]["encoder"]["layers"] == [678, 1024, 1024, 1024, 1024, 96]
    assert entry["networks"]["prior"]["layers"] == [339, 1024, 1024, 1024, 1024, 96]
    assert "decoder" not in entry["networks"]
    assert entry["source"]["checkpoint"] == str(ckpt_path) and len(entry["source"]["sha256"]) == 64
    tensors, embedded = ex.read_exported(out / "humor.safetensors")
    assert embedded["networks"] == entry["networks"]
    expected = {k: v for k, v in humor.state_dict().items() if k.startswith(("encoder.", "prior_net."))}
    assert set(tensors) == set(expected)
    for k, v in expected.items():
        assert tensors[k].dtype == np.float32
        np.testing.assert_array_equal(tensors[k], v.numpy())

    vp_tensors, vp_entry = ex.read_exported(out / "vposer.safetensors")
    assert vp_entry["version"] == "v1" and vp_entry["leaky_relu_slope"] == 0.2
    assert vp_entry["encoder_ops"] == ["bn1", "fc1", "leaky_relu", "bn2", "fc2", "leaky_relu"]
    np.testing.assert_array_equal(vp_tensors["decoder.out.weight"], vposer.bodyprior_dec_out.weight.detach().numpy())
    np.testing.assert_array_equal(vp_tensors["encoder.bn1.running_var"], vposer.bodyprior_enc_bn1.running_var.numpy())
    assert not any("num_batches" in k for k in vp_tensors)
    assert len(vp_tensors) == 4 + 2 + 4 + 2 + 2 + 2 + 2 + 2 + 2


def test_export_v2_float64_merges_manifest(tmp_path):
    torch.manual_seed(1)
    out = tmp_path / "export"
    ex.export_weights(out, humor=HumorModel(), include_humor_decoder=True)
    v2 = VPoserV2()
    manifest = ex.export_weights(out, vposer=v2, dtype="float64")
    assert set(manifest["models"]) == {"humor", "vposer"}
    assert manifest["models"]["humor"]["networks"]["decoder"]["skip_dim"] == 48
    tensors, entry = ex.read_exported(out / "vposer.safetensors")
    assert entry["version"] == "v2" and entry["leaky_relu_slope"] == 0.01 and entry["dtype"] == "float64"
    assert entry["encoder_ops"][-1] == "fc3"
    np.testing.assert_array_equal(tensors["encoder.fc3.weight"], v2.encoder_net[7].weight.detach().numpy())
    np.testing.assert_array_equal(tensors["encoder.logvar.bias"], v2.encoder_net[8].logvar.bias.detach().numpy())
    assert tensors["decoder.fc1.weight"].dtype == np.float64


def test_export_errors(tmp_path, capsys):
    assert ex.main(["--out", str(tmp_path), "--humor", str(tmp_path / "missing.pth")]) == 2
    assert "missing.pth" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        ex.main(["--out", str(tmp_path)])
    with pytest.raises(ValueError, match="dtype"):
        ex.export_weights(tmp_path, humor=HumorModel(), dtype="float16")
