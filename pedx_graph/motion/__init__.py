"""Body motion on SMPL's 24-joint tree: BVH reading, CMU retargeting, resampling, procedural gait.

Public API::

    from pedx_graph.motion import (MotionClip, load_cmu_clip, list_clips, resample_clip,
                                   procedural_gait, smpl_joint_positions)

    clip = procedural_gait("walk", 1.3, duration=8.0, fps=10.0, seed=0)     # no data files needed
    clip = resample_clip(load_cmu_clip(info.path), fps=10.0)               # CMU clip, if available
    trans = clip.trans_for(J0)           # smplx-style trans for a body with rest pelvis J0 = J(betas)[0]
"""
from pedx_graph.motion.bvh import BvhError, BvhMotion, BvhSkeleton, forward_kinematics, parse_bvh, read_bvh
from pedx_graph.motion.clips import (HOLDOUT, ClipInfo, MotionClip, default_motion_dir, is_holdout,
                                     list_clips, read_clip_index)
from pedx_graph.motion.gait import GAIT_KINDS, GaitParams, procedural_gait
from pedx_graph.motion.resample import interpolate_rotvecs, resample_clip, slerp_quaternions
from pedx_graph.motion.retarget import (CMU_BVH_SCALE, CMU_SETTLE_FRAMES, RetargetError, generic_rest_joints,
                                        load_cmu_clip, retarget_bvh, retarget_joint_error,
                                        smpl_joint_positions)

__all__ = [
    "BvhError", "BvhMotion", "BvhSkeleton", "forward_kinematics", "parse_bvh", "read_bvh",
    "HOLDOUT", "ClipInfo", "MotionClip", "default_motion_dir", "is_holdout", "list_clips", "read_clip_index",
    "GAIT_KINDS", "GaitParams", "procedural_gait",
    "interpolate_rotvecs", "resample_clip", "slerp_quaternions",
    "CMU_BVH_SCALE", "CMU_SETTLE_FRAMES", "RetargetError", "generic_rest_joints", "load_cmu_clip",
    "retarget_bvh", "retarget_joint_error", "smpl_joint_positions",
]
