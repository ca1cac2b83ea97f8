"""Property-based calls of every public bound function of m3c._core and of the Python wrappers over it, with random
dtypes (float16 .. longdouble, bool, signed and unsigned integers, complex, object, strings), shapes (valid, wrong,
empty, 2**40 rows as zero-stride views), memory layouts (Fortran order, strides, reversed, read-only, broadcast),
values (NaN, inf, huge) and non-array objects. Each call must either return the result the same function gives for
the canonical input (the arguments converted to C-contiguous float64 / int64 beforehand) or raise ValueError,
TypeError, MemoryError or OverflowError with a message: never crash, never raise anything else.

Run by test_bindings_fuzz.py in a child process with a fault handler, so that a crash fails that test (with the
case printed just before it) instead of killing pytest:  python fuzz_core.py GROUP MAX_EXAMPLES [WEIGHTS_DIR]
"""

from __future__ import annotations

import faulthandler
import sys
import warnings
from dataclasses import dataclass, fields, is_dataclass
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

faulthandler.enable()
warnings.simplefilter("ignore")  # numpy's cast and overflow warnings on the hostile inputs are expected

ALLOWED = (ValueError, TypeError, MemoryError, OverflowError)
HUGE = 2 ** 40  # rows of a zero-stride view: any copy of it exceeds every machine's memory, so it must be refused
DTYPES = [np.float64, np.float64, np.float32, np.float16, np.longdouble, np.bool_, np.int8, np.int32, np.int64,
          np.uint8, np.uint16, np.uint64, np.complex128, object, "U3"]


@dataclass
class Arg:
    name: str
    shape: tuple  # the valid shape
    kind: str = "float"  # float | int | bool | u8: what the canonical conversion makes of it
    optional: bool = False
    scale: float = 1.0  # magnitude of valid values
    low: float | None = None  # valid values are clipped to [low, high]
    high: float | None = None


@st.composite
def argument(draw, spec: Arg):
    """A hostile or valid value for one argument."""
    what = draw(st.sampled_from(["valid"] * 6 + ["random_shape", "empty", "huge", "scalar", "list", "none", "ragged",
                                                 "string"]))
    if what == "none":
        return None
    if what == "string":
        return "not an array"
    if what == "ragged":
        return [[0.0, 1.0], [2.0]]
    shape = tuple(spec.shape)
    if what == "random_shape":
        shape = tuple(draw(st.lists(st.integers(0, 5), max_size=4)))
    elif what == "empty" and shape:
        shape = (0,) + shape[1:]
    elif what == "scalar":
        shape = ()
    seed = draw(st.integers(0, 2 ** 32 - 1))
    rng = np.random.default_rng(seed)
    magnitude = draw(st.sampled_from([1.0, 1.0, 1.0, 1e3, 1e30, 1e300]))
    values = np.asarray(rng.standard_normal(shape)) * spec.scale * magnitude
    if spec.low is not None or spec.high is not None:
        values = np.asarray(np.clip(values, spec.low, spec.high))
    if spec.kind in ("int", "bool"):
        values = np.asarray(np.round(np.abs(values)) if spec.low is not None and spec.low >= 0 else np.round(values))
    if spec.kind == "u8":
        values = np.asarray(rng.integers(0, 256, shape), dtype=np.float64)
    special = draw(st.sampled_from(["none"] * 4 + ["nan", "inf", "-inf"]))
    if special != "none" and values.size:
        values.flat[int(rng.integers(values.size))] = {"nan": np.nan, "inf": np.inf, "-inf": -np.inf}[special]
    default = {"float": np.float64, "int": np.int64, "bool": np.bool_, "u8": np.uint8}[spec.kind]
    dtype = draw(st.sampled_from([default] * 4 + DTYPES))
    with np.errstate(all="ignore"):
        if dtype == "U3" or dtype is object:
            array = values.astype(dtype)
        elif np.dtype(dtype).kind in "iu":
            info = np.iinfo(dtype)
            array = np.nan_to_num(np.clip(values, info.min, info.max)).astype(dtype)
        else:
            array = values.astype(dtype)
    array = np.asarray(array)  # 0-d results of numpy functions come back as scalars
    layout = draw(st.sampled_from(["C", "C", "F", "strided", "reversed", "readonly", "broadcast"]))
    if what == "huge" and array.ndim:
        return np.broadcast_to(array[:1] if len(array) else np.zeros((1,) + array.shape[1:], array.dtype),
                               (HUGE,) + array.shape[1:])
    if layout == "F":
        array = np.asfortranarray(array)
    elif layout == "strided" and array.ndim:
        array = np.repeat(array, 2, axis=0)[::2]
    elif layout == "reversed" and array.ndim:
        array = array[::-1]
    elif layout == "readonly":
        array.setflags(write=False)
    elif layout == "broadcast" and array.ndim and len(array):
        array = np.broadcast_to(array[:1], array.shape)
    if what == "list":
        return array.tolist()
    return array


