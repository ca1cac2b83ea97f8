"""The built-in node types of the M3C pipeline, in the thesis's order.

frame level   frames, camera, depth
patch level   perception (tracks, and per frame detections and masks), patches, focal, vo
SMPL level    ground
track level   local_tracks, scale, lift, optimize, hands
outputs       results, overlay, world_view, camera_plot
any           load (outputs read from a folder)

m3c.pipeline knows none of them: a program that builds M3C's graphs (the m3c command, the benchmarks, a script)
calls register_builtin_nodes() first.
"""

from __future__ import annotations

from pathlib import Path


def register_builtin_nodes() -> None:
    """Registers the built-in node types with m3c.pipeline (importing their modules runs their @register_node) and
    the loader of the body-model setting they read. Idempotent."""
    from m3c.nodes import (camera, camera_plot, depth, focal, frames, ground, hands, lean, lift,  # noqa: F401
                           load, local_tracks, optimize, overlay, patches, perception, results, scale, vo,
                           world_view)
    from m3c.pipeline.node import register_setting_loader

    register_setting_loader("body_model", _body_model_fingerprint, _load_body_model)


def _body_model_fingerprint(path: str | None) -> str:
    """The body model's part of the cache keys: its file's content digest (the open model's, named, when unset)."""
    from m3c.pipeline.cache import file_digest
    from m3c.pipeline.node import InputError

    if path is None:
        from m3c.body import OPEN_MODEL_NAME, open_body_model_path

        return f"{OPEN_MODEL_NAME}:{file_digest(open_body_model_path())}"
    file = Path(path).expanduser()
    if not file.is_file():
        raise InputError(f"body model file not found: {file}; pass an SMPL .pkl/.npz (--body-model) or leave it "
                         "unset for M3C's open model")
    return file_digest(file)


def _load_body_model(path: str | None):
    """The configured body model (settings.body_model, else M3C's open model)."""
    from m3c.body import default_body_model
    from m3c.pipeline.node import InputError

    if path is not None and not Path(path).expanduser().is_file():
        raise InputError(f"body model file not found: {path}")
    return default_body_model(None if path is None else Path(path).expanduser())
