"""Settings of the streaming estimator (:class:`StreamConfig`, besides the estimator's ``FitConfig``)."""
from __future__ import annotations

from dataclasses import dataclass, field

from pedx_graph.solvers.isam import IsamConfig


@dataclass
class StreamConfig:
    """Settings of the streaming estimator (besides the estimator's :class:`FitConfig`)."""

    isam: IsamConfig = field(default_factory=IsamConfig)
    """iSAM2 settings."""
    track_timeout_s: float = 1.0
    """A track not seen for this long (seconds of stream time) ends and is finalised."""
    heading_half_window_s: float = 0.35
    """Trajectory heading from the frames of the last ``heading_half_window_s`` seconds (one-sided)."""
    causal_covariance: bool = False
    """Also give each causal estimate its translation and keypoint covariances (iSAM2 joint marginal)."""
    marginals: bool = True
    """Marginal covariances of each finalised track."""
    diagnostics: bool = True
    """Residual / information diagnostics of each finalised track."""
    predict_body_pose: bool = True
    """Start a new frame's body pose at constant joint-angle velocity from the two previous estimates (scaled
    by the time steps, at most one previous step ahead) instead of at the previous estimate."""
    presolve_exclude: tuple = ("lidar_chamfer",)
    """Factor kinds left out of the presolve (they still enter the iSAM2 update): the chamfer term is half
    the cost of linearising a frame, and its nearest-vertex correspondences are poor before the frame is
    placed by the other terms."""
    batched_frame_systems: bool = True
    """Form the new frames' own factors' Gauss-Newton systems (for the presolve and for iSAM2) for all
    pedestrians of a sample in one batched pass (:mod:`pedx_graph.solvers.frame_system`; the same systems
    as GTSAM's linearisation) instead of through one GTSAM callback per factor and frame.  Used with the
    Gauss-Newton presolve of one iteration and ``IsamConfig.linearize_frame_factors``."""
    final_restart: bool = True
    """When a track ends, also solve it from scratch with the batch fit (staged LM, centred headings) and
    keep whichever estimate has the lower error on the track's streamed graph: the incremental path can
    end in a worse local optimum than a batch solve (measured on the simulator, see docs/solvers.md)."""

    def batched(self) -> bool:
        """Whether the new frames' own factors' systems are formed in a batch (``batched_frame_systems``
        with ``IsamConfig.linearize_frame_factors``)."""
        return bool(self.batched_frame_systems and self.isam.linearize_frame_factors)
