"""The cases of issue 19 at the Python boundary of the C++ core, each in its own process (isolated.py): dtype mixes
numpy casts without loss give the result of the float64 computation, everything else a ValueError that names the
argument and its dtype; NaN/inf inputs and bad thread counts are refused instead of crashing."""

import pytest
from isolated import run_isolated

BODY = """
import numpy as np
from m3c.body import default_body_model
model = default_body_model()
rng = np.random.default_rng(0)
pose = (0.3 * rng.standard_normal((2, 24, 3))).astype(np.float32)
betas = rng.standard_normal(10)
"""

# (id, code setting `result`, expected outcome): "ok" results are checked inside the child against numpy / the
# float64 computation; errors by their type and a fragment of the message.
LEGAL = [
    ("float32 pose, float64 betas", BODY + """
out = model.forward(pose, betas)
ref = model.forward(pose.astype(np.float64), betas)
result = [str(out.vertices.dtype), bool(np.array_equal(out.vertices, ref.vertices)),
          bool(np.array_equal(out.joints, ref.joints))]""", ["float64", True, True]),
    ("float32 pose, int64 transl", BODY + """
transl = np.array([1, -2, 3], dtype=np.int64)
out = model.forward(pose, betas.astype(np.float32), transl)
ref = model.forward(pose.astype(np.float64), betas.astype(np.float32).astype(np.float64), transl.astype(float))
result = [str(out.vertices.dtype), bool(np.array_equal(out.vertices, ref.vertices))]""", ["float64", True]),
    ("all float32 stays float32", BODY + """
out = model.forward(pose, betas.astype(np.float32))
ref = model.forward(pose.astype(np.float64), betas.astype(np.float32).astype(np.float64))
result = [str(out.vertices.dtype), bool(np.abs(out.vertices - ref.vertices).max() < 1e-5)]""", ["float32", True]),
    ("float16 pose computes in float32", BODY + """
out = model.joints(pose.astype(np.float16), betas.astype(np.float16))
ref = model.joints(pose.astype(np.float16).astype(np.float64), betas.astype(np.float16).astype(np.float64))
result = [str(out.dtype), bool(np.abs(out - ref).max() < 1e-5)]""", ["float32", True]),
    ("strided, Fortran-ordered and list inputs", BODY + """
big = np.asfortranarray(np.repeat(pose.astype(np.float64), 2, axis=0)[::2])
out = model.forward(big, list(betas), (1.0, 2.0, 3.0))
ref = model.forward(np.ascontiguousarray(big), betas, np.array([1.0, 2.0, 3.0]))
result = bool(np.array_equal(out.vertices, ref.vertices))""", True),
    ("core BodyModel with int64 faces", """
import numpy as np
from m3c import _core
from m3c.body import default_body_model
d = default_body_model().data
m = _core.BodyModel(d.v_template, d.shapedirs, d.posedirs, d.J_regressor, d.weights, d.parents,
                    d.faces.astype(np.int64))
result = [m.num_vertices == d.num_vertices, bool(np.array_equal(m.faces, d.faces))]""", [True, True]),
    ("frame_planes with uint64 person ids", """
import numpy as np
import m3c.ground as g
rng = np.random.default_rng(1)
points = np.c_[rng.uniform(-0.3, 0.3, (150, 2)), 0.002 * rng.standard_normal(150)][:, [0, 2, 1]]
a = g.frame_planes(points, np.zeros(150, np.uint64), np.ones(150, bool), up=[0, 1, 0])
b = g.frame_planes(points, np.zeros(150, np.int64), np.ones(150, bool), up=[0, 1, 0])
result = [bool(np.array_equal(a.labels, b.labels)), bool(np.array_equal(a.normals, b.normals)),
          a.person_plane.tolist()]""", [True, True, [0]]),
]

VO = """
import numpy as np
import m3c.vo as v
from m3c.vo.synthetic import forward_trajectory, render_sequence
seq = render_sequence(forward_trajectory(12, length=0.6), width=96, height=72, seed=3)
depth32 = seq.depths.astype(np.float32)
"""

