"""Causal initialisation of a streamed frame: its centre, orientation, heading and first values from the
frames up to now only."""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import FrameKeys
from pedx_graph.data.ground import GroundFrame
from pedx_graph.data.types import Track
from pedx_graph.graph.build import select_template_poses
from pedx_graph.graph.config import FitConfig
from pedx_graph.graph.init import FrameMeasurements, initialise_from_measurements
from pedx_graph.solvers.lm import local_config, python_lm
from pedx_graph.solvers.stream.prediction import predicted_body_pose, predicted_init
from pedx_graph.solvers.stream.state import ActiveTrack, FrameInit


def causal_init(state: ActiveTrack, window: list[FrameMeasurements], model, config: FitConfig,
                half_window_s: float, ground: GroundFrame | None) -> FrameInit:
    """Centre, orientation, heading and speed of the newest frame from the recent frames only (the batch
    fit's initialisation on their cached measurements, ``window``; the heading over the last
    ``half_window_s`` seconds, one-sided).

    A frame with nothing to place it (neither LiDAR points nor a torso joint seen by two cameras, or a
    window the initialisation cannot place) takes its centre from the previous estimates (constant
    velocity) when the track has any, and so does a frame placed by the body's size alone; a track's
    first frame must be placeable, by the body's size at least (``ValueError``)."""
    # a frame that only the body's size places (one camera, no LiDAR: ~7 % depth sigma) is better predicted
    # from the track's previous estimates when it has any
    own = window[-1].placeable and window[-1].depth_source != "body_size"
    if own or state.previous is None:
        try:
            init = initialise_from_measurements(window, ground, f"{state.sequence}/{state.tracking_id}",
                                                min_speed_mps=config.noise.heading_min_speed_mps,
                                                half_window_s=half_window_s)
        except ValueError:
            if state.previous is None:
                raise
        else:
            sigma = 0.0 if init.heading_sigma_rad is None else float(init.heading_sigma_rad[-1])
            return FrameInit(init.world_p_centre[-1], init.world_R_body[-1], float(init.heading_yaw[-1]),
                             float(init.speed_mps[-1]), sigma)
    return predicted_init(state, model)


def starting_pose(state: ActiveTrack, init: FrameInit, ctx, config: FitConfig,
                  ground: GroundFrame | None) -> np.ndarray:
    """A new track's first body pose: the candidate (pose prior means) reprojecting best onto its labels."""
    track = Track(state.sequence, state.tracking_id, state.frames[-1:], state.calibrations, ground=ground)
    return select_template_poses(track, ctx, init.world_R_body[None], init.world_p_centre[None],
                                 all_views=config.terms.all_views)[0].copy()


def initial_values(state: ActiveTrack, i: int, init: FrameInit, ctx, config: FitConfig,
                   ground: GroundFrame | None, predict_body_pose: bool) -> gtsam.Values:
    """Initial values of frame ``i``'s new variables: the first frame from its causal initialisation and
    the best template pose (and a zero shape); later frames from the previous estimate (the body pose
    predicted, ``predict_body_pose``); the translation puts the pelvis on the initialisation's centre."""
    k = state.keys[i]
    values = gtsam.Values()
    if state.previous is None:
        values.insert(k.root, gtsam.Rot3(init.world_R_body))
        values.insert(k.body_pose, starting_pose(state, init, ctx, config, ground))
        betas = np.zeros(ctx.model.num_betas)
        values.insert(k.betas, betas)
    else:
        rot, _, _, betas = state.previous
        values.insert(k.root, gtsam.Rot3(rot))
        values.insert(k.body_pose, predicted_body_pose(state, i, predict_body_pose))
    pelvis_rest = ctx.model.rest_joints(betas)[0]
    values.insert(k.trans, np.asarray(init.world_p_centre - pelvis_rest, dtype=float))
    return values


def best_facing(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys: FrameKeys,
                iterations: int) -> gtsam.Values:
    """First frame without a trajectory heading: the torso-based facing can be reversed (front/back), so
    both it and its half-turn are solved on the frame alone (``iterations`` LM iterations) and the lower
    error is kept."""
    best = None
    for turn in (0.0, np.pi):
        candidate = gtsam.Values(values)
        candidate.update(keys.root, gtsam.Rot3.Rz(turn).compose(values.atRot3(keys.root)))
        solved, report = python_lm(graph, candidate, local_config(iterations), free_keys=candidate.keys())
        if best is None or report.final_error < best[1]:
            best = (solved, report.final_error)
    return best[0]
