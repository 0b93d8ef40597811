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
    return difference_parts(world_R_body_i, trans_i, body_pose_i, world_R_body_j, trans_j, body_pose_j)[0]


def difference_parts(world_R_body_i: np.ndarray, trans_i: np.ndarray, body_pose_i: np.ndarray,
                     world_R_body_j: np.ndarray, trans_j: np.ndarray, body_pose_j: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """d(i, j) (..., 75) with the intermediate quantities its Jacobians reuse (``factors.temporal_prior``):
    the step ``s = world_R_body_i^T (trans_j - trans_i)`` (..., 3), ``world_R_body_i^T`` (..., 3, 3) and the
    relative rotation ``world_R_body_i^T world_R_body_j`` (..., 3, 3) (``d[..., 3:6]`` is its Log)."""
    body_i_R_world = np.swapaxes(np.asarray(world_R_body_i, dtype=np.float64), -1, -2)
    rot_j = np.asarray(world_R_body_j, dtype=np.float64)
    step = np.einsum("...ab,...b->...a", body_i_R_world,
                     np.asarray(trans_j, dtype=np.float64) - np.asarray(trans_i, dtype=np.float64))
    rel = body_i_R_world @ rot_j
    d = np.concatenate([step, log_so3(rel),
                        np.asarray(body_pose_j, dtype=np.float64) - np.asarray(body_pose_i, dtype=np.float64)],
                       axis=-1)
    return d, step, body_i_R_world, rel
