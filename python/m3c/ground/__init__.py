"""Ground planes from body contacts: DBSCAN, robust plane fits, per-person association, temporal filling."""

from m3c.ground.planes import (CAMERA_UP, FramePlanes, GroundParams, PlaneFit, RayGroundParams, dbscan,
                               fit_ground_along_rays, fit_plane, frame_planes)
from m3c.ground.tracks import (MAX_CONTACT_POINTS, ContactTrack, GroundTrack, contact_vertices, estimate_ground_planes,
                               foot_vertex_ids)

__all__ = ["CAMERA_UP", "MAX_CONTACT_POINTS", "ContactTrack", "FramePlanes", "GroundParams", "GroundTrack", "PlaneFit",
           "RayGroundParams", "contact_vertices", "dbscan", "estimate_ground_planes", "fit_ground_along_rays", "fit_plane",
           "foot_vertex_ids", "frame_planes"]
