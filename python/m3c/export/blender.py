"""Blender from M3C: FBX export through Blender's own FBX exporter, and the Blender steps of tests and docs.

Blender runs as the `bpy` module (PyPI's bpy 5.0.1, Python 3.11 only). It pins numpy<2, so it lives in its own
virtual environment and M3C runs it in a subprocess (blender_script.py). The interpreter is, in this order:
$M3C_BLENDER_PYTHON, ~/.cache/m3c/blender-venv/bin/python (what scripts/setup.sh creates), or this Python when
it can import bpy itself.
"""

from __future__ import annotations

import functools
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from m3c.export.source import ExportSource
from m3c.io.atomic import atomic_path

SCRIPT = Path(__file__).with_name("blender_script.py")
DEFAULT_VENV = Path("~/.cache/m3c/blender-venv").expanduser()
INSTALL_HINT = ("python3.11 -m venv ~/.cache/m3c/blender-venv && ~/.cache/m3c/blender-venv/bin/pip install "
                "bpy==5.0.1 (Blender as a Python module; or set M3C_BLENDER_PYTHON to a Python that has bpy)")


class BlenderUnavailable(ImportError):
    """No Python with Blender's bpy module was found."""


@functools.lru_cache(maxsize=None)
def _has_bpy(python: str) -> bool:
    try:
        return subprocess.run([python, "-c", "import bpy"], capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def blender_python() -> str:
    """The interpreter that runs Blender steps; BlenderUnavailable (naming how to install it) when none has bpy."""
    configured = os.environ.get("M3C_BLENDER_PYTHON")
    if configured:
        if not _has_bpy(configured):
            raise BlenderUnavailable(f"M3C_BLENDER_PYTHON={configured} cannot import bpy; install it there: "
                                     f"{configured} -m pip install bpy==5.0.1")
        return configured
    venv = DEFAULT_VENV / "bin" / "python"
    if venv.is_file() and _has_bpy(str(venv)):
        return str(venv)
    if importlib.util.find_spec("bpy") is not None:
        return sys.executable
    raise BlenderUnavailable(f"FBX export and the Blender steps need Blender's bpy module, not found; install it "
                             f"with {INSTALL_HINT}")


def run_blender(*args: str, timeout: float = 600.0) -> None:
    """Runs blender_script.py with `args` in the Blender interpreter; a failure raises RuntimeError with its log."""
    cmd = [blender_python(), str(SCRIPT), *map(str, args)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if done.returncode != 0:
        raise RuntimeError(f"the Blender step {args[0]} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")


def export_fbx(source: ExportSource, out: Path) -> list[Path]:
    """The GLB export converted by Blender's FBX exporter (y up, -z forward, armatures with baked animation,
    meshes, the camera; people hold their first/last pose outside their tracks): out/scene.fbx, or `out` when
    it ends in .fbx."""
    from m3c.export.gltf import export_glb

    path = out if out.suffix.lower() == ".fbx" else out / "scene.fbx"
    blender_python()  # fail before any work when Blender is missing
    with tempfile.TemporaryDirectory(prefix="m3c-fbx-") as tmp:
        # Zero scales (people hidden outside their tracks) make Blender's FBX bake NaN bone matrices.
        glb, = export_glb(source, Path(tmp) / "scene.glb", hide_outside_track=False)
        with atomic_path(path) as fbx:
            run_blender("fbx", glb, fbx, repr(source.fps), *source.image_size)
    return [path]


def render_glb(glb: str | Path, png: str | Path, fps: float, frame: int = 0) -> Path:
    """A still of `glb` imported into Blender at `frame` (Cycles on the CPU, 960 x 540): the README's picture."""
    png = Path(png)
    with atomic_path(png) as tmp:
        run_blender("render", glb, repr(float(fps)), int(frame), tmp)
    return png
