"""Blender steps of the exports, run by Blender's own Python (the bpy module) in a subprocess, since bpy pins
numpy<2 and lives in its own environment. Self-contained: it imports nothing from m3c.

    python blender_script.py fbx    GLB FBX FPS W H             the GLB converted by Blender's FBX exporter
    python blender_script.py sample FILE FPS FIRST LAST OUT     imported joints and camera per frame (JSON)
    python blender_script.py render GLB FPS FRAME PNG           a still of the imported GLB (Cycles, CPU)
    python blender_script.py rig GLB FPS FRAMES PNG HAND W H    a rig's poses side by side and a close-up
                                                                of bone HAND (Cycles; PNG, PNG.hand.png)

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


def _material(name: str, colour: tuple, alpha: float = 1.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes.get("Principled BSDF")
    bsdf.inputs["Base Color"].default_value = (*colour, 1.0)
    bsdf.inputs["Alpha"].default_value = alpha
    bsdf.inputs["Roughness"].default_value = 0.6
    mat.diffuse_color = (*colour, alpha)
    return mat


def _bone_mesh(arm, name: str, finger_words: tuple, materials: tuple):
    """A mesh of the armature's posed bones as octahedra (head, tail, a waist a fifth of the way along), in the
    world; finger bones (names holding one of finger_words) get the second material."""
    verts, faces, mats = [], [], []
    for pb in arm.pose.bones:
        head, tail = arm.matrix_world @ pb.head, arm.matrix_world @ pb.tail
        frame = (arm.matrix_world @ pb.matrix).to_3x3()
        along = tail - head
        length = along.length
        if length < 1e-6:
            continue
        x, z = frame.col[0].normalized(), frame.col[2].normalized()
        w = 0.12 * length
        waist = head + 0.2 * along
        base = len(verts)
        verts += [head, tail, waist + w * x, waist + w * z, waist - w * x, waist - w * z]
        for a, b in ((2, 3), (3, 4), (4, 5), (5, 2)):
            faces += [(base, base + a, base + b), (base + 1, base + b, base + a)]
        finger = any(word in pb.name for word in finger_words)
        mats += [1 if finger else 0] * 8
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(v) for v in verts], [], faces)
    for m in materials:
        mesh.materials.append(m)
    for poly, m in zip(mesh.polygons, mats):
        poly.material_index = m
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _look(cam, eye: Vector, target: Vector) -> None:
    cam.location = eye
    cam.rotation_euler = (target - eye).to_track_quat("-Z", "Y").to_euler()


def render_rig(glb: str, fps: float, frames: str, png: str, hand: str, width: int, height: int) -> None:
    """The imported rig's armature and its skinned mesh at each of `frames` (comma separated), snapshotted as
    static meshes, each turned about its hips so that the hips' left-right line lies across the view, and set
    side by side: the mesh translucent,
    the bones as octahedra (finger bones in another colour). Rendered by Cycles on the CPU to `png`, and a
    close-up of the first pose's bone `hand` and its fingers to `png`.hand.png."""
    _import(glb, fps)
    scene = bpy.context.scene
    arm = next(o for o in scene.objects if o.type == "ARMATURE")
    body = next(o for o in scene.objects if o.type == "MESH")
    skin = _material("skin", (0.55, 0.62, 0.75), alpha=0.3)
    bones = _material("bones", (0.92, 0.42, 0.08))
    fingers = _material("fingers", (0.10, 0.45, 0.95))
    words = ("Thumb", "Index", "Middle", "Ring", "Pinky")
    hips_name = next(b.name for b in arm.pose.bones if b.parent is None)
    frame_list = [int(f) for f in frames.split(",")]
    spots = [0.0] + [1.9 + 0.9 * k for k in range(len(frame_list) - 1)]   # the first (rest) pose's arms wide
    hand_point = None
    for i, (frame, spot) in enumerate(zip(frame_list, spots)):
        scene.frame_set(frame)
        bpy.context.view_layer.update()
        depsgraph = bpy.context.evaluated_depsgraph_get()
        mesh = bpy.data.meshes.new_from_object(body.evaluated_get(depsgraph), depsgraph=depsgraph)
        mesh.transform(body.matrix_world)
        mesh.materials.clear()
        mesh.materials.append(skin)
        snapshot = bpy.data.objects.new(f"pose{i}", mesh)
        scene.collection.objects.link(snapshot)
        skeleton = _bone_mesh(arm, f"bones{i}", words, (bones, fingers))
        pose = {b.name: arm.matrix_world @ b.head for b in arm.pose.bones}
        hips = pose[hips_name]
        left = next(v for k, v in pose.items() if k.endswith("LeftUpLeg")) - next(
            v for k, v in pose.items() if k.endswith("RightUpLeg"))
        forward = left.cross(Vector((0.0, 0.0, 1.0)))
        turn = -0.5 * math.pi - math.atan2(forward.y, forward.x)   # the hips' line across the view
        move = (Matrix.Translation(Vector((spot, 0.0, 0.0))) @ Matrix.Rotation(turn, 4, "Z")
                @ Matrix.Translation(Vector((-hips.x, -hips.y, 0.0))))
        for obj in (snapshot, skeleton):
            obj.data.transform(move)
        if i == 0:
            points = [move @ v for k, v in pose.items() if k.startswith(hand)]
            hand_point = sum(points, Vector()) / len(points)
    arm.hide_render = body.hide_render = True
    lo, hi = -1.0, spots[-1] + 0.55
    ground = bpy.data.meshes.new("ground")
    ground.from_pydata([(lo - 30, -30.0, 0.0), (hi + 30, -30.0, 0.0), (hi + 30, 30.0, 0.0),
                        (lo - 30, 30.0, 0.0)], [], [(0, 1, 2, 3)])
    ground.materials.append(_material("ground", (0.42, 0.42, 0.4)))
    scene.collection.objects.link(bpy.data.objects.new("ground", ground))
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(35.0), 0.0, math.radians(-25.0))
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("sky")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.75, 0.8, 0.88, 1.0)
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.45
    scene.world = world
    view = bpy.data.objects.new("view", bpy.data.cameras.new("view"))
    scene.collection.objects.link(view)
    scene.camera = view
    centre = Vector(((lo + hi) / 2, 0.0, 0.92))
    view.data.type = "ORTHO"
    view.data.ortho_scale = max(hi - lo + 0.3, 2.1 * width / height)
    _look(view, centre + Vector((1.2, -6.0, 1.6)), centre)
    scene.view_settings.view_transform = "Standard"
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 24
    scene.cycles.use_denoising = True
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.filepath = png
    bpy.ops.render.render(write_still=True)
    view.data.type = "PERSP"
    view.data.lens = 50.0
    _look(view, hand_point + Vector((0.03, -0.55, 0.42)), hand_point)
    scene.render.resolution_x = height * 2 // 3
    scene.render.filepath = png + ".hand.png"
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    command, *args = sys.argv[1:]
    if command == "fbx":
        export_fbx(args[0], args[1], float(args[2]), int(args[3]), int(args[4]))
    elif command == "sample":
        sample(args[0], float(args[1]), int(args[2]), int(args[3]), args[4])
    elif command == "render":
        render(args[0], float(args[1]), int(args[2]), args[3])
    elif command == "rig":
        render_rig(args[0], float(args[1]), args[2], args[3], args[4], int(args[5]), int(args[6]))
    else:
        raise SystemExit(f"unknown command {command!r}")
