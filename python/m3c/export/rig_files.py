"""Files of the rig exports (`m3c export --rig RIG --format glb|fbx|usd`): one file per track, the track's
motion retargeted by m3c.export.rigs onto the rig's skeleton, keys from time 0 (the track's first frame, or
the reference pose) at the results' fps.

- GLB (pygltflib): the rig's bones as joint nodes under a node `<rig>_track<ID>` (rest translation and
  rotation of each bone relative to its parent, animated rotations, the pelvis's animated translation), the
  performer's mesh in the rig's rest pose skinned to the bones (at most 4 influences), one animation named
  after the rig.
- FBX: that GLB converted by Blender's FBX exporter (as `--format fbx`; needs Blender's bpy).
- USD (usd-core's pxr.UsdSkel, text .usda): a SkelRoot with a Skeleton (joint paths from the bone names, `:`
  written `_`; the true names in jointNames; bind and rest transforms) and a SkelAnimation (per-joint local
  translations, rotations, scales per time code, one per frame). The mesh is not written to USD. Stage: y up,
  metersPerUnit 1, timeCodesPerSecond the results' fps.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from m3c.export.rigs import RigMotion, retarget
from m3c.export.source import ExportSource, TrackMotion, finger_skeleton, finger_skin, per_track_paths
from m3c.io.atomic import atomic_path

USD_HINT = "pip install usd-core (or pip install m3c[usd]; scripts/setup.sh installs it)"


class UsdUnavailable(ImportError):
    """usd-core (the pxr module) is not installed."""


def track_rig_motion(source: ExportSource, track: TrackMotion, rig: str, **options) -> RigMotion:
    """The track retargeted onto `rig`; options: root_motion, smoothing, foot_lock, reference_pose."""
    model = source.model
    rest_mesh = model.forward(np.zeros((1, 24, 3)), track.betas).vertices[0]
    contacts = source.arrays["contacts"][track.index, track.frames] if "contacts" in source.arrays else None
    fingers = finger_skeleton(track)   # None: the results hold no hand poses; the rig then has no fingers
    skin = np.asarray(model.data.weights) if fingers is None else finger_skin(track, model.data.weights)
    return retarget(rig, track.rest_joints, track.pose, track.root_positions, source.fps, rest_mesh, skin,
                    contacts, frames=track.frames, fingers=fingers, **options)


def _write_glb(source: ExportSource, track: TrackMotion, motion: RigMotion, path: Path) -> None:
    import pygltflib as gl

    from m3c.export.gltf import _Builder, continuous_quaternions, top_influences
    from m3c.viz.scene import track_colour

    b = _Builder()
    b.gltf.asset.generator = f"M3C (m3c export --rig {motion.rig.name})"
    animation = gl.Animation(name=motion.rig.name)
    first = len(b.gltf.nodes)
    rest_quat = continuous_quaternions(motion.rest_rotations[None])[0]
    for i, name in enumerate(motion.names):
        b.node(name=name, translation=[float(v) for v in motion.rest_translations[i]],
               rotation=[float(v) for v in rest_quat[i]])
    for i, p in enumerate(motion.parents):
        if p >= 0:
            b.gltf.nodes[first + p].children.append(first + i)
    joints = list(range(first, first + len(motion.names)))
    rest_world = np.tile(np.eye(4), (len(joints), 1, 1))
    rest_world[:, :3, :3], rest_world[:, :3, 3] = motion.rest_frames, motion.rest_positions
    inverse_bind = np.linalg.inv(rest_world)
    prefix = f"{motion.rig.name}_track{track.track_id}"
    b.gltf.skins.append(gl.Skin(name=prefix, joints=joints, skeleton=first, inverseBindMatrices=b.accessor(
        inverse_bind.transpose(0, 2, 1).astype(np.float32), "MAT4")))
    influences, weights = top_influences(motion.weights)
    mesh = b.mesh(f"{prefix}_body", motion.rest_vertices, np.asarray(source.model.faces),
                  b.material(prefix, track_colour(track.track_id)), influences, weights)
    body = b.node(name=f"{prefix}_body", mesh=mesh, skin=0)
    person = b.node(name=prefix, children=[first])
    times = b.accessor((np.arange(len(motion.frames)) / source.fps).astype(np.float32), "SCALAR", bounds=True)
    b.animate(animation, first + motion.translation_bone, "translation", times, motion.translations)
    quat = continuous_quaternions(motion.rotations)
    for i in range(len(joints)):
        b.animate(animation, first + i, "rotation", times, quat[:, i])
    b.gltf.animations.append(animation)
    b.gltf.scenes.append(gl.Scene(name=prefix, nodes=[person, body]))
    b.gltf.scene = 0
    b.save(path)


def _usd_joint_paths(motion: RigMotion) -> list[str]:
    safe = [n.replace(":", "_").replace(".", "_").replace("-", "_") for n in motion.names]
    paths = []
    for i, p in enumerate(motion.parents):
        paths.append(safe[i] if p < 0 else f"{paths[p]}/{safe[i]}")
    return paths


def _usd_matrix(R: np.ndarray, t: np.ndarray):
    """A Gf.Matrix4d of x -> R x + t (USD's row-vector convention: R transposed, t in the last row)."""
    from pxr import Gf

    m = np.eye(4)
    m[:3, :3], m[3, :3] = R.T, t
    return Gf.Matrix4d(m.tolist())


def _write_usd(source: ExportSource, track: TrackMotion, motion: RigMotion, path: Path) -> None:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt
    from scipy.spatial.transform import Rotation

    with atomic_path(path) as tmp:
        stage = Usd.Stage.CreateNew(str(tmp))   # tmp ends in .usda: the text format
        UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
        UsdGeom.SetStageMetersPerUnit(stage, 1.0)
        n = len(motion.frames)
        stage.SetTimeCodesPerSecond(source.fps)
        stage.SetFramesPerSecond(source.fps)
        stage.SetStartTimeCode(0)
        stage.SetEndTimeCode(n - 1)
        prefix = f"{motion.rig.name}_track{track.track_id}"
        root = UsdSkel.Root.Define(stage, f"/{prefix}")
        stage.SetDefaultPrim(root.GetPrim())
        skel = UsdSkel.Skeleton.Define(stage, f"/{prefix}/Skeleton")
        joints = _usd_joint_paths(motion)
        skel.CreateJointsAttr(Vt.TokenArray(joints))
        skel.CreateJointNamesAttr(Vt.TokenArray(motion.names))
        skel.CreateBindTransformsAttr(Vt.Matrix4dArray([_usd_matrix(R, t) for R, t in
                                                        zip(motion.rest_frames, motion.rest_positions)]))
        rest = zip(motion.rest_rotations, motion.rest_translations)
        skel.CreateRestTransformsAttr(Vt.Matrix4dArray([_usd_matrix(R, t) for R, t in rest]))
        anim = UsdSkel.Animation.Define(stage, f"/{prefix}/Skeleton/Motion")
        anim.CreateJointsAttr(Vt.TokenArray(joints))
        translations, rotations = anim.CreateTranslationsAttr(), anim.CreateRotationsAttr()
        anim.CreateScalesAttr().Set(Vt.Vec3hArray([Gf.Vec3h(1, 1, 1)] * len(joints)))
        quat = Rotation.from_matrix(motion.rotations.reshape(-1, 3, 3)).as_quat().reshape(n, -1, 4)
        local_t = np.tile(motion.rest_translations, (n, 1, 1))
        local_t[:, motion.translation_bone] = motion.translations
        for k in range(n):
            translations.Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, v)) for v in local_t[k]]), Usd.TimeCode(k))
            rotations.Set(Vt.QuatfArray([Gf.Quatf(float(q[3]), float(q[0]), float(q[1]), float(q[2]))
                                         for q in quat[k]]), Usd.TimeCode(k))
        binding = UsdSkel.BindingAPI.Apply(skel.GetPrim())
        binding.CreateAnimationSourceRel().SetTargets([Sdf.Path(anim.GetPath())])
        UsdSkel.BindingAPI.Apply(root.GetPrim()).CreateSkeletonRel().SetTargets([Sdf.Path(skel.GetPath())])
        stage.GetRootLayer().Save()