VO_LEGAL = [
    ("run_vo with float64 / int32 depth maps", VO + """
ref = v.run_vo(seq.frames, depths=depth32, intrinsics=seq.intrinsics)
as64 = v.run_vo(seq.frames, depths=depth32.astype(np.float64), intrinsics=seq.intrinsics)
millimetres = np.round(depth32 * 1000).astype(np.int32)
mm = v.run_vo(seq.frames, depths=millimetres, intrinsics=seq.intrinsics)
mm_ref = v.run_vo(seq.frames, depths=millimetres.astype(np.float32), intrinsics=seq.intrinsics)
# float32 -> float64 -> float32 is exact, and int32 converts as numpy's astype(float32) does: the same poses.
result = [bool(np.array_equal(as64.world_from_cam, ref.world_from_cam)),
          bool(np.array_equal(mm.world_from_cam, mm_ref.world_from_cam))]""",
     [True, True]),
    ("VisualOdometry.add_frame with a float64 depth", VO + """
vo = v.VisualOdometry(intrinsics=seq.intrinsics)
for frame, depth in zip(seq.frames, seq.depths.astype(np.float64)):
    vo.add_frame(frame, depth=depth)
result = vo.finish().world_from_cam.shape[0]""", 12),
]

REFUSED = [
    ("longdouble pose", BODY + "model.forward(pose.astype(np.longdouble), betas)",
     ["ValueError", "pose must be a float array"]),
    ("longdouble betas", BODY + "model.forward(pose, betas.astype(np.longdouble))",
     ["ValueError", "betas must be a float array"]),
    ("complex transl", BODY + "model.forward(pose, betas, np.zeros(3, complex))",
     ["ValueError", "transl must be a float array"]),
    ("object pose", BODY + "model.forward(np.array([[None] * 72]), betas)",
     ["ValueError", "pose must be a float array"]),
    ("ragged pose", BODY + "model.forward([[0.0] * 72, [0.0] * 3], betas)",
     ["ValueError", "numpy cannot turn into an array"]),
    ("NaN pose", BODY + "pose[1, 4, 2] = np.nan\nmodel.forward(pose, betas)",
     ["ValueError", "pose holds nan at index (1, 4, 2)"]),
    ("inf betas", BODY + "betas[3] = np.inf\nmodel.joints(pose, betas)", ["ValueError", "betas holds inf"]),
    ("NaN transl", BODY + "model.keypoints(model.coco17_regressor(), pose, betas, [0, np.nan, 0])",
     ["ValueError", "transl holds nan"]),
    ("float parents", """
import numpy as np
from m3c import _core
from m3c.body import default_body_model
d = default_body_model().data
_core.BodyModel(d.v_template, d.shapedirs, d.posedirs, d.J_regressor, d.weights, d.parents.astype(float), d.faces)
""", ["ValueError", "parents must be an integer or boolean array"]),
    ("uint64 parents", """
import numpy as np
from m3c import _core
from m3c.body import default_body_model
d = default_body_model().data
_core.BodyModel(d.v_template, d.shapedirs, d.posedirs, d.J_regressor, d.weights, d.parents.astype(np.uint64),
                d.faces)""", ["ValueError", "beyond int64's range"]),
    ("faces out of range", """
import numpy as np
from m3c import _core
from m3c.body import default_body_model
d = default_body_model().data
_core.BodyModel(d.v_template, d.shapedirs, d.posedirs, d.J_regressor, d.weights, d.parents, d.faces + 10**6)""",
     ["ValueError", "outside [0, V="]),
    ("dbscan longdouble points",
     "import numpy as np, m3c.ground as g\ng.dbscan(np.zeros((5, 3), np.longdouble), 0.1, 2)",
     ["ValueError", "points must be a float array"]),
    ("fit_plane longdouble up", """
import numpy as np, m3c.ground as g
g.fit_plane(np.random.default_rng(0).random((30, 3)), up=np.array([0, 1, 0], np.longdouble))""",
     ["ValueError", "up must be a float array"]),
    ("frame_planes float person ids", """
import numpy as np, m3c.ground as g
g.frame_planes(np.zeros((4, 3)), np.array([0, 0.7, 0, 0]), np.ones(4, bool), up=[0, 1, 0], num_people=1)""",
     ["ValueError", "floats are not rounded to indices"]),
    ("run_vo float frames", VO + "v.run_vo(seq.frames.astype(np.float32))", ["ValueError", "frames must be uint8"]),
    ("add_frame int64 mask", VO + "v.VisualOdometry().add_frame(seq.frames[0], mask=np.zeros((72, 96), np.int64))",
     ["ValueError", "mask[0] must be a bool or uint8 mask"]),
    ("VOConfig num_threads 0", "import m3c.vo as v\nv.VOConfig(num_threads=0)",
     ["ValueError", "num_threads must be an integer >= 1"]),
    ("core PatchVO num_threads 0", """
from m3c import _core
o = _core.PatchVOOptions()
o.num_threads = 0
_core.PatchVO(o)""", ["ValueError", "num_threads must be >= 1"]),
]