def canonical(value, spec: Arg):
    """The argument as the conversion layer should see it: C-contiguous float64 / int64 / bool / uint8."""
    if value is None or isinstance(value, str):
        return value
    dtype = {"float": np.float64, "int": np.int64, "bool": np.bool_, "u8": np.uint8}[spec.kind]
    return np.array(value, dtype=dtype, order="C")


def flatten(result) -> list[np.ndarray]:
    """Every array of a result, without timings (which differ from call to call)."""
    if isinstance(result, dict):
        return [a for k in sorted(result) if "seconds" not in k for a in flatten(result[k])]
    if isinstance(result, (list, tuple)):
        return [a for item in result for a in flatten(item)]
    if is_dataclass(result):
        return [a for f in fields(result) if f.name != "stats" for a in flatten(getattr(result, f.name))]
    if isinstance(result, (str, type(None))):
        return []
    return [np.asarray(result)]


def same(got, want, tolerant: bool) -> None:
    got, want = flatten(got), flatten(want)
    assert len(got) == len(want), (len(got), len(want))
    for g, w in zip(got, want):
        assert g.shape == w.shape, (g.shape, w.shape)
        if g.dtype.kind in "fc" and (tolerant or g.dtype != w.dtype):
            # float32 arithmetic: errors relative to the largest value, and overflow where float64 has none.
            g, w = g.astype(np.float64), w.astype(np.float64)
            keep = np.isfinite(w) & (np.abs(w) < 1e30)
            scale = max(1.0, float(np.abs(w[keep]).max())) if keep.any() else 1.0
            np.testing.assert_allclose(g[keep], w[keep], rtol=1e-4, atol=1e-4 * scale)
        else:
            np.testing.assert_array_equal(g, w)


def low_precision(value) -> bool:
    """The core may compute this input in float32, so compare with a tolerance."""
    return isinstance(value, np.ndarray) and value.dtype.kind == "f" and value.dtype.itemsize <= 4


def all_finite(values) -> bool:
    for v in values:
        if isinstance(v, np.ndarray) and v.dtype.kind in "fc" and not np.isfinite(v).all():
            return False
    return True


def check(call, specs: list[Arg], data, tag: str, finite: bool = False) -> None:
    """finite: a successful call returns finite arrays (no silent NaN/inf)."""
    values = {s.name: data.draw(argument(s), label=s.name) for s in specs}
    print(f"CASE {tag}: " + ", ".join(f"{k}={describe(v)}" for k, v in values.items()), flush=True)
    try:
        got = call(**values)
    except ALLOWED as err:
        assert str(err), f"{type(err).__name__} without a message"
        return
    if finite:
        assert all_finite(flatten(got)), "a call that succeeded returned NaN or inf"
    # It succeeded: the canonical input must give the same result.
    canon = {s.name: canonical(values[s.name], s) for s in specs}
    want = call(**canon)
    same(got, want, any(low_precision(v) for v in values.values()))


def describe(v) -> str:
    if isinstance(v, np.ndarray):
        return f"array(dtype={v.dtype}, shape={v.shape}, strides={v.strides}, c={v.flags.c_contiguous})"
    return type(v).__name__


def run(group_tests, max_examples: int) -> None:
    for name, test in group_tests:
        wrapped = settings(max_examples=max_examples, deadline=None, database=None, derandomize=True,
                           suppress_health_check=list(HealthCheck))(given(st.data())(test))
        print(f"TARGET {name}", flush=True)
        wrapped()


