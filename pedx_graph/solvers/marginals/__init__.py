"""Marginal covariances of a track's estimate: the entry points that pick how they are computed.

Per frame the joint covariance of its variables with the shape (translation, root, body pose; 3D
keypoints from them) and the shape's, by a Gaussian (Laplace) approximation at the estimate
(``MarginalsConfig``, :class:`pedx_graph.graph.config.MarginalsConfig`):

* ``method="chain"`` (default): the information of the track in chain form — from the batched linearizer
  (:class:`pedx_graph.solvers.batched.BatchedLinearizer`, the terms' own assemblers, no GTSAM callbacks)
  or from ``graph.linearize`` — then a forward-backward pass (:mod:`~pedx_graph.solvers.marginals.chain`);
* ``method="gtsam"``: ``gtsam.Marginals`` per frame (the reference).

The LiDAR chamfer enters with point-to-plane information by default
(:mod:`~pedx_graph.solvers.marginals.plane`; decoded from GTSAM's linearisation by
:mod:`~pedx_graph.solvers.marginals.decode`); the result fields of a track are formed by
:mod:`~pedx_graph.solvers.marginals.fields`.  The package's modules, one job each: ``chain`` (linear
algebra), ``normals`` (mesh normals), ``plane`` and ``decode`` (the chamfer's plane information, from the
cache's matches or decoded), ``fields`` (JSON output).
"""
from __future__ import annotations

import logging
import time

import gtsam
from scipy.linalg import LinAlgError

from pedx_graph.graph.config import MarginalsConfig  # noqa: F401  (defined with the fit's config)
from pedx_graph.solvers.chain import FRAME_DIM, NotAChainError  # noqa: F401
from pedx_graph.solvers.marginals.chain import (POSE_SLICE, ROOT_SLICE, TRANS_SLICE, ChainInformation,  # noqa: F401
                                                TrackMarginals, chain_information, chain_marginals, gtsam_marginals,
                                                isam_frame_covariance, joint_marginal_matrix, key_dims)
from pedx_graph.solvers.marginals.decode import chamfer_plane_rows, point_to_plane_rows  # noqa: F401
from pedx_graph.solvers.marginals.fields import (frame_fields, keypoint_covariances,  # noqa: F401
                                                 keypoint_covariances_batch, marginals_to_fields)
from pedx_graph.solvers.marginals.normals import face_incidence, vertex_normals  # noqa: F401
from pedx_graph.solvers.marginals.plane import add_chamfer_plane_information, plane_rows  # noqa: F401

log = logging.getLogger(__name__)

__all__ = ["MarginalsConfig", "TrackMarginals", "ChainInformation", "FRAME_DIM", "ROOT_SLICE", "TRANS_SLICE",
           "POSE_SLICE", "NotAChainError", "chain_information", "chain_marginals", "gtsam_marginals",
           "isam_frame_covariance", "joint_marginal_matrix", "chamfer_plane_rows", "point_to_plane_rows",
           "plane_rows", "add_chamfer_plane_information", "face_incidence", "vertex_normals", "frame_fields",
           "keypoint_covariances", "keypoint_covariances_batch", "marginals_to_fields", "compute_marginals",
           "problem_linearizer", "problem_marginals", "track_marginals"]


def _batched_information(linearizer, values: gtsam.Values, config: MarginalsConfig, model):
    """Chain information from a :class:`~pedx_graph.solvers.batched.BatchedLinearizer` (no GTSAM callbacks),
    with the point-to-plane chamfer information when configured; None when that cannot be formed here."""
    plane = config.chamfer_information == "point_to_plane"
    if config.chamfer_information not in ("point_to_plane", "point_to_point"):
        raise ValueError(f"chamfer_information must be 'point_to_plane' or 'point_to_point', "
                         f"got {config.chamfer_information!r}")
    if plane and model is None:
        return None
    system = linearizer.system(values, skip=("lidar_chamfer",) if plane else ())
    if plane and not add_chamfer_plane_information(system, linearizer, model):
        return None
    return system


