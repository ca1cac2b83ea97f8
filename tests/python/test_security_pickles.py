"""Files from strangers run no code: crafted pickles against every loader M3C points at a user's file (body
models, 3DPW sequences, torch checkpoints), and a cache entry whose file name leaves its folder.

Each crafted file would create a marker file if any of it ran; the tests assert the loader refuses it with a
message naming the global, and that no marker appears."""

from __future__ import annotations

import io
import json
import pickle
import struct
import zipfile

import numpy as np
import pytest
import torch

from m3c.body.model_file import BodyModelFileError, load_model_file
from m3c.eval.datasets.threedpw import read_sequence
from m3c.io import safe_pickle
from m3c.models.checkpoint import CheckpointError, CheckpointSource, read_checkpoint
from pickled_names import importable, named_class

SOURCE = CheckpointSource("test network", "net.pth", "made by the test.")


# Hand-assembled pickles ------------------------------------------------------------------------------------------
def _str_op(text: str, protocol: int) -> bytes:
    data = text.encode()
    if protocol >= 4:
        return b"\x8c" + bytes([len(data)]) + data  # SHORT_BINUNICODE
    return b"X" + struct.pack("<I", len(data)) + data  # BINUNICODE


def call_pickle(module: str, name: str, args: tuple[str, ...], protocol: int) -> bytes:
    """A pickle that looks up module.name and calls it with string args (GLOBAL for protocols 0-3, STACK_GLOBAL
    for 4-5), wrapped in a dict as a model file would be."""
    head = b"\x80" + bytes([protocol]) if protocol >= 2 else b""
    if protocol <= 3:
        fetch = b"c" + module.encode() + b"\n" + name.encode() + b"\n"
    else:
        fetch = _str_op(module, protocol) + _str_op(name, protocol) + b"\x93"
    if protocol == 0:
        call_args = b"(" + b"".join(b"V" + a.encode() + b"\n" for a in args) + b"t"
    else:
        call_args = b"(" + b"".join(_str_op(a, protocol) for a in args) + b"t"
    key = _str_op("v_template", max(protocol, 1)) if protocol else b"Vv_template\n"
    body = b"(" + key + fetch + call_args + b"R" + b"d"  # MARK key value DICT
    return head + body + b"."


def marker_command(tmp_path) -> str:
    return f"touch {tmp_path / 'MARKER'}"


def attacks(tmp_path) -> list[tuple[str, str, tuple[str, ...]]]:
    cmd = marker_command(tmp_path)
    return [
        ("os", "system", (cmd,)),
        ("posix", "system", (cmd,)),
        ("numpy.lib._datasource", "os.system", (cmd,)),  # the dotted name of the report
        ("numpy", "lib._datasource.os.system", (cmd,)),
        ("numpy.core.multiarray", "_reconstruct.__globals__.get", ("x",)),
        ("numpyevil", "system", (cmd,)),  # prefix tricks
        ("numpy.testing", "run_module_suite", (cmd,)),
        ("scipy.sparse", "csc_matrix.__init__.__globals__", (cmd,)),
        ("scipy.sparse._sputils", "check_shape", (cmd,)),
        ("builtins", "eval", (f"__import__('os').system({cmd!r})",)),
        ("__builtin__", "exec", (f"__import__('os').system({cmd!r})",)),
        ("copyreg", "_reconstructor.__globals__", (cmd,)),
        ("torch._utils", "_rebuild_tensor.__builtins__.get", ("eval",)),
        ("torch._utils", "_rebuild_evil", (cmd,)),
        ("subprocess", "getoutput", (cmd,)),
    ]


PROTOCOLS = range(6)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_crafted_pickles_are_valid_pickles(tmp_path, protocol):
    """The crafted files are real pickles: the stdlib's unpickler (which trusts them) does run them, so a
    loader that refuses them refuses an attack, not a malformed file."""
    cmd = marker_command(tmp_path)
    pickle.loads(call_pickle("os", "system", (cmd,), protocol))
    assert (tmp_path / "MARKER").exists()


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_body_model_pickles_run_no_code(tmp_path, protocol):
    for k, (module, name, args) in enumerate(attacks(tmp_path)):
        path = tmp_path / f"evil{k}.pkl"
        path.write_bytes(call_pickle(module, name, args, protocol))
        with pytest.raises(BodyModelFileError, match="refused") as err:
            load_model_file(path)
        assert f"{module}.{name}" in str(err.value) and str(path) in str(err.value)
    assert not (tmp_path / "MARKER").exists()


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_3dpw_pickles_run_no_code(tmp_path, protocol):
    for k, (module, name, args) in enumerate(attacks(tmp_path)):
        path = tmp_path / f"evil{k}.pkl"
        path.write_bytes(call_pickle(module, name, args, protocol))
        with pytest.raises(ValueError, match="refused") as err:
            read_sequence(path)
        assert f"{module}.{name}" in str(err.value)
    assert not (tmp_path / "MARKER").exists()


