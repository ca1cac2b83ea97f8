"""The `m3c` command's argument parser: every command and its options, each command's function in the module of
its group (body, perception, pipeline, results, evaluation)."""

from __future__ import annotations

import argparse

from m3c import __version__
from m3c.cli import body as body_commands
from m3c.cli import data as data_commands
from m3c.cli import evaluation as eval_commands
from m3c.cli import perception as perception_commands
from m3c.cli import pipeline as pipeline_commands
from m3c.cli import results as results_commands
from m3c.cli import training as train_commands


# The video benchmark's camera motions (m3c.synth.cameras.CAMERA_KINDS; listed here so --help imports nothing).
CAMERA_KINDS_TEXT = ("static", "pan", "follow", "tracking", "orbit", "handheld", "high")


def _frame_range(text: str) -> tuple[int, int | None, int]:
    """START:STOP[:STEP] (STOP exclusive, may be empty for the end)."""
    parts = text.split(":")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(f"expected START:STOP or START:STOP:STEP, got {text!r}")
    try:
        start = int(parts[0]) if parts[0] else 0
        stop = int(parts[1]) if parts[1] else None
        step = int(parts[2]) if len(parts) == 3 and parts[2] else 1
    except ValueError:
        raise argparse.ArgumentTypeError(f"frame range {text!r} must hold integers") from None
    return start, stop, step


def _add_config_options(parser) -> None:
    parser.add_argument("--config", metavar="FILE", help="pipeline config YAML (default: the built-in one; see "
                                                         "`m3c config`)")
    parser.add_argument("--set", action="append", metavar="NODE.SETTING=VALUE",
                        help="change one setting, e.g. --set optimize.enabled=false (repeatable)")


def _add_video_options(parser, many: bool) -> None:
    """What `m3c run` and `m3c batch` take about the video(s): one video, or many sharing these settings."""
    parser.add_argument("--intrinsics", nargs=4, type=float, metavar=("FX", "FY", "CX", "CY"),
                        help="camera intrinsics in pixels, the same for every video" if many else
                        "camera intrinsics in pixels (default: focal sqrt(W^2 + H^2), image centre)")
    parser.add_argument("--hfov", type=float, metavar="DEGREES",
                        help="the camera's horizontal field of view, instead of --intrinsics (square pixels, principal "
                             "point at the image centre); worth giving for a camera that does not move, whose focal "
                             "length its motion cannot tell (a phone's main camera: about 60-70)")
    parser.add_argument("--force-intrinsics", action="store_true",
                        help="use --intrinsics even where they are not those of a physical camera (focal length "
                             "outside 0.2..10 image diagonals, principal point outside the image)")
    parser.add_argument("--static-camera", action="store_true",
                        help=f"the camera{'s do' if many else ' does'} not move (no visual odometry)")
    parser.add_argument("--slow-motion", type=float, metavar="FACTOR",
                        help="the video plays FACTOR times slower than it was filmed (a phone's 120 fps slow motion "
                             "at 30 fps: 4; 50 fps played at 23.976: 2.085): times, speeds and the exported animation "
                             "are then real time")
    parser.add_argument("--fps", type=float, metavar="RATE",
                        help="the video's true frame rate, where its file states an implausible one or one its "
                             "timestamps contradict (frame times are then frame id / RATE)")
    parser.add_argument("--frames", type=_frame_range, metavar="START:STOP[:STEP]",
                        help="process frames START..STOP-1 (every STEP-th)" + (" of each video" if many else ""))
    parser.add_argument("--no-hands", action="store_true",
                        help="no hands: skip MediaPipe Hands and the finger fit (results then hold no hand poses)")
    parser.add_argument("--side-by-side", action="store_true",
                        help="world.mp4 shows the input video beside the world view (world_view.beside_video)")
    parser.add_argument("--body-model", metavar="FILE", help="SMPL-layout body model .pkl/.npz (default: the open "
                                                             "model)")
    parser.add_argument("--checkpoints", metavar="DIR", help="folder of learned-model checkpoints (default: "
                                                             "$M3C_MODELS)")