@pytest.mark.parametrize("code, expected", [pytest.param(c, e, id=i) for i, c, e in LEGAL + VO_LEGAL])
def test_legal_dtype_mixes_give_the_float64_result(code, expected):
    assert run_isolated(code) == ["ok", expected]


@pytest.mark.parametrize("code, expected", [pytest.param(c, e, id=i) for i, c, e in REFUSED])
def test_refused_inputs_raise_a_named_value_error(code, expected):
    kind, message = run_isolated(code)
    assert kind == expected[0] and expected[1] in message, message


OPTIMIZER = """
import numpy as np
from m3c.body import default_body_model
from m3c.motion import Cameras, OptimizerConfig, Track, optimize
model = default_body_model()
n = 4
track = Track(0, np.zeros((n, 17, 3)), np.tile([0.0, 0.0, 4.0], (n, 1)), np.zeros((n, 3)), np.zeros((n, 23, 3)),
              np.zeros(10))
cameras = Cameras(np.tile(np.eye(4), (n, 1, 1)), np.array([500.0, 500.0, 320.0, 240.0]), static=True)
config = OptimizerConfig.default()
"""


@pytest.mark.parametrize("threads", [0, -3])
def test_optimizer_thread_count_is_refused_not_aborted(threads):
    kind, message = run_isolated(OPTIMIZER + f"config.num_threads = {threads}\n"
                                 "optimize(model, [track], cameras, config)")
    assert kind == "ValueError" and "num_threads must be an integer >= 1" in message
    # The core refuses it too when the Python check is bypassed (Ceres would abort the process).
    kind, message = run_isolated(OPTIMIZER + f"""
from m3c import _core
core = config.to_core()
core.num_threads = {threads}
_core.optimize_world(model._core, model.coco17_regressor(), None, [], _core.CameraInput(), core)""")
    assert kind == "ValueError" and "num_threads must be >= 1" in message


def test_optimizer_rejects_nan_inputs():
    kind, message = run_isolated(OPTIMIZER + "track.transl[2, 1] = np.nan\noptimize(model, [track], cameras, config)")
    assert kind == "ValueError" and "NaN" in message


def test_body_model_file_with_keypoint_ids_out_of_range(tmp_path):
    path = tmp_path / "model.npz"
    kind, message = run_isolated(f"""
import numpy as np
from m3c.body import BodyModel, open_body_model_path
raw = dict(np.load(open_body_model_path()))
raw["keypoint_vertex_ids"] = raw["keypoint_vertex_ids"] + 10**6
np.savez({str(path)!r}, **raw)
BodyModel.from_file({str(path)!r}).coco17_regressor()""")
    assert kind == "BodyModelFileError" and "'keypoint_vertex_ids' must be" in message and "in [0, 13380)" in message