# --- targets -----------------------------------------------------------------------------------------------------
def body_tests(weights_dir):
    from m3c import _core
    from m3c.body import BodyModel
    from m3c.body.synthetic import make_synthetic_model

    data = make_synthetic_model(vertices_per_bone=2)
    model = BodyModel(data)
    J, V, B = model.num_joints, model.num_vertices, model.num_betas
    regressor = model.regressor(np.eye(3, V), np.eye(3, J))
    pose_args = [Arg("pose", (2, J, 3), scale=0.5), Arg("betas", (B,)), Arg("transl", (3,), optional=True)]

    def forward(d):
        check(lambda pose, betas, transl: model.forward(pose, betas, transl), pose_args, d, "forward", finite=True)

    def joints(d):
        check(lambda pose, betas, transl: model.joints(pose, betas, transl), pose_args, d, "joints", finite=True)

    def keypoints(d):
        check(lambda pose, betas, transl: model.keypoints(regressor, pose, betas, transl), pose_args, d,
              "keypoints", finite=True)

    def jacobians(d):
        check(lambda pose, betas, transl: (model.keypoints_jacobian(regressor, pose, betas, transl),
                                           model.joints_jacobian(pose, betas, transl)), pose_args, d, "jacobians",
              finite=True)

    def construct(d):
        specs = [Arg("v_template", (V, 3)), Arg("shapedirs", (V, 3, B)), Arg("posedirs", (V, 3, 9 * (J - 1))),
                 Arg("J_regressor", (J, V), low=0, high=1), Arg("weights", (V, J), low=0, high=1),
                 Arg("parents", (J,), kind="int", low=-1, high=J - 1), Arg("faces", (4, 3), kind="int", low=0,
                                                                            high=V - 1)]
        # Most draws keep the real tree and weights, so that the constructor's success path is reached.
        def build(v_template, shapedirs, posedirs, J_regressor, weights, parents, faces):
            m = _core.BodyModel(v_template, shapedirs, posedirs, J_regressor, weights, parents, faces)
            return _core.forward_kinematics(m, np.zeros((1, m.num_joints, 3)), np.zeros(m.num_betas))
        pick = d.draw(st.sampled_from(["all", "parents", "faces", "weights"]))
        real = {"v_template": data.v_template, "shapedirs": data.shapedirs, "posedirs": data.posedirs,
                "J_regressor": data.J_regressor, "weights": data.weights, "parents": data.parents,
                "faces": data.faces}
        chosen = [s for s in specs if pick == "all" or s.name == pick]
        check(lambda **kw: build(**{**real, **kw}), chosen, d, f"BodyModel({pick})")

    def regressors(d):
        specs = [Arg("vertex_weights", (3, V)), Arg("joint_weights", (3, J))]
        check(lambda vertex_weights, joint_weights: _core.keypoints(
            model._core, _core.KeypointRegressor(model._core, vertex_weights, joint_weights),
            np.zeros((1, J, 3)), np.zeros(B)), specs, d, "KeypointRegressor")

    return [("forward", forward), ("joints", joints), ("keypoints", keypoints), ("jacobians", jacobians),
            ("BodyModel", construct), ("KeypointRegressor", regressors)]


def ground_tests(weights_dir):
    from m3c import _core
    from m3c.ground import GroundParams, dbscan, fit_plane, frame_planes

    def cluster(d):
        eps = d.draw(st.sampled_from([0.1, 0.5, 0.0, -1.0, np.nan, np.inf, 1e300]), label="eps")
        min_samples = d.draw(st.sampled_from([1, 3, 0, -5, 2 ** 31 - 1]), label="min_samples")
        check(lambda points: dbscan(points, eps, min_samples, return_core=True), [Arg("points", (30, 3))], d,
              f"dbscan(eps={eps}, min_samples={min_samples})")

    def plane(d):
        specs = [Arg("points", (40, 3), scale=0.3), Arg("up", (3,))]
        robust = d.draw(st.booleans(), label="robust")
        check(lambda points, up: fit_plane(points, up=up, robust=robust, min_support=5), specs, d, "fit_plane")

    def frames(d):
        specs = [Arg("points", (40, 3), scale=0.3), Arg("person", (40,), kind="int", low=0, high=2),
                 Arg("is_foot", (40,), kind="bool", low=0, high=1), Arg("up", (3,))]
        params = GroundParams(min_samples=3, min_support=5)
        check(lambda points, person, is_foot, up: frame_planes(points, person, is_foot, up=up, num_people=3,
                                                               params=params), specs, d, "frame_planes")

    def tracks(d):
        specs = [Arg("points", (40, 3), scale=0.3), Arg("point_track", (40,), kind="int", low=0, high=1),
                 Arg("point_step", (40,), kind="int", low=0, high=3), Arg("is_foot", (40,), kind="bool", low=0,
                                                                           high=1),
                 Arg("up", (3,))]
        frame_ids = [np.arange(4), np.arange(10, 14)]
        options = GroundParams(min_samples=3, min_support=5).core_options()
        check(lambda points, point_track, point_step, is_foot, up: _core.track_planes(
            points, point_track, point_step, is_foot, frame_ids, up, options), specs, d, "track_planes")

    return [("dbscan", cluster), ("fit_plane", plane), ("frame_planes", frames), ("track_planes", tracks)]


