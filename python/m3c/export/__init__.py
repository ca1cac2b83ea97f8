"""Exports of a result folder for animation packages (BVH, glTF/GLB, FBX, USD) and for peer methods' tools
(WHAM, SLAHMR and GVHMR result layouts). `m3c export OUT_DIR --format FMT` and export_results() do the same;
`--rig` retargets the motion onto a published skeleton (Mixamo, UE5 mannequin, Unity Humanoid, Rigify;
m3c.export.rigs)."""

from __future__ import annotations

import tempfile
from pathlib import Path

from m3c.export.source import ExportSource, TrackMotion, load_source, parse_track_ids

FORMATS = ("bvh", "glb", "fbx", "usd", "wham", "slahmr", "gvhmr")
RIG_FORMATS = ("glb", "fbx", "usd")
RIG_NAMES = ("smpl", "mixamo", "ue5", "unity", "rigify")
# Retarget options and their defaults: with these and rig smpl, glb/fbx are the scene exports (every person,
# the camera, the ground in one file); anything else writes one retargeted file per track.
RIG_DEFAULTS = {"root_motion": "performer", "reference_pose": "none", "smoothing": "off", "foot_lock": True}
# Where each format goes when no --out is given (inside the result folder).
DEFAULT_OUT = {"bvh": "export/bvh", "glb": "export/scene.glb", "fbx": "export/scene.fbx", "usd": "export/usd",
               "wham": "export/wham",
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
    the tracker ids `tracks` (None: all). Returns the files written. options: bvh_unit ("cm" or "m"); rig (one
    of RIG_NAMES, default smpl) and the retarget's root_motion, reference_pose, smoothing, foot_lock
    (RIG_DEFAULTS).
    """
    if fmt not in FORMATS:
        raise ValueError(f"unknown export format {fmt!r}; choose one of {', '.join(FORMATS)}")
    rig = options.get("rig") or "smpl"
    if rig not in RIG_NAMES:
        raise ValueError(f"unknown rig {rig!r}; choose one of {', '.join(RIG_NAMES)}")
    retarget = {k: options.get(k, v) if options.get(k) is not None else v for k, v in RIG_DEFAULTS.items()}
    rigged = fmt == "usd" or rig != "smpl" or retarget != RIG_DEFAULTS
    if rigged and fmt not in RIG_FORMATS:
        raise ValueError(f"--rig and the retarget options write {', '.join(RIG_FORMATS)}, not {fmt}")
    folder = Path(folder)
    default = f"export/{rig}" if rigged else DEFAULT_OUT[fmt]
    out = Path(out).expanduser() if out is not None else folder / default
    if fmt == "usd":
        from m3c.export.rig_files import check_usd
        check_usd()   # before any work
    source = load_source(folder, tracks, body_model)
    check_writable(out)
    if rigged:
        from m3c.export.rig_files import export_rig
        return export_rig(source, out, rig, fmt, **retarget)
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


__all__ = ["FORMATS", "DEFAULT_OUT", "RIG_FORMATS", "RIG_NAMES", "RIG_DEFAULTS", "ExportSource",
           "TrackMotion", "export_results", "load_source", "parse_track_ids"]