def _add_motion_options(parser) -> None:
    """The benchmarks' motion sources, read by _benchmark_clips."""
    parser.add_argument("--clips", nargs="+", metavar="NPZ", help="retargeted clips (m3c eval retarget) to use "
                        "instead of the shipped CMU clips")
    parser.add_argument("--mocap", action="append", metavar="DIR",
                        help="also use every BVH under DIR (retargeted once, cached); repeatable")
    parser.add_argument("--cache", help="cache folder for retargeted BVH (default ~/.cache/m3c/mocap)")


def _add_report_options(parser, body_model: bool = True) -> None:
    """The evaluation commands' shared options: the body model (where the command runs one) and the report."""
    if body_model:
        parser.add_argument("--body-model", help="body model file (default: the shipped open model)")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--quiet", action="store_true", help="no progress lines on stderr")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="m3c", description="M3C: world-grounded human motion capture.")
    parser.add_argument("--version", action="version", version=f"m3c {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    body = sub.add_parser("body", help="inspect or convert SMPL-layout body model files").add_subparsers(
        dest="body_command", required=True)
    info = body.add_parser("info", help="summarise a .pkl/.npz body model file")
    info.add_argument("model")
    info.set_defaults(func=body_commands.body_info)
    convert = body.add_parser("convert", help="rewrite a .pkl/.npz model (e.g. a chumpy pickle) as a plain .npz")
    convert.add_argument("model")
    convert.add_argument("out")
    convert.add_argument("--smpl-layout", action="store_true", help="reduce SMPL-H/SMPL-X to SMPL's 24 joints")
    convert.set_defaults(func=body_commands.body_convert)
    vo = sub.add_parser("vo", help="camera trajectory of a video (patch visual odometry, no people masked yet)")
    vo.add_argument("video")
    vo.add_argument("--out", required=True, help="output folder")
    vo.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                    help="pixels; default f = sqrt(W^2 + H^2), principal point at the centre")
    vo.add_argument("--max-frames", type=int)
    vo.set_defaults(func=perception_commands.vo)

    run = sub.add_parser("run", help="capture every person's 3D motion in a video",
                         description="Runs the pipeline on VIDEO; results, videos and the cache go to --out. "
                                     "A second run reuses every node whose inputs and settings are unchanged.")
    run.add_argument("video", help="input video file (any format OpenCV/FFmpeg reads)")
    run.add_argument("--out", required=True, help="output folder (results.npz/json, overlay.mp4, world.mp4, cache/)")
    _add_config_options(run)
    _add_video_options(run, many=False)
    run.add_argument("--until", nargs="+", metavar="NODE", help="run only these nodes and what they need")
    run.add_argument("--visualize", action="store_true", help="also write each node's pictures under OUT/viz/")
    run.add_argument("--no-progress", action="store_true", help="no progress lines")
    run.add_argument("-v", "--verbose", action="count", default=0)
    run.add_argument("-q", "--quiet", action="count", default=0)
    run.set_defaults(func=pipeline_commands.run)

    batch = sub.add_parser("batch", help="run the pipeline on many videos (on Ray when installed)",
                           description="Runs every video of INPUTS as `m3c run` would, into OUT/<video name>/ (each "
                                       "with its own cache: a re-run skips finished videos and resumes unfinished "
                                       "ones). Failed videos are reported and the others go on; OUT/batch_summary.json "
                                       "holds every video's outcome. Exit status 1 when any video failed.")
    batch.add_argument("inputs", nargs="+", metavar="INPUT",
                       help="video files, folders of videos, or .txt files listing one video or folder per line")
    batch.add_argument("--out", required=True, help="output folder (one result folder per video)")
    batch.add_argument("--address", help="Ray cluster address, or auto for the one running on this machine "
                       "(default: start a local Ray instance for this batch)")
    batch.add_argument("--sequential", action="store_true", help="run the videos one after another here, not on Ray")
    batch.add_argument("--cpus-per-video", type=float, help="CPUs Ray reserves per video (default: the most any "
                       "node of the pipeline needs, its `needs` in the config)")
    batch.add_argument("--memory-per-video", type=float, metavar="GB",
                       help="memory Ray reserves per video, GB (default: the most any node of the pipeline needs)")
    _add_config_options(batch)
    _add_video_options(batch, many=True)
    batch.add_argument("--no-progress", action="store_true", help="no progress lines")
    batch.add_argument("-v", "--verbose", action="count", default=0)
    batch.add_argument("-q", "--quiet", action="count", default=0)
    batch.set_defaults(func=pipeline_commands.batch)

    info = sub.add_parser("info", help="summarise the results in an output folder")
    info.add_argument("folder")
    info.set_defaults(func=results_commands.info)

    export = sub.add_parser("export", help="write the results as BVH, GLB, FBX or USD (optionally on a "
                                         "Mixamo, UE5, Unity or Rigify skeleton), or in WHAM/SLAHMR/GVHMR "
                                         "layouts",
                            description="Exports OUT_DIR's results (see README, 'Use the results' for axes and "
                                        "units of each format).")
    export.add_argument("folder", metavar="OUT_DIR", help="a result folder of `m3c run`")
    export.add_argument("--format", required=True,
                        choices=("bvh", "glb", "fbx", "usd", "wham", "slahmr", "gvhmr"),
                        help="usd: USD (UsdSkel, .usda) of the retargeted skeleton; needs usd-core")
    export.add_argument("--tracks", metavar="IDS", help="comma-separated track ids (default: every track)")
    export.add_argument("--out", metavar="PATH", help="output file or folder (default: OUT_DIR/export/...)")
    export.add_argument("--body-model", metavar="FILE", help="the body model file the run used, when it was not "
                                                             "M3C's open model")
    export.add_argument("--bvh-unit", choices=("cm", "m"), default="cm", help="BVH length unit (default cm)")
    export.add_argument("--rig", choices=("smpl", "mixamo", "ue5", "unity", "rigify"), default="smpl",
                        help="the skeleton: smpl (default: the body model's 24 joints, one scene) or the "
                             "motion retargeted onto Mixamo's, the UE5 mannequin's, Unity's Humanoid or "
                             "Rigify's DEF bones (glb, fbx, usd; one file per track; see docs/outputs.md)")
    export.add_argument("--root-motion", choices=("performer", "in-place"), default="performer",
                        help="performer (default): the true metric world path; in-place: the horizontal path "
                             "removed, height and heading kept")
    export.add_argument("--reference-pose", choices=("none", "tpose", "apose"), default="none",
                        help="an extra first frame in this pose (default none)")
    export.add_argument("--smoothing", choices=("off", "standard", "strong"), default="off",
                        help="Savitzky-Golay filter on the rotations (0.25 s or 0.5 s windows), planted feet "
                             "re-locked after (default off)")
    export.add_argument("--no-foot-lock", dest="foot_lock", action="store_false",
                        help="do not hold planted feet (results' contacts) where the source has them")
    export.set_defaults(func=results_commands.export)

    view = sub.add_parser("view", help="interactive 3D viewer of a result folder in the browser (viser)")
    view.add_argument("folder", metavar="OUT_DIR", help="a result folder of `m3c run`")
    view.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    view.add_argument("--port", type=int, default=8080, help="port (default 8080)")
    view.add_argument("--body-model", metavar="FILE", help="the body model file the run used, when it was not "
                                                           "M3C's open model")
    view.add_argument("--video", metavar="FILE", help="show the source video's frames (default: OUT_DIR/overlay.mp4)")
    view.set_defaults(func=results_commands.view)

    graph = sub.add_parser("graph", help="draw the pipeline graph (Graphviz dot text, or .svg/.png via `dot`)")
    _add_config_options(graph)
    graph.add_argument("--out", metavar="FILE", help="write FILE (.dot, .svg, .png, .pdf) instead of printing dot")
    graph.add_argument("--status", metavar="DIR", help="colour nodes by the last run in output folder DIR")
    graph.set_defaults(func=pipeline_commands.graph)

    config = sub.add_parser("config", help="print the default pipeline config (YAML) to start your own from")
    config.set_defaults(func=pipeline_commands.config)
    perceive = sub.add_parser("perceive", help="people, keypoints, masks, camera-local bodies, tracks and contacts "
                                               "from a video (offline, CPU)")
    perceive.add_argument("video")
    perceive.add_argument("out", help="output path; OUT.npz and OUT.json are written")
    perceive.add_argument("--config", help="perception settings (YAML: estimators by task, tracker, ...)")
    perceive.add_argument("--max-frames", type=int, default=None)
    perceive.add_argument("--intrinsics", type=float, nargs=4, metavar=("FX", "FY", "CX", "CY"),
                          help="pixels (default: focal length = image diagonal, principal point at the centre)")
    perceive.add_argument("--detector", help="detector estimator name (see m3c.perception.available)")
    perceive.add_argument("--pose2d", help="2D pose estimator name")
    perceive.add_argument("--body", help="camera-local body estimator name")
    perceive.set_defaults(func=perception_commands.perceive)

    data = sub.add_parser("data", help="training data: motion capture retargeted onto the body model")
    data = data.add_subparsers(dest="data_command", required=True)
    mc = data.add_parser("mocap", help="retarget every BVH of CORPUS (files, folders, .tar.xz archives) onto the "
                         "body model: one .npz per clip, a held-out split by clip",
                         description="Each clip: pose (T, 24, 3) axis-angle, world root translation (y up, ground "
                                     "y = 0), betas fitted to its bone lengths, foot contacts, source and licence, "
                                     "at --fps. Cached per clip (a re-run skips finished clips); a bad file is "
                                     "reported and skipped. The clips the benchmarks render are left out.")
    mc.add_argument("corpus", nargs="+", metavar="CORPUS", help="BVH files, folders of them, or tar archives")
    mc.add_argument("--out", required=True, help="output folder (clips/, index.json, split.json)")
    mc.add_argument("--fps", type=float, default=30.0, help="output frame rate (default 30)")
    mc.add_argument("--held-out", type=float, default=10.0, metavar="PERCENT",
                    help="share of clips held out of training, chosen by a hash of the clip id (default 10)")
    mc.add_argument("--exclude", action="append", metavar="BVH_OR_DIR",
                    help="also leave out clips of these names (a BVH file, or every BVH under a folder); repeatable")
    mc.add_argument("--workers", type=int, default=1, help="processes (default 1)")
    mc.add_argument("--limit", type=int, help="only the first N clips (a quick look)")
    mc.add_argument("--body-model", help="body model file (default: the shipped open model)")
    mc.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    mc.set_defaults(func=data_commands.data_mocap)

    train = sub.add_parser("train", help="train M3C's own priors on a corpus of `m3c data mocap`")
    train = train.add_subparsers(dest="train_command", required=True)
    pp = train.add_parser("pose-prior", help="the pose prior: VPoser v2's architecture, on the corpus's training "
                          "clips; evaluated on its held-out clips against a Gaussian baseline",
                          description="Writes OUT/vposer_v2.ckpt (load_vposer(path, version='v2') reads it; "
                                      "python -m m3c.models.export --vposer OUT/vposer_v2.ckpt exports it for the "
                                      "optimizer), OUT/checkpoint.pt (every --checkpoint-minutes; --resume "
                                      "continues from it), OUT/train.json and OUT/metrics.json.")
    pp.add_argument("corpus", help="a folder written by `m3c data mocap`")
    pp.add_argument("--out", required=True, help="output folder")
    pp.add_argument("--steps", type=int, default=20000, help="optimiser steps (default 20000)")
    pp.add_argument("--batch-size", type=int, default=256)
    pp.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate, decayed by a cosine (default 1e-3)")
    pp.add_argument("--kl-weight", type=float, default=5e-4, help="weight of the KL term (default 5e-4)")
    pp.add_argument("--no-mirror", action="store_true", help="do not add the left-right mirrored poses")
    pp.add_argument("--seed", type=int, default=0)
    pp.add_argument("--threads", type=int, default=1, help="torch threads (default 1: deterministic)")
    pp.add_argument("--checkpoint-minutes", type=float, default=3.0, help="checkpoint period (default 3)")
    pp.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    pp.add_argument("--body-model", help="body model file for the joint loss (default: the shipped open model)")
    pp.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    pp.set_defaults(func=train_commands.train_pose_prior_command)
    mp = train.add_parser("motion-prior", help="the motion prior: HuMoR's layout (narrower by --hidden), on the "
                          "corpus's training clips; one-step prediction on its held-out clips against constant "
                          "velocity", description="Writes OUT/motion_prior.pt, OUT/checkpoint.pt (every "
                          "--checkpoint-minutes; --resume continues from it), OUT/train.json, OUT/metrics.json.")
    mp.add_argument("corpus", help="a folder written by `m3c data mocap`")
    mp.add_argument("--out", required=True, help="output folder")
    mp.add_argument("--steps", type=int, default=20000, help="optimiser steps (default 20000)")
    mp.add_argument("--batch-size", type=int, default=256)
    mp.add_argument("--hidden", type=int, default=256, help="hidden width (HuMoR's: 1024; default 256)")
    mp.add_argument("--lr", type=float, default=5e-4, help="AdamW learning rate, cosine decay (default 5e-4)")
    mp.add_argument("--kl-weight", type=float, default=1e-3, help="weight of the KL term (default 1e-3)")
    mp.add_argument("--seed", type=int, default=0)
    mp.add_argument("--threads", type=int, default=1, help="torch threads (default 1: deterministic)")
    mp.add_argument("--checkpoint-minutes", type=float, default=3.0, help="checkpoint period (default 3)")
    mp.add_argument("--rollout-steps", type=int, default=1,
                    help="transitions per training window, rolled out on the prior's own predictions (default 1: "
                         "consecutive pairs)")
    mp.add_argument("--init", help="with --rollout-steps > 1: start from another run's motion_prior.pt or "
                                   "checkpoint.pt")
    mp.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    mp.add_argument("--body-model", help="body model file (default: the shipped open model)")
    mp.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    mp.set_defaults(func=train_commands.train_motion_prior_command)
    rg = train.add_parser("regressor", help="the world regressor: WHAM's layout (narrower by --width), on "
                          "the corpus's training clips seen through virtual cameras with M3C's measured "
                          "detector errors; evaluated on held-out clips against simple baselines",
                          description="Writes OUT/regressor.pt, OUT/checkpoint.pt (every "
                                      "--checkpoint-minutes; --resume continues from it), OUT/train.json and "
                                      "OUT/metrics.json (held-out figures: camera-frame PA-MPJPE, world root "
                                      "velocity and orientation, contact F1, and the baselines').")
    rg.add_argument("corpus", help="a folder written by `m3c data mocap`")
    rg.add_argument("--out", required=True, help="output folder")
    rg.add_argument("--steps", type=int, default=20000, help="optimiser steps (default 20000)")
    rg.add_argument("--minutes", type=float,
                    help="stop (resumably, with a checkpoint) after this many minutes")
    rg.add_argument("--batch-size", type=int, default=32)
    rg.add_argument("--frames", type=int, default=48, help="window length in frames (default 48)")
    rg.add_argument("--width", type=int, default=128, help="motion-encoder width (WHAM's: 512; default 128)")
    rg.add_argument("--lr", type=float, default=1e-3, help="AdamW learning rate, cosine decay (default 1e-3)")
    rg.add_argument("--teacher-noise", type=float, default=0.05,
                    help="noise on the teacher-forced previous-frame rotations (6D; a fifth of it, in "
                         "metres, on the 3D keypoints; default 0.05)")
    rg.add_argument("--root-noise", type=float,
                    help="the same noise on the previous root orientation (default: --teacher-noise)")
    rg.add_argument("--root", choices=("residual", "absolute"), default="residual",
                    help="the trajectory decoder's orientation: a change from the previous frame's (default) "
                         "or, as WHAM reads it, the world orientation itself")
    rg.add_argument("--sampling-passes", type=int, default=0,
                    help="parallel scheduled sampling: passes feeding the decoders their own previous outputs "
                         "before each step (default 0: teacher forcing only)")
    rg.add_argument("--sampling-prob", type=float, default=0.5,
                    help="with --sampling-passes: the share of frames fed the network's own values, reached "
                         "by a linear ramp over the first half of the steps (default 0.5)")
    rg.add_argument("--dropout", type=float, default=0.3,
                    help="dropout between the LSTM layers, half of it on the input embedding (default WHAM's "
                         "0.3)")
    rg.add_argument("--contact-weight", type=float, default=0.1,
                    help="weight of the foot-contact loss (default 0.1)")
    rg.add_argument("--init", help="start from another run's weights (its regressor.pt or checkpoint.pt, the "
                                   "same --width and --root)")
    rg.add_argument("--eval-windows", type=int, default=256,
                    help="held-out windows for the figures (fixed seed; default 256)")
    rg.add_argument("--seed", type=int, default=0)
    rg.add_argument("--threads", type=int, default=1, help="torch threads (default 1: deterministic)")
    rg.add_argument("--checkpoint-minutes", type=float, default=3.0, help="checkpoint period (default 3)")
    rg.add_argument("--resume", action="store_true", help="continue from OUT/checkpoint.pt")
    rg.add_argument("--body-model", help="body model file (default: the shipped open model)")
    rg.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    rg.set_defaults(func=train_commands.train_regressor_command)

    ev = sub.add_parser("eval", help="evaluation: metrics tables, benchmark, mocap retargeting").add_subparsers(
        dest="eval_command", required=True)
    rt = ev.add_parser("retarget", help="fit the body model to a BVH clip (IK) and save its parameters (.npz)")
    rt.add_argument("bvh")
    rt.add_argument("out")
    rt.add_argument("--frames", help="BVH frames START:STOP[:STEP] (e.g. 1: drops CMU's added T-pose)")
    rt.add_argument("--fps", type=float, default=30.0, help="output frame rate (default 30)")
    rt.add_argument("--up", choices=("y", "z"), default="y", help="the BVH's up axis (default y)")
    rt.add_argument("--scale", type=float, help="metres per BVH unit (default: from the skeleton)")
    rt.add_argument("--joint-map", help="cmu_3dsmax, cmu_motionbuilder or bandai_namco (default: detected)")
    rt.add_argument("--body-model", help="body model file (default: the shipped open model)")
    rt.add_argument("--source", help="a description of the clip stored in the file")
    rt.set_defaults(func=eval_commands.eval_retarget)

    bm = ev.add_parser("benchmark", help="the ground-truth benchmark on retargeted mocap: Local and Global Opt "
                       "metrics tables (mm)")
    bm.add_argument("--sequences", type=int, default=2, help="number of sequences (default 2)")
    bm.add_argument("--frames", type=int, default=120, help="frames per sequence at 30 fps (default 120)")
    bm.add_argument("--seed", type=int, default=0)
    bm.add_argument("--max-people", type=int, default=3, choices=(1, 2, 3))
    bm.add_argument("--cameras", default="walking,panning,orbiting,static",
                    help="camera motions, used in turn (default walking,panning,orbiting,static)")
    _add_motion_options(bm)
    bm.add_argument("--optimizer-config", help="YAML optimizer config (default: the built-in recipe)")
    bm.add_argument("--vposer", help="exported vposer.safetensors (python -m m3c.models.export) for the optimizer's "
                    "pose prior (default: none; the pose_prior terms are then reported unavailable)")
    _add_report_options(bm)
    bm.set_defaults(func=eval_commands.eval_benchmark)

    vb = ev.add_parser("video-benchmark", help="render mocap people into textured scenes filmed by known moving "
                       "cameras, run the real pipeline on the videos and score it against the ground truth")
    vb.add_argument("--sequences", type=int, default=7, help="number of sequences (default 7: one per camera motion)")
    vb.add_argument("--frames", type=int, default=150, help="frames per sequence at 30 fps (default 150)")
    vb.add_argument("--cameras", default=",".join(CAMERA_KINDS_TEXT),
                    help=f"camera motions, used in turn (default {','.join(CAMERA_KINDS_TEXT)})")
    vb.add_argument("--people", type=int, default=3, choices=(1, 2, 3), help="most people in a sequence (default 3)")
    _add_motion_options(vb)
    vb.add_argument("--seed", type=int, default=0)
    vb.add_argument("--size", type=int, nargs=2, default=(960, 540), metavar=("W", "H"),
                    help="image size in pixels (default 960 540)")
    vb.add_argument("--supersample", type=int, default=1, help="samples per pixel along each axis (default 1; "
                    "textures are mip-mapped either way)")
    vb.add_argument("--out", default="out/video_benchmark", help="folder for the videos, ground truth and runs "
                    "(default out/video_benchmark; both are cached there)")
    vb.add_argument("--suite", choices=("default", "hard"), default="default",
                    help="default: --sequences sequences over --cameras (the README's figures); hard: 12 fixed "
                    "sequences of near-still handheld cameras, slow motion (1/2 and 1/4 speed), plain floors, "
                    "phone optics (blur, noise, low bitrate) and background crowds (12-25 unscored walkers), "
                    "--sequences and --cameras ignored")
    vb.add_argument("--only", type=int, nargs="+", metavar="INDEX", default=(),
                    help="run only the sequences of these indices (seqNN's NN)")
    vb.add_argument("--render-only", action="store_true", help="write the videos and ground truth only")
    vb.add_argument("--known-intrinsics", action="store_true", help="give the pipeline the true intrinsics "
                    "(default: it runs uncalibrated, as on a user's video)")
    _add_config_options(vb)
    _add_report_options(vb)
    vb.set_defaults(func=eval_commands.eval_video_benchmark)

    mv = ev.add_parser("multiview", help="run M3C on each video of a calibrated multi-camera recording alone and "
                       "compare with the calibration and the triangulated 3D keypoints")
    mv.add_argument("folder", nargs="?", default="examples/pose2sim_single_person",
                    help="Pose2Sim-layout folder: Calib_qualisys.toml, a .trc, videos/ (default: the repository's "
                    "examples/pose2sim_single_person)")
    mv.add_argument("--out", default="out/multiview", help="folder for the runs (cached; default out/multiview)")
    mv.add_argument("--cameras", nargs="+", metavar="NAME", help="only these cameras (e.g. cam_01)")
    mv.add_argument("--known-intrinsics", action="store_true", help="give the pipeline the calibrated intrinsics")
    _add_config_options(mv)
    _add_report_options(mv)
    mv.set_defaults(func=eval_commands.eval_multiview)

    rb = ev.add_parser("real-benchmark", help="real footage with truth: calibrated still videos warped by "
                       "known camera rotations (pan, tilt, shake), scored against the calibration's ground "
                       "and the triangulated person; and the odometry alone on EuRoC")
    rb.add_argument("folder", nargs="?", default="examples/pose2sim_single_person",
                    help="Pose2Sim-layout folder: Calib_qualisys.toml, a .trc, videos/ (default: the "
                    "repository's examples/pose2sim_single_person)")
    rb.add_argument("--sequences", nargs="+", metavar="CAMERA:MOTION",
                    help="camera and motion (still, pan, tilt or shake) of each sequence (default: the four "
                    "cameras still, pan of cam_02 and cam_03, tilt of cam_01 and cam_04, shake of cam_01 and "
                    "cam_03)")
    rb.add_argument("--frames", type=int, default=60,
                    help="frames per sequence from the start (default 60 of 100)")
    rb.add_argument("--intrinsics", choices=("both", "true", "estimated"), default="both",
                    help="give the pipeline the warped video's true intrinsics, let it estimate them, or "
                    "both runs (default both)")
    rb.add_argument("--euroc", metavar="DIR", help="a EuRoC-layout folder (cam0/data/*.png, "
                    "cam0/sensor.yaml, groundtruth*.txt) to score the odometry alone on; skipped, with the "
                    "reason printed, when not given or absent")
    rb.add_argument("--out", default="out/real_benchmark", help="folder for the warped videos and the runs "
                    "(cached; default out/real_benchmark)")
    _add_config_options(rb)
    _add_report_options(rb)
    rb.set_defaults(func=eval_commands.eval_real_benchmark)

    pw = ev.add_parser("3dpw", help="evaluate prediction files on 3DPW (users bring the dataset and SMPL)")
    pw.add_argument("root", help="the 3DPW folder that holds sequenceFiles/")
    pw.add_argument("--split", default="test", choices=("train", "validation", "test"))
    pw.add_argument("--results", nargs="+", required=True, metavar="METHOD=FOLDER",
                    help="per method, a folder of <sequence>.npz prediction files (layout: m3c.eval.threedpw_eval)")
    pw.add_argument("--smpl-neutral", required=True, help="SMPL neutral model file (.pkl/.npz), for predictions")
    pw.add_argument("--smpl-male", required=True, help="SMPL male model file, for the ground truth")
    pw.add_argument("--smpl-female", required=True, help="SMPL female model file, for the ground truth")
    pw.add_argument("--h36m-regressor", help="J_regressor_h36m.npy (17 x 6890): the 14 evaluation joints; "
                    "without it SMPL's 24 joints are used")
    pw.add_argument("--sequences", nargs="+", help="only these sequence names")
    _add_report_options(pw, body_model=False)
    pw.set_defaults(func=eval_commands.eval_3dpw)
    return parser
