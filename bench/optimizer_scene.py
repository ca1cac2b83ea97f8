"""The world optimizer's bench scene, one definition for bench/motion_optimizer.py (time) and
bench/optimizer_memory.py (memory): m3c.eval.scenes' synthetic people and handheld camera, whose lift goes through
M3C's scale estimator (m3c.motion.scale, planted feet) as the pipeline's scale node does. Imports no torch."""

from __future__ import annotations


def add_scene_arguments(parser) -> None:
    parser.add_argument("--frames", type=int, default=600)
    parser.add_argument("--people", type=int, default=2)
    parser.add_argument("--seed", type=int, default=3)


def optimizer_scene(frames: int, people: int, seed: int):
    """(model, scene, estimate, (tracks, cameras)): the scene as made (its lift at VO scale 1), the scale estimate,
    and the lift rescaled by it, where the optimizer starts."""
    from m3c.body import BodyModel
    from m3c.body.synthetic import make_synthetic_model
    from m3c.eval.scenes import make_scene
    from m3c.motion.scale import estimate_scale, rescaled

    model = BodyModel(make_synthetic_model())
    scene = make_scene(model, num_people=people, num_frames=frames, seed=seed)
    estimate = estimate_scale(model, scene.init, scene.cameras_vo)
    return model, scene, estimate, rescaled(scene.init, scene.cameras_vo, estimate)


def world_error_mm(model, tracks, truth) -> float:
    """The mean world joint error of the tracks against the truth, person by person, mm."""
    import numpy as np

    from m3c.motion import track_joints

    return 1000 * float(np.mean([np.linalg.norm(track_joints(model, a) - track_joints(model, b), axis=-1).mean()
                                 for a, b in zip(tracks, truth)]))
