"""Exports of a result folder for animation packages (BVH, glTF/GLB, FBX) and for peer methods' tools (WHAM,
SLAHMR and GVHMR result layouts). `m3c export OUT_DIR --format FMT` and export_results() do the same."""

from __future__ import annotations

import tempfile
from pathlib import Path

from m3c.export.source import ExportSource, TrackMotion, load_source, parse_track_ids

FORMATS = ("bvh", "glb", "fbx", "wham", "slahmr", "gvhmr")
# Where each format goes when no --out is given (inside the result folder).
DEFAULT_OUT = {"bvh": "export/bvh", "glb": "export/scene.glb", "fbx": "export/scene.fbx", "wham": "export/wham",
               "slahmr": "export/slahmr", "gvhmr": "export/gvhmr"}


def check_writable(out: Path) -> None:
    """Fails before anything is computed or written when `out` (a file or folder to be) cannot be written."""
    folder = out if not out.suffix else out.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as err:
        raise PermissionError(f"cannot write {out}: {err.strerror or err} ({folder}); pass --out a folder you can "
                              "write to") from None


def export_results(folder: str | Path, fmt: str, out: str | Path | None = None, tracks=None,
                   body_model: str | Path | None = None, **options) -> list[Path]:
    """Exports the results in `folder` as `fmt` (one of FORMATS) to `out` (default: folder/DEFAULT_OUT[fmt]) for
    the tracker ids `tracks` (None: all). Returns the files written. options: bvh_unit ("cm" or "m")."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    folder = Path(folder)
    out = Path(out).expanduser() if out is not None else folder / DEFAULT_OUT[fmt]
    source = load_source(folder, tracks, body_model)
    check_writable(out)
    if fmt == "bvh":
        from m3c.export.bvh import export_bvh
        return export_bvh(source, out, unit=options.get("bvh_unit", "cm"))
    if fmt == "glb":
        from m3c.export.gltf import export_glb
        return export_glb(source, out)
    if fmt == "fbx":
        from m3c.export.blender import export_fbx
        return export_fbx(source, out)
    from m3c.export import peers
    return {"wham": peers.export_wham, "slahmr": peers.export_slahmr, "gvhmr": peers.export_gvhmr}[fmt](source, out)


__all__ = ["FORMATS", "DEFAULT_OUT", "ExportSource", "TrackMotion", "export_results", "load_source",
           "parse_track_ids"]
