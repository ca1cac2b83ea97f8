"""World-frame motion: the staged global optimization (thesis 4.1.4, SLAHMR-style) over the C++ core."""

from m3c.motion.config import OptimizerConfig, StageSpec
from m3c.motion.optimize import Cameras, StageResult, Track, WorldResult, optimize, track_joints

__all__ = ["Cameras", "OptimizerConfig", "StageResult", "StageSpec", "Track", "WorldResult",
           "optimize", "track_joints"]
