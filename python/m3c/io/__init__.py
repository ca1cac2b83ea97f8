"""File I/O shared by every stage."""

from m3c.io.atomic import atomic_path, save_npz_atomic

__all__ = ["atomic_path", "save_npz_atomic"]
