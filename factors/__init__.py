"""Custom GTSAM factors of pedx-graph: one energy term of the PedX method per module.

Every ``make_*_factor`` returns one factor per frame (per frame pair for the temporal prior), or ``None``
when the frame has no measurement for that term.  Per-frame keys are ``[root (Rot3), trans (3),
body_pose (69), betas (B)]`` (:class:`FrameKeys`); see docs/factors.md for residuals, units and noise.

=========================  ===============================  ============================================
term                       module                           factory
=========================  ===============================  ============================================
E_J (every labelled view)  :mod:`factors.stereo_reprojection`  :func:`make_reprojection_factor`
E_3d (Eq. 4)               :mod:`factors.lidar_chamfer`        :func:`make_lidar_chamfer_factor`
E_T (Eq. 2)                :mod:`factors.translation_prior`    :func:`make_translation_prior_factor`
E_D (Eq. 3)                :mod:`factors.heading_prior`        :func:`make_heading_prior_factor`
E_P (GMM)                  :mod:`factors.pose_prior`           :func:`make_pose_prior_factor`
E_P (joint limits)         :mod:`factors.joint_limits`         :func:`make_joint_limit_factor`
shape                      :mod:`factors.shape_prior`          :func:`make_shape_prior_factor`
shape support (hinge)      :mod:`factors.shape_prior`          :func:`make_shape_support_factor`
E_tp (Eq. 10)              :mod:`factors.temporal_prior`       :func:`make_temporal_prior_factor`
E_G (stance foot)          :mod:`factors.ground_contact`       :func:`make_ground_contact_factor`
=========================  ===============================  ============================================

Each term module also declares its noise model (``noise_of``), its assembler to Gauss-Newton normal
equations and its :class:`factors.terms.Term`, listed once in :mod:`factors.registry` (how to add one:
docs/adding-a-term.md).
"""
from factors.common import FrameKeys, FrameState, MaxMixture, make_noise, read_frame_state
from factors.ground_contact import make_ground_contact_factor
from factors.heading_prior import heading_sigma, make_heading_prior_factor, trajectory_headings
from factors.joint_limits import DEFAULT_JOINT_LIMITS, JointLimit, make_joint_limit_factor
from factors.lidar_chamfer import make_lidar_chamfer_factor
from factors.pose_prior import make_pose_prior_factor
from factors.shape_prior import make_shape_prior_factor, make_shape_support_factor
from factors.stereo_reprojection import (ImageKeypoints, StereoKeypoints, images_from_views,
                                         make_reprojection_factor, make_stereo_reprojection_factor)
from factors.temporal_prior import (TEMPORAL_DIM, make_temporal_prior_factor, sequence_differences,
                                    temporal_difference)
from factors.translation_prior import make_translation_prior_factor

__all__ = [
    "FrameKeys", "FrameState", "MaxMixture", "make_noise", "read_frame_state",
    "make_stereo_reprojection_factor", "StereoKeypoints", "make_reprojection_factor", "ImageKeypoints",
    "images_from_views",
    "make_lidar_chamfer_factor",
    "make_translation_prior_factor",
    "make_heading_prior_factor", "heading_sigma", "trajectory_headings",
    "make_pose_prior_factor",
    "make_joint_limit_factor", "JointLimit", "DEFAULT_JOINT_LIMITS",
    "make_shape_prior_factor", "make_shape_support_factor",
    "make_temporal_prior_factor", "temporal_difference", "sequence_differences", "TEMPORAL_DIM",
    "make_ground_contact_factor",
]
