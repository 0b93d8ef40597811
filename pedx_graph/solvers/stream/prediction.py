"""Prediction of a streamed frame's state from its track's previous estimates (constant velocity)."""
from __future__ import annotations

import numpy as np

from pedx_graph.solvers.stream.state import ActiveTrack, FrameInit


def predicted_body_pose(state: ActiveTrack, i: int, constant_velocity: bool = True) -> np.ndarray:
    """Body pose of frame ``i`` from the previous estimates: constant joint-angle velocity (scaled by the
    time steps, at most one previous step ahead; ``constant_velocity``, ``StreamConfig.predict_body_pose``)
    when the two frames before have estimates, else the previous estimate."""
    body_pose = np.asarray(state.previous[2], float)
    if not constant_velocity or state.before_previous is None or i < 2:
        return body_pose.copy()
    t0, t1, t2 = (state.frames[j].timestamp for j in (i - 2, i - 1, i))
    if not t1 > t0:
        return body_pose.copy()
    ratio = min(max((t2 - t1) / (t1 - t0), 0.0), 1.0)
    return body_pose + ratio * (body_pose - np.asarray(state.before_previous[2], float))


def predicted_init(state: ActiveTrack, model) -> FrameInit:
    """The newest frame's centre at constant velocity from the two previous pelvis estimates (``model``: the
    body model), its orientation the previous estimate's; heading unknown, speed 0."""
    rot, trans, _, betas = state.previous
    pelvis = model.rest_joints(betas)[0] + trans
    step = pelvis - state.last_pelvis if state.last_pelvis is not None else np.zeros(3)
    return FrameInit(pelvis + step, rot, float("nan"), 0.0)
