"""Synthetic videos with ground truth: retargeted motion-capture people in textured 3D scenes, filmed by known
moving cameras and rendered on the CPU (C++ rasteriser, m3c._core). The video benchmark
(m3c.eval.video_benchmark) runs the real pipeline on them.

World frame: y up, metres, ground plane y = 0 (as m3c.eval.scenes); cameras OpenCV (x right, y down, z forward),
world_from_cam 4 x 4.
"""

from m3c.synth.cameras import CAMERA_KINDS, camera_path
from m3c.synth.people import Person, PersonLook, place_people
from m3c.synth.render import Renderer, TexturedMesh
from m3c.synth.sequence import (
    SequenceSetup,
    SequenceSpec,
    SyntheticVideo,
    make_video,
    render_video,
    setup_sequence,
)
from m3c.synth.world import StaticScene, make_scene

__all__ = [
    "CAMERA_KINDS",
    "Person",
    "PersonLook",
    "Renderer",
    "SequenceSetup",
    "SequenceSpec",
    "StaticScene",
    "SyntheticVideo",
    "TexturedMesh",
    "camera_path",
    "make_scene",
    "make_video",
    "place_people",
    "render_video",
    "setup_sequence",
]
