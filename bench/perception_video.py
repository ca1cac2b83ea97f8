"""The offline perception stage on a real clip against MediaPipe's own single-person pose tracking, timed in the
same process on the same decoded frames.

Reference: mp.solutions.pose.Pose in video mode (static_image_mode=False, segmentation on), one person, BlazePose
tracking its own region of interest from frame to frame. Ours: the multi-person pipeline (tiled
detect-whiten-redetect every `detect_every` frames, isolated square patches per tracked person, tracking with
pose/3D/colour cues) plus the per-frame body fit and contacts. Printed: frames with a person, fps of each and
their ratio, body-fit reprojection errors, and how often the keypoints lie inside the segmentation's box.

    PYTHONPATH=python python3 bench/perception_video.py VIDEO [--frames N]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from m3c.io.video import iter_frames, probe_video
from m3c.perception import PerceptionConfig, run_perception_frames
from m3c.perception.evaluation import keypoints_in_mask_box
from m3c.perception.mediapipe_pose import import_mediapipe


def reference(frames: list) -> tuple[int, float]:
    mp = import_mediapipe()
    found = 0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start = time.perf_counter()
        with mp.solutions.pose.Pose(static_image_mode=False, model_complexity=1, enable_segmentation=True) as pose:
            for image in frames:
                found += pose.process(image).pose_landmarks is not None
        seconds = time.perf_counter() - start
    return found, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("video")
    parser.add_argument("--frames", type=int, default=None)
    args = parser.parse_args()
    info = probe_video(args.video)
    frames = [image for _, image in iter_frames(args.video, stop=args.frames, colour="rgb")]
    n = len(frames)
    print(f"{args.video}: {n} frames {info.width}x{info.height} at {info.fps:.2f} fps")

    ref_found, ref_seconds = reference(frames)
    start = time.perf_counter()
    result = run_perception_frames(iter(frames), info.fps, (info.height, info.width),
                                   PerceptionConfig(), source=args.video)
    ours_seconds = time.perf_counter() - start

    with_person = int(np.count_nonzero(result.people_per_frame))
    print(f"MediaPipe tracking (1 person): person in {ref_found}/{n} frames, {n / ref_seconds:.1f} fps")
    print(f"M3C perception (multi-person): person in {with_person}/{n} frames, {n / ours_seconds:.1f} fps "
          f"(ratio to MediaPipe tracking: {ref_seconds / ours_seconds:.2f}x)")
    print("  seconds per stage: " + ", ".join(f"{k} {v:.1f}" for k, v in result.seconds.items()))
    print(f"  tracks: {len(result.tracks)}; people per frame: {np.bincount(result.people_per_frame).tolist()}")
    for track in result.tracks:
        e = track.bodies.reprojection_error_px[track.bodies.valid]
        inside = keypoints_in_mask_box(result, track)
        print(f"  track {track.track_id}: frames {track.frame_ids[0]}..{track.frame_ids[-1]} ({len(track.frame_ids)}), "
              f"fitted {track.bodies.valid.sum()}, reprojection px median {np.median(e):.2f} p95 "
              f"{np.percentile(e, 95):.2f} max {e.max():.2f}; keypoints inside the mask box in "
              f"{100 * inside.mean():.1f}% of frames; a foot in contact in "
              f"{100 * (track.contacts.max(axis=1) > 0.5).mean():.0f}% of frames")


if __name__ == "__main__":
    main()
