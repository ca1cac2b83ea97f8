"""Export of the weights the C++ optimizer evaluates (cpp/nn): HuMoR's posterior encoder and conditional prior,
VPoser's decoder and encoder, as safetensors files plus a JSON manifest.

    python -m m3c.models.export --out DIR [--humor CKPT] [--vposer PATH [--vposer-version v1|v2]]
                                [--dtype float32|float64] [--humor-decoder]

DIR receives humor.safetensors, vposer.safetensors and manifest.json (merged with an existing one). Every
.safetensors file also carries its own manifest entry as JSON in its metadata under "m3c", so the C++ side
needs only that file. HuMoR keeps its official tensor names (encoder.net.0.weight, prior_net.net.*);
VPoser v1 and v2 are renamed to one layout (encoder.bn1/fc1/bn2/fc2[/fc3]/mu/logvar, decoder.fc1/fc2/out)
with the differences stated in the entry. All files are written atomically.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from pathlib import Path

import numpy as np
import torch

from m3c import __version__
from m3c.io.manifest import file_sha256
from m3c.models import humor as humor_module
from m3c.models import humor_state as hs
from m3c.models import vposer as vposer_module
from m3c.models.checkpoint import CheckpointError
from m3c.models.safetensors_io import encode_safetensors, read_safetensors, write_atomic

FORMAT = "m3c-weights"
FORMAT_VERSION = 1
MANIFEST = "manifest.json"

_VPOSER_V1_NAMES = {
    "bodyprior_enc_bn1": "encoder.bn1", "bodyprior_enc_fc1": "encoder.fc1", "bodyprior_enc_bn2": "encoder.bn2",
    "bodyprior_enc_fc2": "encoder.fc2", "bodyprior_enc_mu": "encoder.mu", "bodyprior_enc_logvar": "encoder.logvar",
    "bodyprior_dec_fc1": "decoder.fc1", "bodyprior_dec_fc2": "decoder.fc2", "bodyprior_dec_out": "decoder.out",
}
_VPOSER_V2_NAMES = {
    "encoder_net.1": "encoder.bn1", "encoder_net.2": "encoder.fc1", "encoder_net.4": "encoder.bn2",
    "encoder_net.6": "encoder.fc2", "encoder_net.7": "encoder.fc3", "encoder_net.8.mu": "encoder.mu",
    "encoder_net.8.logvar": "encoder.logvar", "decoder_net.0": "decoder.fc1", "decoder_net.3": "decoder.fc2",
    "decoder_net.5": "decoder.out",
}
# The encoder body, op by op, before the mu / logvar heads.
_VPOSER_ENCODER_OPS = {
    "v1": ["bn1", "fc1", "leaky_relu", "bn2", "fc2", "leaky_relu"],
    "v2": ["bn1", "fc1", "leaky_relu", "bn2", "fc2", "fc3"],
}


def _source(path) -> dict:
    if path is None:
        return {"checkpoint": "in-memory model"}
    path = Path(path)
    return {"checkpoint": str(path), "sha256": file_sha256(path)} if path.is_file() else {"checkpoint": str(path)}


def _numpy(state: dict, dtype: np.dtype) -> dict:
    return {k: v.detach().cpu().numpy().astype(dtype) for k, v in state.items()}


def humor_entry(include_decoder: bool = False, model: humor_module.HumorModel | None = None) -> dict:
    """The manifest entry of an exported HuMoR model (architecture and dimensions; the layer widths are the
    model's, HuMoR's own when none is given)."""
    def layers(net: str, official) -> list:
        return list(getattr(model, net).sizes if model is not None else official)

    networks = {
        "encoder": {"prefix": "encoder.net", "layers": layers("encoder", humor_module.ENCODER_LAYERS), "skip_dim": 0},
        "prior": {"prefix": "prior_net.net", "layers": layers("prior_net", humor_module.PRIOR_LAYERS), "skip_dim": 0},
    }
    if include_decoder:
        networks["decoder"] = {"prefix": "decoder.net", "layers": layers("decoder", humor_module.DECODER_LAYERS),
                               "skip_dim": hs.LATENT_DIM}
    return {
        "architecture": "humor",
        "state_dim": hs.STATE_DIM,
        "latent_dim": hs.LATENT_DIM,
        "networks": networks,
        "mlp": "Linear, then [GroupNorm -> ReLU -> Linear(concat(h, skip))] per further layer",
        "group_norm_groups": humor_module.GROUP_NORM_GROUPS,
        "group_norm_eps": humor_module.GROUP_NORM_EPS,
        "output": "first latent_dim = mean, last latent_dim = log-variance",
        "state_layout": ["trans 3", "trans_vel 3", "root_orient 9 row-major", "root_orient_vel 3",
                         "pose_body 189 (21 row-major 3x3)", "joints 66 (SMPL 0..21)", "joints_vel 66"],
        "fps": hs.HUMOR_FPS,
    }


def vposer_entry(version: str) -> dict:
    model = vposer_module.VPoserV1 if version == "v1" else vposer_module.VPoserV2
    return {
        "architecture": "vposer",
        "version": version,
        "num_joints": vposer_module.NUM_JOINTS,
        "latent_dim": vposer_module.LATENT_DIM,
        "hidden": vposer_module.HIDDEN,
        "leaky_relu_slope": model.leaky_slope,
        "batch_norm_eps": 1e-5,
        "encoder_ops": _VPOSER_ENCODER_OPS[version],
        "encoder_scale": "softplus(logvar)",
        "decoder_ops": ["fc1", "leaky_relu", "fc2", "leaky_relu", "out", "rotation_6d_columns"],
        "rotation_6d": "columns: each joint's 6 values are a row-major 3x2 matrix; its columns are "
                       "Gram-Schmidt orthonormalised into R's first two columns, third = b1 x b2",
    }


def vposer_tensors(model: vposer_module.VPoserV1 | vposer_module.VPoserV2) -> dict:
    """The model's state dict renamed to the export layout (BatchNorm counters dropped)."""
    names = _VPOSER_V1_NAMES if model.version == "v1" else _VPOSER_V2_NAMES
    out = {}
    for key, value in model.state_dict().items():
        module, _, leaf = key.rpartition(".")
        if leaf == "num_batches_tracked":
            continue
        out[f"{names[module]}.{leaf}"] = value
    return out


