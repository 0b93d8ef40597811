"""The new frames' Gauss-Newton systems of one sample, formed for all its pedestrians in one batched pass
(presolve and iSAM2 update), and the batched body model they and the streamed factors evaluate."""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import FrameKeys
from factors.temporal_prior import held_normal_equations, pair_terms
from pedx_graph.graph.batch import BatchedBodyModel
from pedx_graph.solvers.frame_system import OWN_KINDS, add_new_frame_rows, frame_systems, register_sample
from pedx_graph.solvers.stream.config import StreamConfig
from pedx_graph.solvers.stream.step import Step


class StreamBody(BatchedBodyModel):
    """:class:`~pedx_graph.graph.batch.BatchedBodyModel` as the streamed factors' body model: its value cache
    (keypoints, their Jacobians, the chamfer vertex subset), prefetched for all pedestrians of a sample at
    once (:func:`prefetch_states`).  The factors do not register with it (a stream-long registry would
    grow without bound, and tracks share keys); its registry holds one sample's specs at a time, filed
    under per-pedestrian keys (:func:`~pedx_graph.solvers.frame_system.register_sample`), for the batched
    frame systems."""

    term_cache = None


def prefetch_states(body: BatchedBodyModel, states: list[tuple], jacobians: bool, vertices: bool,
                    kinds=frozenset()) -> None:
    """Evaluate the body model at every ``(world_R_body, trans, body_pose, betas)`` of ``states`` in one
    batched call; the factors' own calls at exactly these values are then cache look-ups
    (:class:`~pedx_graph.graph.batch.BatchedBodyModel`, keyed by the values)."""
    values, keys = gtsam.Values(), []
    for j, (rot, trans, body_pose, betas) in enumerate(states):
        k = FrameKeys.for_frame(j, j)
        values.insert(k.root, rot if isinstance(rot, gtsam.Rot3) else gtsam.Rot3(rot))
        values.insert(k.trans, np.asarray(trans, float))
        values.insert(k.body_pose, np.asarray(body_pose, float))
        values.insert(k.betas, np.asarray(betas, float))
        keys.append(k)
    body.prefetch(values, keys, jacobians, vertices=vertices, kinds=kinds)


def form_systems(body: BatchedBodyModel, steps: list[Step], presolve: bool, stream_config: StreamConfig) -> None:
    """Prefetch the body model at the steps' current values (their keypoint Jacobians; for the update
    also the chamfer's vertices) and, when batched, form each step's own factors' system there: for the
    presolve without the kinds of ``StreamConfig.presolve_exclude`` (``presolve_system``), for the update
    all of them (``own_system``)."""
    states = [s.point(s.values) for s in steps]
    isam = stream_config.isam
    batched = stream_config.batched() and (not presolve or (isam.presolve_method == "gn"
                                                            and isam.presolve_iterations == 1))
    served = [s for s in steps if s.specs is not None]
    if not batched or not served:
        prefetch_states(body, states, jacobians=True, vertices=not presolve)
        return
    exclude = set(stream_config.presolve_exclude or ()) if presolve else set()
    kinds = tuple(k for k in OWN_KINDS if k not in exclude)
    keys = register_sample(body, [(s.state.keys[s.i], s.specs or []) for s in steps])
    try:
        prefetch_states(body, states, jacobians=True, vertices=not presolve, kinds=frozenset(kinds))
        systems = frame_systems(body, keys, kinds)
    finally:
        body.clear_registry()
    # the temporal priors to the tracks' previous frames, batched: in the presolve their rows on the new
    # frame (previous frame held at its estimate); for the update served to the factors' callbacks at
    # the point iSAM2 linearises them (the previous frame's linearisation point)
    pairs, owners = [], []
    for j, (step, (rot, trans, body_pose, _)) in enumerate(zip(steps, states)):
        if step.temporal is None or (presolve and systems is None):
            continue
        (kr, kt, kp, *_), (mixture, gap) = step.temporal
        isam = step.state.smoother.isam
        if presolve:
            previous = (isam.calculateEstimateRot3(kr).matrix(), isam.calculateEstimateVector(kt),
                        isam.calculateEstimateVector(kp))
        else:
            theta = isam.getLinearizationPoint()
            previous = (theta.atRot3(kr).matrix(), theta.atVector(kt), theta.atVector(kp))
        rot = rot.matrix() if isinstance(rot, gtsam.Rot3) else np.asarray(rot)
        pairs.append((previous, (rot, np.asarray(trans), np.asarray(body_pose)), mixture, gap))
        owners.append(j)
    terms = pair_terms(pairs) if pairs else []
    if presolve and terms:              # the temporal term's rows on the new frames, through its assembler
        add_new_frame_rows(systems, owners, held_normal_equations([steps[j].temporal[0] for j in owners], pairs,
                                                                  terms))
    elif terms:
        for j, pair, (r, blocks) in zip(owners, pairs, terms):
            step = steps[j]
            if step.recorder is not None:
                step.recorder.serve("temporal_prior", step.temporal[0], [*pair[0], *pair[1]], r, blocks)
    for j, step in enumerate(steps):
        system = None if systems is None or step.specs is None else tuple(x[j] for x in systems)
        if presolve:
            step.presolve_system = system
        else:
            step.own_system = system
