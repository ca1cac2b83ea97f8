"""M3C: monocular, multi-person, world-grounded 3D human motion capture."""

__version__ = "0.4.0"
