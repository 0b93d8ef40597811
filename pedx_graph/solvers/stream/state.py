"""What the streaming estimator keeps of each active track, and what it returns for each frame."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from factors.common import FrameKeys
from pedx_graph.data.types import TrackFrame
from pedx_graph.graph.init import FrameMeasurements
from pedx_graph.solvers.isam import IncrementalTrack


@dataclass
class FrameEstimate:
    """The current (causal) estimate of one pedestrian in one frame."""

    tracking_id: str
    frame: int
    timestamp: float
    pose: np.ndarray
    """(72,) axis-angle, root first."""
    betas: np.ndarray
    """(B,) the track's current shape."""
    trans: np.ndarray
    """(3,) metres."""
    world_keypoints: np.ndarray
    """(N, 3) metres, world frame: the fitted model's keypoints (PedX's 18; a detector track's fit layout
    has 18 + E, and ``stream_track`` reports PedX's 18 of the original model instead)."""
    update_seconds: float
    """Wall time of this frame's update (causal initialisation, factors, initial values, presolve, iSAM2
    update, reading the estimate and its keypoints, plus an equal share of the sample's batched body-model
    calls, :meth:`StreamingEstimator.add_frame`; not the optional covariances)."""
    isam_seconds: float = 0.0
    """Wall time of the ``ISAM2.update`` call and of linearising the frame's own factors for it
    (:attr:`pedx_graph.solvers.isam.UpdateStats.isam_seconds`)."""
    cpu_seconds: float = 0.0
    """CPU time of the same work as ``update_seconds`` (this process; robust to a shared machine)."""
    extra: dict = field(default_factory=dict)
    """Covariances when ``causal_covariance`` is on."""


@dataclass
class FrameInit:
    """Causal initialisation of the newest frame of a track."""

    world_p_centre: np.ndarray
    """(3,) pelvis estimate, metres."""
    world_R_body: np.ndarray
    """(3, 3) upright orientation."""
    heading_yaw: float
    """Trajectory heading (rad), NaN when unknown."""
    speed_mps: float
    """Trajectory speed, m/s."""
    heading_sigma_rad: float = 0.0
    """Uncertainty of the trajectory heading (``TrackInit.heading_sigma_rad``), radians."""


@dataclass
class ActiveTrack:
    """One track while it streams: its frames, factors' bookkeeping, smoother and latest estimates."""

    sequence: str
    tracking_id: str
    calibrations: dict
    smoother: IncrementalTrack
    rng: np.random.Generator
    frames: list[TrackFrame] = field(default_factory=list)
    measurements: list[FrameMeasurements] = field(default_factory=list)
    """Each frame's initialisation measurements (:func:`~pedx_graph.graph.init.measure_frame`), taken once."""
    keys: list[FrameKeys] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    factor_frames: list[int] = field(default_factory=list)
    last_seen: float = -np.inf
    frame_seconds: list[float] = field(default_factory=list)
    """Wall time of each frame's whole update (``FrameEstimate.update_seconds``)."""
    previous: tuple | None = None
    """Estimate ``(world_R_body, trans, body_pose, betas)`` of the newest frame right after its update."""
    before_previous: tuple | None = None
    """The same for the frame before (constant-velocity prediction of the body pose)."""
    last_pelvis: np.ndarray | None = None
    """Pelvis of the frame before ``previous`` (constant-velocity prediction of unplaceable frames)."""

    def rollback(self, i: int, n_kinds: int) -> None:
        """Forget frame ``i`` onwards and the factors from the ``n_kinds``-th on (an observation that
        failed before it entered iSAM2)."""
        del self.measurements[i:], self.frames[i:], self.keys[i:]
        del self.kinds[n_kinds:], self.factor_frames[n_kinds:]

    def read_estimate(self, i: int, model) -> tuple:
        """Read frame ``i``'s new estimate from the smoother into ``previous`` (shifting the older ones;
        ``model``: the body model, for the pelvis) and return it."""
        if self.previous is not None:
            self.last_pelvis = model.rest_joints(self.previous[3])[0] + self.previous[1]
        self.before_previous = self.previous
        self.previous = self.smoother.frame_estimate(self.keys[i])
        return self.previous
