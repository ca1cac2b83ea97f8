"""Joint layouts shared by every part of M3C (the one place that defines them)."""

# SMPL's 24 joints, in order; parents[0] = -1.
SMPL_JOINT_NAMES = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)
SMPL_PARENTS = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

# Contact joints: the ankles and feet, the joints that touch the ground when walking. Every per-person contact
# probability in M3C (perception, ground, scale, optimizer, results) is over these, in this order.
CONTACT_JOINT_NAMES = ("left_ankle", "right_ankle", "left_foot", "right_foot")
CONTACT_JOINTS = tuple(SMPL_JOINT_NAMES.index(name) for name in CONTACT_JOINT_NAMES)  # (7, 8, 10, 11)

# COCO-17 keypoint order used for every 2D keypoint array in M3C.
COCO17_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder",
    "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee",
    "right_knee", "left_ankle", "right_ankle",
)

# The 14 evaluation joints as rows of the H36M-17 regressor (REFERENCE.md F); pelvis = mean of rows 2 and 3 of J14.
H36M_TO_J14 = (6, 5, 4, 1, 2, 3, 16, 15, 14, 11, 12, 13, 8, 10)
J14_PELVIS = (2, 3)

# Keypoints that are mesh vertices rather than joints, by M3C name. Each model file may carry its own table
# (keypoint_names / keypoint_vertex_ids); these are the SMPL/SMPL-H (V = 6890) and SMPL-X (V = 10475) ones.
KEYPOINT_VERTEX_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_big_toe", "left_small_toe", "left_heel",
    "right_big_toe", "right_small_toe", "right_heel", "left_hand", "right_hand",
)
SMPL_KEYPOINT_VERTICES = dict(zip(KEYPOINT_VERTEX_NAMES,
                                  (332, 2800, 6260, 583, 4071, 3216, 3226, 3387, 6617, 6624, 6787, 2445, 5905)))
SMPLX_KEYPOINT_VERTICES = dict(zip(KEYPOINT_VERTEX_NAMES,
                                   (9120, 9448, 9929, 6, 616, 5770, 5780, 8846, 8463, 8474, 8635, 5058, 7794)))

# COCO-17 from the body: face points are vertices, limbs are SMPL joints.
COCO17_SOURCES = (
    ("vertex", "nose"), ("vertex", "left_eye"), ("vertex", "right_eye"), ("vertex", "left_ear"),
    ("vertex", "right_ear"), ("joint", 16), ("joint", 17), ("joint", 18), ("joint", 19), ("joint", 20),
    ("joint", 21), ("joint", 1), ("joint", 2), ("joint", 4), ("joint", 5), ("joint", 7), ("joint", 8),
)
