"""Patch visual odometry: camera trajectory of a moving, uncalibrated camera.

A DPVO-style patch graph with sliding-window Ceres bundle adjustment (C++), a classical Lucas-Kanade
front-end with gradient-biased patch sampling, optional human masks (zero the gradient, reject measurements)
and optional depth maps (initialise patch inverse depth).

    from m3c.vo import run_vo, run_vo_video
    result = run_vo(frames, masks=masks, depths=depths)   # frames uint8 (T, H, W[, 3])
    result.world_from_cam                                 # (T, 4, 4), world = first camera
    result.points                                         # (M, 3) the final map, VO units
    plane = map_ground_plane(result.points, result.world_from_cam, up)    # the ground among the map points
    scale = scale_from_camera_height([contacts_in_camera], result.world_from_cam, plane[:2])  # m per VO unit
    focal = estimate_focal(frames, masks)                 # the focal length of a camera that turns (m3c.vo.focal)
"""

from m3c.io.video import default_intrinsics
from m3c.vo.focal import FocalEstimate, FocalSearchConfig, estimate_focal
from m3c.vo.metrics import absolute_trajectory_error, path_length, relative_ate, umeyama_sim3
from m3c.vo.odometry import VisualOdometry, VOConfig, VOResult, run_vo
from m3c.vo.scale import (ScaleEstimate, ScaleObservation, fuse, map_ground_plane, scale_from_camera_height,
                          scale_from_depth, scale_from_planted_feet)
from m3c.vo.video import run_vo_video

__all__ = ["VOConfig", "VOResult", "VisualOdometry", "run_vo", "run_vo_video", "default_intrinsics", "absolute_trajectory_error",
           "relative_ate", "path_length", "umeyama_sim3", "ScaleEstimate", "ScaleObservation", "fuse",
           "map_ground_plane", "scale_from_camera_height", "scale_from_depth", "scale_from_planted_feet",
           "estimate_focal", "FocalEstimate", "FocalSearchConfig"]
