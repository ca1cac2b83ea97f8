"""glTF 2.0 binary (GLB) export, written with pygltflib: every person as a skinned mesh, the ground plane, and the
video camera as an animated perspective camera, all driven by one animation ("m3c") so that importers which
activate only a file's first animation (Blender) play everything.

Axes and units: glTF's own, y up, metres, right-handed; the results' world frame is already that (+z is the
first camera's viewing direction along the ground), so coordinates are copied as they are. Keyframe k of a
track is at time frame / fps (seconds) with frame the processed frame index, so a track that starts late starts
late in the animation; before its first and after its last frame a person is hidden (its node is scaled to 0,
stepped keys).

Per person: the body model's mesh at the track's betas in the rest pose (no pose blend shapes: glTF has no
pose correctives), the 24 SMPL joints as nodes (rest translation = offset from the parent, animated rotation =
the joint's rotation relative to its parent, the root's translation animated), and at most 4 skinning
influences per vertex (the model's largest 4 weights, renormalised to sum to 1, as glTF requires). Where the
results hold hand poses (the open model's hands), 30 SMPL-H finger joints follow below the wrists, animated
the same way, and the hand vertices are skinned to them (m3c.body.hands).
The camera: glTF cameras look down their local -z with y up; M3C's are OpenCV (z forward, y down), so each
pose is world_from_cam @ diag(1, -1, -1). The field of view is the vertical one of fy and the aspect ratio the
image's; glTF cannot hold a principal point off the image centre or fx != fy.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pygltflib as gl
from scipy.spatial.transform import Rotation

from m3c.export.source import ExportSource, TrackMotion, finger_skeleton, finger_skin
from m3c.io.atomic import atomic_path
from m3c.viz.raster import vertex_normals
from m3c.viz.scene import track_colour

MAX_INFLUENCES = 4
GL_FROM_CV = np.diag([1.0, -1.0, -1.0])  # camera axes: OpenCV (x right, y down, z forward) -> glTF (y up, -z forward)
ANIMATION_NAME = "m3c"
_TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}
_COMPONENTS = {np.dtype(np.float32): gl.FLOAT, np.dtype(np.uint8): gl.UNSIGNED_BYTE,
               np.dtype(np.uint16): gl.UNSIGNED_SHORT, np.dtype(np.uint32): gl.UNSIGNED_INT}


def top_influences(weights: np.ndarray, k: int = MAX_INFLUENCES) -> tuple[np.ndarray, np.ndarray]:
    """(joints (V, k) uint8, weights (V, k) float32): each vertex's k largest skinning weights, renormalised."""
    order = np.argsort(-weights, axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(weights, order, axis=1)
    total = top.sum(axis=1, keepdims=True)
    if np.any(total <= 0):
        raise ValueError("the body model has vertices without skinning weights")
    return order.astype(np.uint8), (top / total).astype(np.float32)


def continuous_quaternions(rotations: np.ndarray) -> np.ndarray:
    """(n, ..., 3, 3) rotation matrices -> (n, ..., 4) quaternions x, y, z, w, signs chosen along the first axis
    so that consecutive keys are on the same hemisphere (q and -q are the same rotation; slerp takes the short
    way only then)."""
    shape = rotations.shape[:-2]
    quat = Rotation.from_matrix(rotations.reshape(-1, 3, 3)).as_quat().reshape(*shape, 4)
    for i in range(1, len(quat)):
        flip = np.sum(quat[i] * quat[i - 1], axis=-1) < 0
        quat[i][flip] *= -1
    return quat


class _Builder:
    """Accumulates buffer views and accessors in one binary blob."""

    def __init__(self):
        self.gltf = gl.GLTF2(asset=gl.Asset(generator="M3C (m3c export --format glb)", version="2.0"))
        self.blob = bytearray()

    def accessor(self, array: np.ndarray, kind: str, target: int | None = None, bounds: bool = False) -> int:
        array = np.ascontiguousarray(array)
        if array.dtype == np.float64:
            array = array.astype(np.float32)
        count = array.size // _TYPE_SIZES[kind]
        while len(self.blob) % 4:
            self.blob.append(0)
        offset = len(self.blob)
        self.blob.extend(array.tobytes())
        self.gltf.bufferViews.append(gl.BufferView(buffer=0, byteOffset=offset, byteLength=array.nbytes,
                                                   target=target))
        flat = array.reshape(count, -1)
        accessor = gl.Accessor(bufferView=len(self.gltf.bufferViews) - 1, componentType=_COMPONENTS[array.dtype],
                               count=count, type=kind)
        if bounds:
            accessor.min = [float(v) for v in flat.min(axis=0)]
            accessor.max = [float(v) for v in flat.max(axis=0)]
        self.gltf.accessors.append(accessor)
        return len(self.gltf.accessors) - 1

    def node(self, **kwargs) -> int:
        self.gltf.nodes.append(gl.Node(**kwargs))
        return len(self.gltf.nodes) - 1

    def material(self, name: str, colour, double_sided: bool = False) -> int:
        self.gltf.materials.append(gl.Material(
            name=name, doubleSided=double_sided,
            pbrMetallicRoughness=gl.PbrMetallicRoughness(baseColorFactor=[*map(float, colour), 1.0],
                                                         metallicFactor=0.0, roughnessFactor=0.8)))
        return len(self.gltf.materials) - 1

    def mesh(self, name: str, vertices, faces, material: int, joints=None, weights=None) -> int:
        attributes = gl.Attributes(
            POSITION=self.accessor(vertices.astype(np.float32), "VEC3", gl.ARRAY_BUFFER, bounds=True),
            NORMAL=self.accessor(vertex_normals(vertices, faces).astype(np.float32), "VEC3", gl.ARRAY_BUFFER))
        if joints is not None:
            attributes.JOINTS_0 = self.accessor(joints, "VEC4", gl.ARRAY_BUFFER)
            attributes.WEIGHTS_0 = self.accessor(weights, "VEC4", gl.ARRAY_BUFFER)
        indices = self.accessor(faces.astype(np.uint32).reshape(-1), "SCALAR", gl.ELEMENT_ARRAY_BUFFER,
                                bounds=True)
        self.gltf.meshes.append(gl.Mesh(name=name, primitives=[gl.Primitive(attributes=attributes, indices=indices,
                                                                             material=material)]))
        return len(self.gltf.meshes) - 1

    def animate(self, animation: gl.Animation, node: int, path: str, times: int, values: np.ndarray,
                interpolation: str = "LINEAR") -> None:
        kind = {"translation": "VEC3", "rotation": "VEC4", "scale": "VEC3"}[path]
        animation.samplers.append(gl.AnimationSampler(input=times, output=self.accessor(values, kind),
                                                      interpolation=interpolation))
        animation.channels.append(gl.AnimationChannel(sampler=len(animation.samplers) - 1,
                                                      target=gl.AnimationChannelTarget(node=node, path=path)))

    def save(self, path: Path) -> None:
        self.gltf.buffers.append(gl.Buffer(byteLength=len(self.blob)))
        self.gltf.set_binary_blob(bytes(self.blob))
        with atomic_path(path) as tmp:
            self.gltf.save_binary(str(tmp))


def _add_person(b: _Builder, animation: gl.Animation, source: ExportSource, track: TrackMotion,
                hide_outside_track: bool) -> int:
    """The person's joints, skin and mesh; returns the person's node (the parent of its skeleton)."""
    model, parents, names = source.model, source.parents, source.joint_names
    rest = track.rest_joints
    prefix = f"track{track.track_id}"
    first = len(b.gltf.nodes)
    for j, name in enumerate(names):
        offset = rest[j] - (rest[parents[j]] if parents[j] >= 0 else 0.0)
        b.node(name=f"{prefix}_{name}", translation=[float(v) for v in offset])
    fingers = finger_skeleton(track)
    weights = np.asarray(model.data.weights)
    if fingers is not None:  # 30 finger joints below the wrists (m3c.body.hands), their vertices re-weighted
        parents = np.concatenate([parents, fingers.parents])
        rest = np.concatenate([rest, fingers.rest])
        for k, name in enumerate(fingers.names):
            offset = rest[24 + k] - rest[parents[24 + k]]
            b.node(name=f"{prefix}_{name}", translation=[float(v) for v in offset])
        weights = finger_skin(track, weights)
    for j in range(1, len(parents)):
        b.gltf.nodes[first + parents[j]].children.append(first + j)
    joint_nodes = list(range(first, first + len(parents)))
    # Inverse bind matrices: joint j's rest frame is a translation by its rest position (column-major in glTF).
    inverse_bind = np.tile(np.eye(4), (len(parents), 1, 1))
    inverse_bind[:, :3, 3] = -rest
    b.gltf.skins.append(gl.Skin(name=prefix, joints=joint_nodes, skeleton=first,
                                inverseBindMatrices=b.accessor(inverse_bind.transpose(0, 2, 1).astype(np.float32),
                                                               "MAT4")))
    vertices = model.forward(np.zeros((1, 24, 3)), track.betas).vertices[0]
    joints, weights = top_influences(weights)
    mesh = b.mesh(f"{prefix}_body", vertices, np.asarray(model.faces), b.material(prefix,
                  track_colour(track.track_id)), joints, weights)
    b.node(name=f"{prefix}_body", mesh=mesh, skin=len(b.gltf.skins) - 1)

    # A node per person above its skeleton: importers (Blender) then make one armature per person.
    person = b.node(name=prefix, children=[first])
    if hide_outside_track:
        _animate_presence(b, animation, person, track, source)
    times = b.accessor((track.frames / source.fps).astype(np.float32), "SCALAR", bounds=True)
    b.animate(animation, first, "translation", times, track.root_positions)
    local = Rotation.from_rotvec(track.pose.reshape(-1, 3)).as_matrix().reshape(len(track.frames), 24, 3, 3)
    quat = continuous_quaternions(local)
    for j in range(len(names)):
        b.animate(animation, first + j, "rotation", times, quat[:, j])
    if fingers is not None:
        rotations = Rotation.from_rotvec(fingers.pose.reshape(-1, 3)).as_matrix()
        quat = continuous_quaternions(rotations.reshape(len(track.frames), 30, 3, 3))
        for k in range(30):
            b.animate(animation, first + 24 + k, "rotation", times, quat[:, k])
    return person


def _animate_presence(b: _Builder, animation: gl.Animation, person: int, track: TrackMotion,
                      source: ExportSource) -> None:
    """Scale 0 before the track's first and after its last frame, 1 in between (stepped): a person is shown only
    while tracked. Nothing when the track spans the whole video."""
    first, last = int(track.frames[0]), int(track.frames[-1])
    keys = [(0.0, 0.0), (first, 1.0)] if first > 0 else [(0.0, 1.0)]
    if last < source.num_frames - 1:
        keys.append((last + 1, 0.0))
    if len(keys) == 1:
        return
    times = b.accessor(np.array([k / source.fps for k, _ in keys], np.float32), "SCALAR", bounds=True)
    b.animate(animation, person, "scale", times, np.array([[v, v, v] for _, v in keys], np.float32), "STEP")


def _add_camera(b: _Builder, animation: gl.Animation, source: ExportSource) -> int:
    width, height = source.image_size
    b.gltf.cameras.append(gl.Camera(name="video_camera", type="perspective", perspective=gl.Perspective(
        yfov=source.vertical_fov, aspectRatio=width / height, znear=0.01, zfar=1000.0)))
    world_from_cam = source.arrays["world_from_cam"].astype(np.float64)
    node = b.node(name="video_camera", camera=len(b.gltf.cameras) - 1)
    times = b.accessor((np.arange(len(world_from_cam)) / source.fps).astype(np.float32), "SCALAR", bounds=True)
    b.animate(animation, node, "translation", times, world_from_cam[:, :3, 3])
    b.animate(animation, node, "rotation", times, continuous_quaternions(world_from_cam[:, :3, :3] @ GL_FROM_CV))
    return node


def _add_ground(b: _Builder, source: ExportSource) -> int:
    lo, hi = source.ground_extent()
    vertices = np.array([[lo[0], 0.0, lo[1]], [hi[0], 0.0, lo[1]], [hi[0], 0.0, hi[1]], [lo[0], 0.0, hi[1]]])
    faces = np.array([[0, 2, 1], [0, 3, 2]])  # counter-clockwise seen from above (+y)
    mesh = b.mesh("ground", vertices, faces, b.material("ground", [0.75, 0.75, 0.72], double_sided=True))
    return b.node(name="ground", mesh=mesh)


def export_glb(source: ExportSource, out: Path, hide_outside_track: bool = True) -> list[Path]:
    """One .glb with every selected person, the ground (when the run found one: y = 0) and the camera.
    hide_outside_track: scale people to 0 outside their tracks (else they hold their first/last pose there)."""
    if out.suffix.lower() != ".glb":
        out = out / "scene.glb"
    b = _Builder()
    animation = gl.Animation(name=ANIMATION_NAME)
    roots = []
    for track in source.tracks:
        roots.append(_add_person(b, animation, source, track, hide_outside_track))
    bodies = [i for i, n in enumerate(b.gltf.nodes) if n.mesh is not None]
    scene_nodes = roots + bodies + [_add_camera(b, animation, source)]
    if source.ground_found:
        scene_nodes.append(_add_ground(b, source))
    b.gltf.animations.append(animation)
    b.gltf.scenes.append(gl.Scene(name=source.folder.name or "m3c", nodes=scene_nodes))
    b.gltf.scene = 0
    b.save(out)
    return [out]