def vo_tests(weights_dir):
    from m3c.vo import VisualOdometry, VOConfig, run_vo
    from m3c.vo.synthetic import forward_trajectory, render_sequence

    seq = render_sequence(forward_trajectory(4, length=0.3), width=48, height=40, seed=1)
    config = VOConfig(final_iterations=2, init_iterations=2, window_iterations=1)

    def batch(d):
        specs = [Arg("masks", (4, 40, 48), kind="bool", low=0, high=1, optional=True),
                 Arg("depths", (4, 40, 48), low=0.5, high=5.0, optional=True),
                 Arg("intrinsics", (4,), low=10, high=100, optional=True)]
        check(lambda masks, depths, intrinsics: run_vo(seq.frames, masks, depths, intrinsics, config), specs, d,
              "run_vo")

    def frames(d):
        check(lambda frames: run_vo(frames, config=config), [Arg("frames", (4, 40, 48), kind="u8")], d,
              "run_vo frames")

    def stream(d):
        specs = [Arg("frame", (40, 48), kind="u8"), Arg("mask", (40, 48), kind="bool", low=0, high=1),
                 Arg("depth", (40, 48), low=0.5, high=5.0)]

        def go(frame, mask, depth):
            vo = VisualOdometry(config=config)
            vo.add_frame(seq.frames[0])
            vo.add_frame(frame, mask, depth)
            vo.add_frame(seq.frames[2])
            return vo.finish()
        check(go, specs, d, "VisualOdometry")

    return [("run_vo", batch), ("run_vo frames", frames), ("VisualOdometry", stream)]


def nn_tests(weights_dir):
    from m3c.nn import HumorPrior, VPoser, build_humor_states, canonicalize, read_safetensors

    humor = HumorPrior(Path(weights_dir) / "humor.safetensors")
    vposer = VPoser(Path(weights_dir) / "vposer.safetensors")

    def transitions(d):
        specs = [Arg("x_prev", (3, 339), scale=0.3), Arg("x_next", (3, 339), scale=0.3)]
        grad = d.draw(st.booleans(), label="with_gradient")
        check(lambda x_prev, x_next: humor.transition_nll(x_prev, x_next, grad), specs, d, "transition_nll")

    def latents(d):
        specs = [Arg("x_prev", (3, 339), scale=0.3), Arg("z", (3, 48))]
        check(lambda x_prev, z: humor.latent_nll(x_prev, z, True), specs, d, "latent_nll")

    def networks(d):
        specs = [Arg("states", (4, 339), scale=0.3), Arg("pairs", (2, 678), scale=0.3)]
        check(lambda states, pairs: (humor.sequence_transition_nll(states), humor.prior_forward(states),
                                     humor.encoder_forward(pairs)), specs, d, "humor networks")

    def poses(d):
        specs = [Arg("z", (2, vposer.latent_dim)), Arg("pose_body", (2, 21, 3), scale=0.5)]
        check(lambda z, pose_body: (vposer.decode(z), vposer.encode(pose_body)), specs, d, "vposer")

    def states(d):
        specs = [Arg("trans", (5, 3)), Arg("root_orient", (5, 3)), Arg("pose_body", (5, 21, 3), scale=0.5),
                 Arg("joints", (5, 22, 3)), Arg("frame_from", (3, 339), scale=0.3), Arg("ground_R", (3, 3)),
                 Arg("ground_t", (3,))]

        def go(trans, root_orient, pose_body, joints, frame_from, ground_R, ground_t):
            ground = None if ground_R is None or ground_t is None else (ground_R, ground_t)
            x = build_humor_states(trans, root_orient, pose_body, joints, 30.0, ground)
            return x, canonicalize(x, frame_from)
        check(go, specs, d, "humor states")

    def files(d):
        content = d.draw(st.binary(max_size=64), label="content")
        path = Path(weights_dir) / "fuzz.safetensors"
        path.write_bytes(content)
        print(f"CASE read_safetensors: {content!r}", flush=True)
        try:
            read_safetensors(path)
        except ALLOWED:
            pass

    return [("transition_nll", transitions), ("latent_nll", latents), ("humor networks", networks),
            ("vposer", poses), ("humor states", states), ("read_safetensors", files)]


