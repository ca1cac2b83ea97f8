"""What the detector's multi-person pose network (m3c.perception.paf) costs per detection frame, against one
BlazePose run on the same frame measured in the same process (these machines are noisy: the ratio is the figure):
the network's forward pass at its input size, the grouping of its maps, and BlazePose (pose detection, landmarks
and mask) on the whole frame. Frames of the bundled clip (960 x 540) unless --video.

    PYTHONPATH=python python3 bench/perception_paf.py [--video VIDEO] [--frames 10]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "pexels_walking_moving_camera.mp4"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--video", default=str(EXAMPLE))
    parser.add_argument("--frames", type=int, default=10, help="frames timed (every 10th of the video)")
    args = parser.parse_args()

    from m3c.io.video import iter_frames
    from m3c.perception.mediapipe_pose import MediaPipeEngine, mediapipe_available
    from m3c.perception.paf import INSTALL_COMMAND, PafPoseNetwork, group_people, model_available

    if not model_available():
        print(f"the network is not installed: {INSTALL_COMMAND}", file=sys.stderr)
        return 1
    if not mediapipe_available():
        print("mediapipe==0.10.14 is not installed (the reference)", file=sys.stderr)
        return 1
    frames = [f for _, f in iter_frames(args.video, step=10, colour="rgb")][: args.frames]
    net, engine = PafPoseNetwork(), MediaPipeEngine()
    net.maps(frames[0])  # first runs allocate
    engine.run(frames[0])
    times = {"network": [], "grouping": [], "blazepose": []}
    people = []
    for frame in frames:
        t0 = time.perf_counter()
        maps = net.maps(frame)
        t1 = time.perf_counter()
        people.append(len(group_people(maps, frame.shape[:2], net.config)))
        t2 = time.perf_counter()
        engine.run(frame)
        t3 = time.perf_counter()
        times["network"].append(t1 - t0)
        times["grouping"].append(t2 - t1)
        times["blazepose"].append(t3 - t2)
    engine.close()
    reference = float(np.median(times["blazepose"]))
    width, height = net.input_size(frames[0].shape[:2])
    print(f"{len(frames)} frames of {Path(args.video).name} ({frames[0].shape[1]} x {frames[0].shape[0]}; network "
          f"input {width} x {height}); people found per frame: {np.mean(people):.1f}")
    print(f"{'part':10s} {'median ms':>10s} {'x BlazePose':>12s}")
    for name, values in times.items():
        median = float(np.median(values))
        print(f"{name:10s} {1000 * median:10.1f} {median / reference:12.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
