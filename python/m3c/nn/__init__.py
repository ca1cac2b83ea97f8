"""The C++ network runtime (cpp/nn) from Python: HuMoR's motion-prior terms and VPoser evaluated from weights
exported by `python -m m3c.models.export`, HuMoR's state builder, and the C++ safetensors reader. The torch
models in m3c.models are the reference these agree with."""

from m3c.nn.runtime import HumorPrior, VPoser, build_humor_states, canonicalize, read_safetensors

__all__ = ["HumorPrior", "VPoser", "build_humor_states", "canonicalize", "read_safetensors"]
