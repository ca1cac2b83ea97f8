"""The built-in node types of the M3C pipeline, in the thesis's order (importing this module registers them).

frame level   frames, camera, detections, masks, depth
patch level   boxes, patches, keypoints, body, focal, vo
SMPL level    tracking, contacts, ground
track level   local_tracks, scale, lift, optimize
outputs       results, overlay, world_view, camera_plot
any           load (outputs read from a folder)
"""

from m3c.nodes import focal, frames, load, optimize, outputs, patches, perception, tracks, world  # noqa: F401
