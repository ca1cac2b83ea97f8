"""Evaluation: the field's metrics and the thesis's protocol, dataset readers, and ground-truth benchmarks.

  metrics        MPJPE, PA-MPJPE, PVE, acceleration error, W-/WA-MPJPE100, RTE, jitter, foot sliding, camera
                 ATE/RPE (mm unless stated)
  matching       track alignment (common frames) and Hungarian matching on mean PA-MPJPE
  tracks         bodies posed in the world and in the cameras for evaluation
  evaluate       per-sequence evaluation and aggregation, the thesis's table layout
  datasets       3DPW sequence files (users bring the dataset)
  threedpw_eval  3DPW evaluation of prediction files
  retarget       BVH motion capture onto the 24-joint body by inverse kinematics
  scenes         procedural synthetic scenes (tests of the world-frame stages)
  benchmark      the offline benchmark on retargeted motion capture with simulated cameras and perception
  video_benchmark  the real pipeline on rendered videos of retargeted motion capture (m3c.synth), scored
"""