def check_usd() -> None:
    try:
        import pxr.UsdSkel  # noqa: F401
    except ImportError:
        raise UsdUnavailable("USD export needs usd-core's pxr module, not found; install it with "
                             f"{USD_HINT}") from None


def export_rig(source: ExportSource, out: Path, rig: str, fmt: str = "glb", **options) -> list[Path]:
    """One file per selected track on `rig`: out/<rig>_track<ID>.<ext> (out itself for one track and a file
    name with the format's suffix). fmt: glb, fbx or usd (.usda). options: see track_rig_motion."""
    suffix = {"glb": ".glb", "fbx": ".fbx", "usd": ".usda"}[fmt]
    if fmt == "usd":
        check_usd()
        if out.suffix.lower() == ".usd":
            out = out.with_suffix(".usda")
    if fmt == "fbx":
        from m3c.export.blender import blender_python

        blender_python()  # fail before any work when Blender is missing
    paths = per_track_paths(source, out, suffix, rig)
    for track, path in zip(source.tracks, paths):
        motion = track_rig_motion(source, track, rig, **options)
        path.parent.mkdir(parents=True, exist_ok=True)
        if fmt == "glb":
            _write_glb(source, track, motion, path)
        elif fmt == "usd":
            _write_usd(source, track, motion, path)
        else:
            from m3c.export.blender import run_blender

            with tempfile.TemporaryDirectory(prefix="m3c-rig-") as tmp:
                glb = Path(tmp) / "rig.glb"
                _write_glb(source, track, motion, glb)
                with atomic_path(path) as fbx:
                    run_blender("fbx", glb, fbx, repr(source.fps), *source.image_size)
    return paths
