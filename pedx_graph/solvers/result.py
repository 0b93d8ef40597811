"""The estimate of one track as every solver returns it (:class:`TrackResult`), and its record fields."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pedx_graph.data.types import SmplLabel
from pedx_graph.keypoints import PEDX_KEYPOINTS


@dataclass
class TrackResult:
    """Estimate of one track (world frame), with solver statistics."""

    sequence: str
    tracking_id: str
    frames: list[int]
    pose: np.ndarray
    """(T, 72) axis-angle, root first (root = world_R_body)."""
    betas: np.ndarray
    """(10,) the track's shared shape."""
    trans: np.ndarray
    """(T, 3) smplx translation (added after skinning), metres."""
    world_keypoints: np.ndarray
    """(T, 18, 3) PedX keypoints of the fitted model in the world frame, metres."""
    final_error: float
    initial_error: float
    iterations: int
    seconds: float
    solver: str
    extra_per_frame: list[dict] = field(default_factory=list)
    """Per-frame extra fields written with each label (covariances, diagnostics)."""
    extra_track: dict = field(default_factory=dict)
    """Per-track extra fields (shape covariance, residual totals, ...)."""

    def to_labels(self) -> list[SmplLabel]:
        """One PedX SMPL label per frame, with our extra fields (no timings: result files are the same for
        the same input, whatever ran them; times go to the summary)."""
        labels = []
        for i, frame in enumerate(self.frames):
            extra = {"keypoints_3d": self.world_keypoints[i], "keypoint_names": list(PEDX_KEYPOINTS),
                     "track_final_error": self.final_error, "track_iterations": self.iterations,
                     "solver": self.solver}
            if self.extra_per_frame:
                extra.update(self.extra_per_frame[i])
            labels.append(SmplLabel(sequence=self.sequence, frame=int(frame), tracking_id=self.tracking_id,
                                    betas=self.betas, pose=self.pose[i], trans=self.trans[i], extra=extra))
        return labels


def record_depth_sources(init, per_frame: list[dict], per_track: dict) -> None:
    """What placed each frame in depth (``TrackInit.depth_source``: lidar, stereo, multi_view, body_size) into
    the per-frame fields, and their counts into the track's (``depth_sources``); a track placed by body size
    alone is flagged ``depth_from_body_size`` (its depth is as uncertain as the person's size)."""
    sources = None if init is None else init.depth_source
    if not sources:
        return
    for fields, source in zip(per_frame, sources):
        fields["depth_source"] = source
    counts: dict[str, int] = {}
    for source in sources:
        counts[source] = counts.get(source, 0) + 1
    per_track["depth_sources"] = dict(sorted(counts.items()))
    per_track["depth_from_body_size"] = set(counts) <= {"body_size", "none"} and "body_size" in counts

