"""Pictures of results on CPU, without a display: a numpy triangle rasteriser, overlay and world-view frames,
camera-trajectory plots."""

from m3c.viz.raster import Buffers, Mesh, rasterize, render, shade, vertex_normals

__all__ = ["Buffers", "Mesh", "rasterize", "render", "shade", "vertex_normals"]
