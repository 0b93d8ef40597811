"""iSAM2 over a built batch problem: its frames fed one update at a time, then finalised (the same factors
as batch LM; used to check that both reach the same estimate)."""
from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np

from pedx_graph.solvers.isam import IncrementalTrack, IsamConfig


@dataclass
class IsamReport:
    """What :func:`isam_solve` did."""

    initial_error: float
    final_error: float
    update_seconds: list[float]
    """Wall time of each per-frame update (the streaming latency)."""
    finalize_seconds: float
    finalize_updates: int
    seconds: float


def frame_factor_groups(problem) -> list[gtsam.NonlinearFactorGraph]:
    """The factors of ``problem`` grouped by frame (track-level factors, the shape prior, go to frame 0)."""
    groups = [gtsam.NonlinearFactorGraph() for _ in problem.keys]
    for j, frame in enumerate(problem.factor_frames):
        groups[max(frame, 0)].add(problem.graph.at(j))
    return groups


def initial_frame_values(problem, i: int, previous: tuple | None) -> gtsam.Values:
    """Initial values of frame ``i``'s new variables: translation from the problem's (LiDAR) initialisation,
    root and body pose carried over from the previous frame's current estimate (``previous``)."""
    keys = problem.keys[i]
    values = gtsam.Values()
    if previous is None:
        values.insert(keys.root, problem.initial.atRot3(keys.root))
        values.insert(keys.body_pose, np.asarray(problem.initial.atVector(keys.body_pose)))
    else:
        rot, _, body_pose, _ = previous
        values.insert(keys.root, gtsam.Rot3(rot))
        values.insert(keys.body_pose, np.asarray(body_pose))
    values.insert(keys.trans, np.asarray(problem.initial.atVector(keys.trans)))
    if i == 0:
        values.insert(keys.betas, np.asarray(problem.initial.atVector(keys.betas)))
    return values


def isam_solve(problem, config: IsamConfig | None = None, solver_config=None
               ) -> tuple[gtsam.Values, IsamReport, IncrementalTrack]:
    """Solve a batch problem with iSAM2, one frame per update, then finalise; same factors as batch LM."""
    config = config or IsamConfig()
    t0 = time.perf_counter()
    track = IncrementalTrack.create(config, betas_key=problem.keys[0].betas)
    previous = None
    groups = frame_factor_groups(problem)
    for i, keys in enumerate(problem.keys):
        track.add_frame(keys, groups[i], initial_frame_values(problem, i, previous))
        previous = track.frame_estimate(keys)
    n_updates = len(track.updates)
    t1 = time.perf_counter()
    values = track.finalize(solver_config)
    return values, IsamReport(initial_error=float(problem.graph.error(problem.initial)),
                              final_error=float(problem.graph.error(values)),
                              update_seconds=[u.seconds for u in track.updates[:n_updates]],
                              finalize_seconds=time.perf_counter() - t1,
                              finalize_updates=len(track.updates) - n_updates,
                              seconds=time.perf_counter() - t0), track