def test_body_model_cli_runs_no_code(tmp_path):
    """The report's reproduction: `m3c body info FILE` with a 74-byte protocol-4 pickle."""
    from m3c.cli import main

    path = tmp_path / "model.pkl"
    path.write_bytes(call_pickle("numpy.lib._datasource", "os.system", (marker_command(tmp_path),), 4))
    assert main(["body", "info", str(path)]) != 0
    assert not (tmp_path / "MARKER").exists()


def test_allowed_callables_cannot_be_turned(tmp_path):
    """REDUCE on callables that are allowed: the bytes helper takes only latin1 (another codec name imports an
    encodings module of the file's choosing); copyreg's reconstructor only plain bases."""
    blob = call_pickle("_codecs", "encode", ("abc", "rot13"), 2)
    with pytest.raises(safe_pickle.UnsafePickleError, match="codec"):
        safe_pickle.load_restricted(blob, safe_pickle.DATA_GLOBALS)
    ok = call_pickle("_codecs", "encode", ("abc", "latin1"), 2)
    assert safe_pickle.load_restricted(ok, safe_pickle.DATA_GLOBALS) == {"v_template": b"abc"}


def test_persistent_ids_are_refused():
    class P(pickle.Pickler):
        def persistent_id(self, obj):
            return "x" if obj == "external" else None

    buffer = io.BytesIO()
    P(buffer, protocol=2).dump({"a": "external"})
    with pytest.raises(safe_pickle.UnsafePickleError, match="persistent"):
        safe_pickle.load_restricted(buffer.getvalue(), safe_pickle.DATA_GLOBALS)


@pytest.mark.parametrize("protocol", PROTOCOLS)
def test_data_pickles_still_load(protocol):
    """What the files really hold round-trips under every protocol: arrays (float, int, str, 0-d, strided,
    Fortran order), numpy scalars, dtypes, sets, complex numbers, bytes."""
    value = {"a": np.arange(12.0).reshape(3, 4)[:, ::2], "b": np.asfortranarray(np.ones((2, 3), np.int32)),
             "c": np.array(["ab", "cd"]), "d": np.float32(1.5), "e": np.array(3), "f": {1, 2}, "g": 1 + 2j,
             "h": b"\x00\xff", "i": [np.dtype("<f4")], "j": frozenset({"x"})}
    out = safe_pickle.load_restricted(pickle.dumps(value, protocol=protocol), safe_pickle.DATA_GLOBALS)
    assert out.keys() == value.keys()
    for key in value:
        if isinstance(value[key], np.ndarray):
            np.testing.assert_array_equal(out[key], value[key])
            assert out[key].dtype == value[key].dtype
        else:
            assert out[key] == value[key]


def test_protocol5_out_of_band_free_arrays_load():
    """Protocol 5 with in-band buffers (what pickle.dumps writes) rebuilds arrays through numpy's _frombuffer."""
    value = np.arange(5.0)
    blob = pickle.dumps(value, protocol=5)
    np.testing.assert_array_equal(safe_pickle.load_restricted(blob, safe_pickle.DATA_GLOBALS), value)


# Torch checkpoints ----------------------------------------------------------------------------------------------
def _replace_data_pkl(path, blob: bytes) -> None:
    """Rewrites the data.pkl member of a torch zip checkpoint (the nested pickle torch.load reads)."""
    with zipfile.ZipFile(path) as zin:
        members = [(info, zin.read(info.filename)) for info in zin.infolist()]
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zout:
        for info, data in members:
            zout.writestr(info, blob if info.filename.endswith("/data.pkl") else data)


@pytest.mark.parametrize("protocol", [2, 4])
def test_zip_checkpoint_with_crafted_data_pkl_runs_no_code(tmp_path, protocol):
    for k, (module, name, args) in enumerate(attacks(tmp_path)):
        path = tmp_path / f"evil{k}.pth"
        torch.save({"w": torch.zeros(2)}, path)
        _replace_data_pkl(path, call_pickle(module, name, args, protocol))
        # torch's weights-only loader refuses the global (protocol 2) or the protocol itself (4)
        with pytest.raises(CheckpointError, match="refused|not a readable torch checkpoint") as err:
            read_checkpoint(path, SOURCE)
        assert str(path) in str(err.value)
    assert not (tmp_path / "MARKER").exists()


class _Evil:
    def __init__(self, cmd):
        self.cmd = cmd

    def __reduce__(self):
        import os

        return (os.system, (self.cmd,))


@pytest.mark.parametrize("legacy", [False, True])
def test_checkpoint_with_pickled_object_runs_no_code(tmp_path, legacy):
    """A checkpoint (zip or the legacy format) with an object whose reduce calls os.system among its tensors,
    as a file named like WHAM's would be picked up by `m3c run --checkpoints DIR`."""
    path = tmp_path / "wham_vit_w_3dpw.pth.tar"
    torch.save({"model": {"w": torch.ones(3)}, "extra": _Evil(marker_command(tmp_path))}, path,
               _use_new_zipfile_serialization=not legacy)
    with pytest.raises(CheckpointError, match="refused.*(posix|os).system"):
        read_checkpoint(path, SOURCE)
    assert not (tmp_path / "MARKER").exists()