def fit_motion_tests(weights_dir):
    from m3c.body import BodyModel
    from m3c.body.synthetic import make_synthetic_model
    from m3c.motion import Cameras, OptimizerConfig, Track, optimize
    from m3c.perception.body import BodyFitConfig, fit_bodies

    model = BodyModel(make_synthetic_model(vertices_per_bone=2))
    regressor = model.regressor(joint_weights=np.eye(17, 24))
    fit_config = BodyFitConfig(max_iterations=2)
    config = OptimizerConfig.default()
    config.num_threads = 1  # deterministic, so a result can be compared with the canonical input's
    for stage in config.stages:
        stage.max_iterations = 1
    config.stages = config.stages[:2]
    n = 3

    def fits(d):
        specs = [Arg("keypoints", (n, 17, 3), scale=100, low=0), Arg("intrinsics", (4,), low=50, high=500),
                 Arg("keypoints3d", (n, 17, 4), optional=True), Arg("restart", (n,), kind="bool", low=0, high=1,
                                                                    optional=True),
                 Arg("times", (n,), low=0, high=10, optional=True)]
        check(lambda keypoints, intrinsics, keypoints3d, restart, times: fit_bodies(
            model, keypoints, intrinsics, keypoints3d, restart, fit_config, regressor, times), specs, d,
            "fit_bodies")

    def motion(d):
        specs = [Arg("keypoints", (n, 17, 3), scale=100, low=0), Arg("transl", (n, 3), low=-1, high=1),
                 Arg("root_orient", (n, 3), scale=0.3), Arg("body_pose", (n, 23, 3), scale=0.3),
                 Arg("betas", (10,)), Arg("world_from_cam", (n, 4, 4)), Arg("intrinsics", (4,), low=50, high=500)]

        def go(keypoints, transl, root_orient, body_pose, betas, world_from_cam, intrinsics):
            track = Track(0, keypoints, np.asarray(transl, dtype=float) + [0, 0, 4] if transl is not None else None,
                          root_orient, body_pose, betas)
            result = optimize(model, [track], Cameras(world_from_cam, intrinsics, static=True), config, regressor)
            return result.tracks, result.camera_scale
        check(go, specs, d, "optimize")

    return [("fit_bodies", fits), ("optimize", motion)]


def render_tests(weights_dir):
    from m3c import _core

    quad = [Arg("vertices", (4, 3), low=-1.0, high=3.0), Arg("faces", (2, 3), kind="int", low=0, high=3),
            Arg("light", (3,), low=-1.0, high=1.0), Arg("intrinsics", (4,), low=1.0, high=40.0)]

    def coloured(d):
        def draw(vertices, faces, light, intrinsics, face_rgb):
            frame = _core.RenderFrame(32, 24, np.zeros(3))
            frame.draw_coloured(intrinsics, vertices, faces, face_rgb, light, 0.4, 3, False)
            return frame.rgb, frame.depth, frame.ids
        check(draw, quad + [Arg("face_rgb", (2, 3), low=0.0, high=1.0)], d, "draw_coloured")

    def textured(d):
        def draw(vertices, faces, light, intrinsics, texture, uv):
            frame = _core.RenderFrame(32, 24, np.zeros(3))
            frame.draw_textured(intrinsics, vertices, faces, _core.Texture(texture), uv, light)
            return frame.rgb, frame.depth, frame.ids
        check(draw, quad + [Arg("texture", (4, 8, 3), low=0.0, high=1.0), Arg("uv", (4, 2), scale=20.0)], d,
              "draw_textured")

    def texture(d):
        check(lambda texture: np.array(_core.Texture(texture).sample(1.3, 2.7, 2.0)),
              [Arg("texture", (8, 4, 3), low=0.0, high=1.0)], d, "Texture")

    return [("draw_coloured", coloured), ("draw_textured", textured), ("Texture", texture)]


GROUPS = {"body": body_tests, "ground": ground_tests, "vo": vo_tests, "nn": nn_tests, "fit_motion": fit_motion_tests,
          "render": render_tests}

if __name__ == "__main__":
    group, max_examples = sys.argv[1], int(sys.argv[2])
    weights = sys.argv[3] if len(sys.argv) > 3 else None
    run(GROUPS[group](weights), max_examples)
    print("ALL PASSED", flush=True)
