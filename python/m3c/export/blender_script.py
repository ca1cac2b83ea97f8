"""Blender steps of the exports, run by Blender's own Python (the bpy module) in a subprocess, since bpy pins
numpy<2 and lives in its own environment. Self-contained: it imports nothing from m3c.

    python blender_script.py fbx    GLB FBX FPS W H             the GLB converted by Blender's FBX exporter
    python blender_script.py sample FILE FPS FIRST LAST OUT     imported joints and camera per frame (JSON)
    python blender_script.py render GLB FPS FRAME PNG           a still of the imported GLB (Cycles, CPU)

Blender's importers turn y-up files into its z-up world: Blender (x, y, z) = file (x, -z, y).
"""

from __future__ import annotations

import json
import math
import sys

import bpy
from mathutils import Matrix, Vector


def _reset(fps: float) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = max(1, round(fps))
    scene.render.fps_base = scene.render.fps / fps   # fps = render.fps / fps_base exactly


def _import(path: str, fps: float) -> None:
    _reset(fps)
    if path.lower().endswith(".bvh"):
        # M3C's BVH is y up in centimetres; frame k of the file lands on scene frame k + 1 (a glTF key at time t
        # lands on frame t * fps). Blender 5.0.1 puts it there with frame_start 0 too.
        bpy.ops.import_anim.bvh(filepath=path, global_scale=0.01, frame_start=1, use_fps_scale=False,
                                axis_forward="-Z", axis_up="Y", rotate_mode="NATIVE")
    elif path.lower().endswith(".fbx"):
        # Blender's FBX importer shifts animation by anim_offset frames (1 by default): 0 keeps time 0 on frame 0.
        bpy.ops.import_scene.fbx(filepath=path, anim_offset=0.0)
    else:
        bpy.ops.import_scene.gltf(filepath=path)


def _frame_range() -> tuple[int, int]:
    first, last = math.inf, -math.inf
    for action in bpy.data.actions:
        first, last = min(first, action.frame_range[0]), max(last, action.frame_range[1])
    return int(round(first)), int(round(last))


def export_fbx(glb: str, fbx: str, fps: float, width: int, height: int) -> None:
    _import(glb, fps)
    # The FBX camera's aspect comes from the render resolution: the video's.
    bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y = width, height
    first, last = _frame_range()
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = first, last
    bpy.ops.export_scene.fbx(filepath=fbx, object_types={"ARMATURE", "MESH", "CAMERA", "EMPTY"}, bake_anim=True,
                             bake_anim_use_all_actions=False, bake_anim_use_nla_strips=False, add_leaf_bones=False,
                             bake_anim_simplify_factor=0.0,  # a key on every frame: no curve simplification
                             axis_forward="-Z", axis_up="Y", path_mode="AUTO")


def sample(path: str, fps: float, first: int, last: int, out: str) -> None:
    """{"frames": [...], "armatures": {name: {bone: [[x, y, z] per frame]}},
    "parents": {name: {bone: parent}}, "cameras": {name: [4x4 per frame]}} with bone heads and camera
    matrices in Blender's world (metres)."""
    _import(path, fps)
    scene = bpy.context.scene
    frames = list(range(first, last + 1))
    armatures = {o.name: {b.name: [] for b in o.pose.bones} for o in scene.objects if o.type == "ARMATURE"}
    cameras = {o.name: [] for o in scene.objects if o.type == "CAMERA"}
    for frame in frames:
        scene.frame_set(frame)
        for name, bones in armatures.items():
            obj = scene.objects[name]
            for bone in obj.pose.bones:
                bones[bone.name].append(list(obj.matrix_world @ bone.head))
        for name, mats in cameras.items():
            mats.append([list(row) for row in scene.objects[name].matrix_world])
    fovs = {o.name: [o.data.angle_x, o.data.angle_y] for o in scene.objects if o.type == "CAMERA"}
    parents = {o.name: {b.name: b.parent.name if b.parent else None for b in o.data.bones}
               for o in scene.objects if o.type == "ARMATURE"}
    with open(out, "w") as fh:
        json.dump({"frames": frames, "armatures": armatures, "parents": parents, "cameras": cameras,
                   "camera_fov": fovs,
                   "resolution": [scene.render.resolution_x, scene.render.resolution_y],
                   "fps": scene.render.fps / scene.render.fps_base}, fh)


def render(glb: str, fps: float, frame: int, png: str) -> None:
    """The scene at `frame` from a camera above and behind the video camera, sun-lit, Cycles on the CPU."""
    _import(glb, fps)
    scene = bpy.context.scene
    scene.frame_set(frame)
    bodies = [o for o in scene.objects if o.type == "MESH" and o.name != "ground"]
    points = [o.matrix_world @ Vector(c) for o in bodies for c in o.bound_box]
    bpy.context.view_layer.update()
    centre = sum((p for p in points), Vector()) / max(len(points), 1)
    for obj in bodies:  # skinned meshes: their armature's pose sets where they are
        for mod in obj.modifiers:
            if mod.type == "ARMATURE" and mod.object is not None:
                heads = [mod.object.matrix_world @ b.head for b in mod.object.pose.bones]
                centre = sum(heads, Vector()) / len(heads)
    video_cams = [o for o in scene.objects if o.type == "CAMERA"]
    view = bpy.data.objects.new("view", bpy.data.cameras.new("view"))
    scene.collection.objects.link(view)
    eye = centre + Vector((3.5, -5.0, 2.5))
    if video_cams:
        back = (video_cams[0].matrix_world.translation - centre)
        back.z = 0.0
        if back.length > 1e-3:
            eye = centre + back.normalized() * 5.0 + Vector((0.0, 0.0, 2.5))
            eye = Matrix.Rotation(math.radians(35.0), 4, "Z") @ (eye - centre) + centre
    view.location = eye
    view.rotation_euler = (centre - eye).to_track_quat("-Z", "Y").to_euler()
    scene.camera = view
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(40.0), 0.0, math.radians(30.0))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world.color = (0.8, 0.85, 0.9)
    scene.world = world
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.render.resolution_x, scene.render.resolution_y = 960, 540
    scene.render.filepath = png
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    command, *args = sys.argv[1:]
    if command == "fbx":
        export_fbx(args[0], args[1], float(args[2]), int(args[3]), int(args[4]))
    elif command == "sample":
        sample(args[0], float(args[1]), int(args[2]), int(args[3]), args[4])
    elif command == "render":
        render(args[0], float(args[1]), int(args[2]), args[3])
    else:
        raise SystemExit(f"unknown command {command!r}")
