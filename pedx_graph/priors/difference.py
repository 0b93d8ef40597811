"""The 75-d frame-to-frame difference on which the temporal prior is trained and evaluated (one definition).

    d(i, j) = [ world_R_body_i^T (trans_j - trans_i)        (3)  translation step in the body frame of i, m
                Log(world_R_body_i^T world_R_body_j)         (3)  root rotation step, local rotation vector, rad
                body_pose_j - body_pose_i ]                  (69) body pose difference, rad

The step and the rotation are expressed in the body frame of frame i, so d does not change under any rotation
or translation of the world (a Y-up mocap frame and a LiDAR frame of any orientation give the same d).
``trans`` differences equal pelvis differences when the shape is shared, so training on pelvis positions
(:mod:`pedx_graph.priors.train`) and evaluating on SMPL ``trans`` (``factors.temporal_prior``) agree.
"""
from __future__ import annotations

import numpy as np

from pedx_graph.body.rotation import log_so3

#: Dimension of the difference: step (3) + rotation step (3) + body pose difference (69).
DIFFERENCE_DIM = 75


def temporal_difference(world_R_body_i: np.ndarray, trans_i: np.ndarray, body_pose_i: np.ndarray,
                        world_R_body_j: np.ndarray, trans_j: np.ndarray, body_pose_j: np.ndarray) -> np.ndarray:
    """The 75-d difference d(i, j) of the module docstring, batched over leading dimensions.

    Shapes: rotations (..., 3, 3), translations (..., 3) metres, body poses (..., 69) radians -> (..., 75).
    """
    rot_i = np.asarray(world_R_body_i, dtype=np.float64)
    rot_j = np.asarray(world_R_body_j, dtype=np.float64)
    step = np.einsum("...ji,...j->...i", rot_i, np.asarray(trans_j, float) - np.asarray(trans_i, float))
    rel = np.swapaxes(rot_i, -1, -2) @ rot_j
    return np.concatenate([step, log_so3(rel),
                           np.asarray(body_pose_j, float) - np.asarray(body_pose_i, float)], axis=-1)
