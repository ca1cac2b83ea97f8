"""Perception that works offline on CPU (thesis 4.1.1-4.1.3): people, masks, 2D keypoints, camera-local bodies,
tracking and contacts, with one estimator interface per task and a registry that a config selects from.

Defaults: MediaPipe's BlazePose (optional extra m3c[perception]) for people, masks and keypoints; the C++
per-frame body fit (cpp/fit) for camera-local bodies; a SORT/DeepSORT-style tracker with pose, 3D and colour
cues; kinematic contacts; neutral gender; no depth.
"""

from m3c.io.video import default_intrinsics
from m3c.perception.appearance import appearance_descriptor, bhattacharyya_distance
from m3c.perception.body import BodyFitConfig, BodyFits, fit_bodies, rough_location
from m3c.perception.boxes import crop, iou, iou_matrix, isolate, process_box
from m3c.perception.contacts import KinematicContactConfig, contact_track, estimate_up, kinematic_contacts
from m3c.perception.interfaces import (TASKS, BodyEstimator, ContactEstimator, DepthEstimator, Detector,
                                       GenderEstimator, PoseEstimator2D, Segmenter)
from m3c.perception.pipeline import (EstimatorSpec, PerceptionConfig, PerceptionResult, PersonTrack,
                                     load_result, run_perception, run_perception_frames)
from m3c.perception.registry import available, create, register
from m3c.perception.tracking import Observation, Tracker, TrackerConfig
from m3c.perception.types import FrameContext, Person

__all__ = ["TASKS", "BodyEstimator", "BodyFitConfig", "BodyFits", "ContactEstimator", "DepthEstimator", "Detector",
           "EstimatorSpec", "FrameContext", "GenderEstimator", "KinematicContactConfig", "Observation",
           "PerceptionConfig", "PerceptionResult", "Person", "PersonTrack", "PoseEstimator2D", "Segmenter",
           "Tracker", "TrackerConfig", "appearance_descriptor", "available", "bhattacharyya_distance",
           "contact_track", "create", "crop", "default_intrinsics", "estimate_up", "fit_bodies", "iou",
           "iou_matrix", "isolate", "kinematic_contacts", "process_box", "register",
           "load_result", "rough_location", "run_perception", "run_perception_frames"]