@pytest.mark.parametrize("qualified", safe_pickle.CHECKPOINT_STAND_INS)
def test_official_config_containers_load_inert(tmp_path, qualified):
    """Lightning / yacs / argparse containers next to the tensors (HMR 2.0, VPoser v2 files) load as plain
    containers holding their items (or attributes), nested too; the tensors come back exactly."""
    cls = named_class(qualified)
    path = tmp_path / "ckpt.ckpt"
    with importable(cls):
        config = cls(lr=0.1, name="x", inner=cls(depth=3))
        torch.save({"state_dict": {"w": torch.arange(4.0)}, "hyper_parameters": {"cfg": config}}, path)
    out = read_checkpoint(path, SOURCE)
    torch.testing.assert_close(out["state_dict"]["w"], torch.arange(4.0))
    cfg = out["hyper_parameters"]["cfg"]
    assert type(cfg).__module__ == "collections"  # a plain container, not the file's class
    items = dict(cfg) or {k: v for k, v in vars(cfg).items() if not k.startswith("__")}
    inner = items.pop("inner")
    assert items == {"lr": 0.1, "name": "x"}
    assert (dict(inner) or {k: v for k, v in vars(inner).items() if not k.startswith("__")}) == {"depth": 3}


def test_checkpoint_with_numpy_metadata_loads(tmp_path):
    path = tmp_path / "meta.pth"
    torch.save({"state_dict": {"w": torch.ones(2)}, "meta": {"mean": np.arange(3.0), "n": np.int64(4)}}, path)
    out = read_checkpoint(path, SOURCE)
    np.testing.assert_array_equal(out["meta"]["mean"], np.arange(3.0))
    assert out["meta"]["n"] == 4


def test_unknown_class_in_checkpoint_named(tmp_path):
    cls = named_class("somepackage.config.TrainingConfig")
    path = tmp_path / "other.pth"
    with importable(cls):
        torch.save({"state_dict": {"w": torch.ones(2)}, "cfg": cls(a=1)}, path)
    with pytest.raises(CheckpointError, match="somepackage.config.TrainingConfig"):
        read_checkpoint(path, SOURCE)


# The pipeline cache ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["../../../outside.txt", "/etc/passwd", "sub/../../x", "link/secret"])
def test_cache_entry_file_outside_its_folder_is_refused(tmp_path, name):
    from m3c.pipeline.cache import Cache
    from m3c.pipeline.node import PipelineError

    (tmp_path / "outside.txt").write_text("secret")
    cache = Cache(tmp_path / "cache")
    writer = cache.writer("node", "key")
    writer.commit({"x": 1}, {}, "node")
    entry = cache.entry("node", "key")
    (entry / "files").mkdir(exist_ok=True)
    (entry / "files" / "link").symlink_to(tmp_path)
    (entry / "outputs.json").write_text(json.dumps({"video": {"__file__": name}}))
    with pytest.raises(PipelineError, match="outside its files/ folder|not a relative path"):
        cache.load("node", "key")


def test_cache_entry_file_inside_loads(tmp_path):
    from m3c.pipeline.cache import Cache

    cache = Cache(tmp_path / "cache")
    cache.writer("node", "key").commit({"x": 1}, {}, "node")
    entry = cache.entry("node", "key")
    (entry / "files" / "sub").mkdir(parents=True, exist_ok=True)
    (entry / "files" / "sub" / "a.mp4").write_bytes(b"x")
    (entry / "outputs.json").write_text(json.dumps({"video": {"__file__": "sub/a.mp4"}}))
    assert cache.load("node", "key")["video"].path == str(entry / "files" / "sub" / "a.mp4")


def test_writing_a_file_under_an_existing_modules_name_leaves_the_module_as_it_was():
    """The tests' helper that pickles argparse.Namespace under its name must give argparse its own class back."""
    import argparse

    real = argparse.Namespace
    with importable(named_class("argparse.Namespace")) as fake:
        assert argparse.Namespace is fake
    assert argparse.Namespace is real and argparse.ArgumentParser().parse_args([]) == real()


def test_manifest_naming_a_file_outside_its_folder_is_not_followed(tmp_path):
    """A result folder's manifest.json lists its own files; an edited one naming a path outside is reported
    (and the file there is never read), like a cache entry's."""
    import hashlib

    from m3c.io.manifest import folder_state, seal

    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "results.json").write_text("{}")
    seal(folder, ["results.json"])
    assert folder_state(folder).complete
    secret = tmp_path / "secret.txt"
    secret.write_text("x")
    manifest = json.loads((folder / "manifest.json").read_text())
    for name in ("../secret.txt", str(secret)):
        entry = {"size": 1, "sha256": hashlib.sha256(b"x").hexdigest(), "node": None, "key": None}
        (folder / "manifest.json").write_text(json.dumps({**manifest, "files": {name: entry}}))
        state = folder_state(folder)
        assert state.status == "modified" and "not a file of this folder" in state.message
