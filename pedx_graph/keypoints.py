"""Keypoint names shared by every layer (labels, body model, evaluation)."""
from __future__ import annotations

#: The 18 PedX keypoint names, in the order used everywhere in this package (pedx-format notes).
PEDX_KEYPOINTS: tuple[str, ...] = (
    "nose", "leye", "reye", "head", "mouth", "neck",
    "lsho", "rsho", "lelb", "relb", "lwri", "rwri",
    "lhip", "rhip", "lknee", "rknee", "lankl", "rankl",
)

#: The 13 joints the paper evaluates (Tables II/III); "hip" is the mid-point of lhip and rhip.
EVAL_JOINTS: tuple[str, ...] = (
    "rknee", "lknee", "rankl", "lankl", "rsho", "lsho",
    "relb", "lelb", "rwri", "lwri", "head", "neck", "hip",
)

#: SMPL's 24 joint names (index order of the kinematic tree).
SMPL_JOINTS: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2",
    "left_ankle", "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar",
    "right_collar", "head", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist", "left_hand", "right_hand",
)

#: SMPL's parent of each joint (-1 for the root).
SMPL_PARENTS: tuple[int, ...] = (
    -1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21,
)