def compute_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys,
                      config: MarginalsConfig | None = None,
                      linear: gtsam.GaussianFactorGraph | None = None, prefetch=None,
                      factor_kinds=None, model=None, linearizer=None) -> TrackMarginals:
    """Joint marginals of every frame with the shape (``config.method``; chain falls back to gtsam).

    ``linear``: the graph already linearised at ``values`` (e.g. by the solver's last iteration), which
    saves the factor callbacks (most of the cost); ``prefetch(values, jacobians)``: called before linearising
    (``TrackProblem.prefetch`` batch-evaluates the body model for all frames).  ``factor_kinds`` (the
    problem's kind of each factor) and ``model`` (the body model): needed for the point-to-plane chamfer
    information (``config.chamfer_information``; the gtsam method always uses the linearisation as is).
    ``linearizer``: the track's :class:`~pedx_graph.solvers.batched.BatchedLinearizer`; the chain method then
    takes the information from its batched evaluation (equal to the linearisation, no callbacks) and the
    chamfer's matched vertices from the cache."""
    config = config or MarginalsConfig()
    num_betas = key_dims(values, int(keys[0].betas))
    if config.method == "gtsam":
        return gtsam_marginals(graph, values, keys, num_betas)
    if config.method != "chain":
        raise ValueError(f"marginals method must be 'chain' or 'gtsam', got {config.method!r}")
    t0 = time.perf_counter()
    if linearizer is not None and linear is None:
        info = _batched_information(linearizer, values, config, model)
        if info is not None:
            t_lin = time.perf_counter() - t0
            out = chain_marginals(info, config.diffuse_information)
            out.seconds = time.perf_counter() - t0
            out.linearize_seconds = t_lin
            return out
    if linear is None:
        if prefetch is not None:
            prefetch(values, True)
        linear = graph.linearize(values)
    t_lin = time.perf_counter() - t0
    replace = {}
    if config.chamfer_information == "point_to_plane" and factor_kinds is not None and model is not None:
        replace = chamfer_plane_rows(linear, values, keys, factor_kinds, model, config.vertex_match_tol_m)
    elif config.chamfer_information not in ("point_to_plane", "point_to_point"):
        raise ValueError(f"chamfer_information must be 'point_to_plane' or 'point_to_point', "
                         f"got {config.chamfer_information!r}")
    try:
        info = chain_information(linear, keys, num_betas, replace)
    except NotAChainError as exc:
        log.info("marginals: %s; using gtsam.Marginals", exc)
        return gtsam_marginals(graph, values, keys, num_betas)
    out = chain_marginals(info, config.diffuse_information)
    out.seconds = time.perf_counter() - t0
    out.linearize_seconds = t_lin
    return out


def problem_linearizer(problem):
    """A :class:`~pedx_graph.solvers.batched.BatchedLinearizer` of ``problem`` when its factors use the batched
    term cache (tracks built by ``build_track_graph``), else None."""
    if getattr(getattr(problem, "body", None), "term_cache", None) is None or not hasattr(problem, "layout"):
        return None
    from pedx_graph.solvers.batched import BatchedLinearizer
    try:
        return BatchedLinearizer(problem)
    except NotAChainError:
        return None


def problem_marginals(problem, values: gtsam.Values, ctx, config: MarginalsConfig | None = None) -> TrackMarginals:
    """:func:`compute_marginals` of a solved track's problem (a ``TrackProblem``) with everything it offers:
    its prefetch, factor kinds and batched linearizer, and the body model of ``ctx``."""
    return compute_marginals(problem.graph, values, problem.keys, config,
                             prefetch=getattr(problem, "prefetch", None),
                             factor_kinds=getattr(problem, "factor_kinds", None), model=ctx.model,
                             linearizer=problem_linearizer(problem))


def track_marginals(problem, values: gtsam.Values, ctx, config: MarginalsConfig | None = None
                    ) -> tuple[list[dict], dict]:
    """Per-frame and per-track covariance fields of ``values`` (the solved estimate of ``problem``).

    Never raises on an under-constrained track: failures are reported in the track fields
    (``marginals_error``) and every frame gets ``covariance_status = "failed"``.
    """
    from pedx_graph.graph.build import extract_estimate

    config = config or MarginalsConfig()
    try:
        marginals = problem_marginals(problem, values, ctx, config)
    except (RuntimeError, LinAlgError, ValueError) as exc:
        log.warning("marginals failed: %s", exc)
        return ([{"covariance_status": "failed"} for _ in problem.keys],
                {"marginals_error": f"{type(exc).__name__}: {exc}"})
    return marginals_to_fields(marginals, extract_estimate(problem, values, ctx), ctx.model, config)