def _write_model(out_dir: Path, name: str, tensors: dict, entry: dict, dtype: np.dtype) -> dict:
    arrays = _numpy(tensors, dtype)
    entry = dict(entry, file=f"{name}.safetensors", dtype=np.dtype(dtype).name,
                 tensors={k: list(v.shape) for k, v in arrays.items()})
    payload = encode_safetensors(arrays, {"format": "pt", "m3c": json.dumps(entry, sort_keys=True)})
    write_atomic(out_dir / entry["file"], payload)
    return dict(entry, sha256=hashlib.sha256(payload).hexdigest())


def export_weights(out_dir: str | os.PathLike, humor=None, vposer=None, vposer_version: str | None = None,
                   dtype: str = "float32", include_humor_decoder: bool = False) -> dict:
    """Exports HuMoR and/or VPoser to `out_dir`; returns the manifest written there.

    humor: a HuMoR checkpoint path or a HumorModel; vposer: a VPoser file/folder or a VPoserV1/V2.
    dtype: 'float32' (the official weights' precision) or 'float64'.
    """
    if humor is None and vposer is None:
        raise ValueError("nothing to export: give a HuMoR checkpoint and/or a VPoser model")
    if dtype not in ("float32", "float64"):
        raise ValueError(f"dtype must be 'float32' or 'float64', got {dtype!r}")
    np_dtype = np.dtype(dtype)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = out_dir / MANIFEST
    manifest = {"format": FORMAT, "format_version": FORMAT_VERSION, "models": {}}
    if manifest_path.exists():
        try:
            previous = json.loads(manifest_path.read_text())
        except json.JSONDecodeError as err:
            raise ValueError(f"{manifest_path} exists but is not JSON ({err}); remove it or pick another folder")
        if previous.get("format") == FORMAT:
            manifest["models"].update(previous.get("models", {}))
    manifest["m3c_version"] = __version__

    if humor is not None:
        model = humor if isinstance(humor, humor_module.HumorModel) else humor_module.load_humor(humor)
        if hasattr(model, "official_layout"):  # M3C's own prior: its input normalisation folded in
            if include_humor_decoder:
                raise ValueError("M3C's motion prior's decoder adds constant velocity to its output, which "
                                 "HuMoR's layout cannot hold; export it without the decoder")
            model = model.official_layout()
        prefixes = ("encoder.", "prior_net.") + (("decoder.",) if include_humor_decoder else ())
        tensors = {k: v for k, v in model.state_dict().items() if k.startswith(prefixes)}
        entry = dict(humor_entry(include_humor_decoder, model),
                     source=_source(None if isinstance(humor, torch.nn.Module) else humor))
        manifest["models"]["humor"] = _write_model(out_dir, "humor", tensors, entry, np_dtype)

    if vposer is not None:
        if isinstance(vposer, (vposer_module.VPoserV1, vposer_module.VPoserV2)):
            model, source = vposer, None
        else:
            model, source = vposer_module.load_vposer(vposer, version=vposer_version), vposer
        entry = dict(vposer_entry(model.version), source=_source(source))
        manifest["models"]["vposer"] = _write_model(out_dir, "vposer", vposer_tensors(model), entry, np_dtype)

    write_atomic(manifest_path, (json.dumps(manifest, indent=2, sort_keys=True) + "\n").encode())
    return manifest


def read_exported(path: str | os.PathLike) -> tuple[dict, dict]:
    """(tensors, manifest entry) of one exported .safetensors file."""
    tensors, metadata = read_safetensors(path)
    if "m3c" not in metadata:
        raise ValueError(f"{path} is a safetensors file without M3C's manifest entry; export it with "
                         "python -m m3c.models.export")
    return tensors, json.loads(metadata["m3c"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m m3c.models.export", description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--humor", help="HuMoR checkpoint (checkpoints/humor/best_model.pth)")
    parser.add_argument("--vposer", help="VPoser folder (vposer_v1_0, V02_05) or snapshot file")
    parser.add_argument("--vposer-version", choices=["v1", "v2"], help="default: from the file type")
    parser.add_argument("--dtype", choices=["float32", "float64"], default="float32")
    parser.add_argument("--humor-decoder", action="store_true", help="also export HuMoR's decoder")
    args = parser.parse_args(argv)
    if args.humor is None and args.vposer is None:
        parser.error("give --humor and/or --vposer")
    try:
        manifest = export_weights(args.out, humor=args.humor, vposer=args.vposer,
                                  vposer_version=args.vposer_version, dtype=args.dtype,
                                  include_humor_decoder=args.humor_decoder)
    except (CheckpointError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    for name, entry in manifest["models"].items():
        print(f"{name}: {Path(args.out) / entry['file']} ({entry['dtype']}, sha256 {entry['sha256'][:12]})")
    print(f"manifest: {Path(args.out) / MANIFEST}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
