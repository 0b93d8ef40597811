"""iSAM2 over one pedestrian track: frames are added one at a time, the track is finalised at its end.

:class:`IncrementalTrack` wraps one ``gtsam.ISAM2``.  Each :meth:`IncrementalTrack.add_frame` adds the
factors of one frame (the frame's own terms and the temporal prior to the previous frame) with the initial
values of its new variables, runs one iSAM2 update and returns the update's wall time.  Per-frame
variables are relinearised when their linear delta exceeds ``relinearize_threshold`` (rad, m, rad).

The shared shape ``b0`` is linked to every frame factor, so relinearising it re-runs every frame factor
of the track (a spike growing with the track's length).  It therefore gets its own, looser threshold
(``ISAM2ThresholdMap``) and is held at its linearisation point (``noRelinKeys``) while streaming (or
except on every ``shape_relinearize_every``-th update); its linear delta is still solved for at every
update, so the estimate moves, only the Jacobians of old frames are not recomputed.  Likewise only the
newest ``relinearize_window`` frames may be relinearised, so no streaming update re-runs more than that
many frames' factors however long the track.

:meth:`IncrementalTrack.finalize` smooths the whole track: batch LM over all its factors warm-started from
the iSAM2 estimate (``finalize = "lm"``), or further iSAM2 updates with ``force_relinearize`` and no held
keys until the graph error stops decreasing (the batch optimum, up to the relinearisation thresholds).

The local solves (the presolve's Gauss-Newton step or LM, the ``lm`` finalisation) are those of
:mod:`pedx_graph.solvers.lm`; :mod:`pedx_graph.solvers.isam_batch` feeds a batch problem through this
class frame by frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, FrameKeys
from pedx_graph.solvers.frame_system import hessian_factor
from pedx_graph.solvers.lm import gauss_newton_step, local_config, python_lm


@dataclass
class IsamConfig:
    """iSAM2 settings of the streaming estimator."""

    relinearize_threshold_rad: float = 0.05
    """Relinearise a root orientation / body pose when a component of its delta exceeds this, radians."""
    relinearize_threshold_m: float = 0.02
    """Relinearise a translation when a component of its delta exceeds this, metres."""
    shape_relinearize_threshold: float = 0.1
    """Relinearise the shared shape when a coefficient's delta exceeds this (whitened betas units)."""
    shape_relinearize_every: int = 0
    """Relinearise the shape (when its delta exceeds ``shape_relinearize_threshold``) only on every N-th
    update; 0: never while streaming (held at its first linearisation point, its delta is still solved at
    every update; the finalisation relinearises it).  Relinearising the shape re-runs every frame factor
    of the track, a spike growing with the track's length; the keypoints are affine in the shape for a
    fixed pose, so holding it costs little accuracy (bench scene: causal MPJPE unchanged)."""
    relinearize_skip: int = 10
    """Check relinearisation every N updates (gtsam ``relinearizeSkip``)."""
    wildfire_threshold: float = 0.01
    """Back-substitution stops at a clique whose separator's delta changed by less than this (gtsam
    ``ISAM2GaussNewtonParams.wildfireThreshold``, default 0.001).  The shared shape is in every clique's
    separator and moves at every update, so at 0.001 each update's first estimate read-out back-substituted
    every frame of the track; the newest frames (the causal estimate, the previous frame the presolve
    holds) are at the top of the tree and always solved, older frames' estimates may lag by up to this
    much between relinearisations (as they would in iSAM2's own relinearisation check); the finalisation
    starts from a full back-substitution (``calculateBestEstimate``).  Bench scene: causal MPJPE the same
    to 1e-10 mm as at 0.001."""
    relinearize_window: int = 10
    """Only the variables of the newest N frames may be relinearised during streaming (older frames keep
    their linearisation point, their linear deltas are still solved; the finalisation relinearises
    everything), so a relinearisation step costs at most N frames' factors; 0: every frame."""
    presolve_iterations: int = 1
    """Iterations on a new frame's own variables (neighbours and shape held) before it enters iSAM2, so
    one iSAM2 update per frame starts near the optimum; 0 disables."""
    presolve_method: str = "gn"
    """``gn``: each presolve iteration is one lightly damped Gauss-Newton step (one linearisation of the new
    factors, a dense solve, no error evaluation); ``lm``: LM over the new variables (:func:`pedx_graph.solvers.lm.python_lm`
    with ``free_keys``; evaluates the error before and after each step and rejects steps that increase it: two more passes over the new factors)."""
    linearize_frame_factors: bool = True
    """Enter a frame's own factors (those on its root, translation and body pose and at most the shape:
    stereo, chamfer, translation, heading, pose and joint-limit terms) into iSAM2 as one Gaussian factor in
    Hessian form (a ``LinearContainerFactor``) linearised at the presolved values (the shape at its
    estimate), instead of as nonlinear factors.  iSAM2 re-eliminates the newest frames at every update and
    forms the normal equations of their cached linear factors each time: with the chamfer's ~900 Jacobian
    rows that was a third of the update's own cost; here the Hessian is formed once.  The frame is
    relinearised by :class:`IncrementalTrack` where iSAM2 would do it (every ``relinearize_skip`` updates,
    a frame of the ``relinearize_window`` one of whose variables left its ``relinearize_threshold_*``
    around the point; the shape only when not held), so the Gauss-Newton model is the same.  The temporal
    prior (it links two frames) and the shape prior stay nonlinear (the temporal prior in the frame's
    Gaussian factor, linearised at the previous frame's estimate, measured worse: causal MPJPE 116.8 vs
    109.8 mm on the bench scene); ``finalize = "isam"`` swaps the nonlinear factors back."""
    finalize: str = "lm"
    """How an ended track is smoothed: ``lm`` (batch Levenberg-Marquardt over all its factors, warm-started
    from the iSAM2 estimate) or ``isam`` (extra forced iSAM2 updates; stops within the relinearisation
    thresholds of the optimum)."""
    finalize_max_updates: int = 15
    """At most this many extra updates when a track ends (``finalize = "isam"``)."""
    finalize_relative_tol: float = 1e-5
    """Stop finalising when the graph error decreases by less than this fraction."""
    num_betas: int = 10
    """Dimension of the shape (must match the body model)."""


def make_isam(config: IsamConfig) -> gtsam.ISAM2:
    """A ``gtsam.ISAM2`` with per-variable-type relinearisation thresholds (symbols r, t, p, b)."""
    params = gtsam.ISAM2Params()
    thresholds = gtsam.ISAM2ThresholdMap()
    thresholds.insert(("r", np.full(3, config.relinearize_threshold_rad)))
    thresholds.insert(("t", np.full(3, config.relinearize_threshold_m)))
    thresholds.insert(("p", np.full(BODY_POSE_DIM, config.relinearize_threshold_rad)))
    thresholds.insert(("b", np.full(config.num_betas, config.shape_relinearize_threshold)))
    params.setRelinearizeThreshold(thresholds)
    params.relinearizeSkip = int(config.relinearize_skip)
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(float(config.wildfire_threshold)))
    return gtsam.ISAM2(params)


@dataclass
class UpdateStats:
    """One iSAM2 update."""

    seconds: float
    """Wall time of the whole update (presolve + iSAM2)."""
    relinearized: int
    """Number of variables relinearised in this update (-1: the batch LM finalisation)."""
    error_after: float | None = None
    isam_seconds: float = 0.0
    """Wall time of ``ISAM2.update`` and of linearising the frame's own factors for it
    (``IsamConfig.linearize_frame_factors``): the work the update did itself before."""


@dataclass
class _LinearizedFrame:
    """A frame's own factors as iSAM2 holds them (``IsamConfig.linearize_frame_factors``)."""

    keys: FrameKeys
    factors: gtsam.NonlinearFactorGraph
    """The nonlinear factors."""
    point: gtsam.Values
    """Their linearisation point."""
    slot: int = -1
    """Index of their ``LinearContainerFactor`` in the iSAM2 factor graph."""


def _vector_exceeds(a, b, threshold: float) -> bool:
    return bool(np.max(np.abs(np.asarray(a, float) - np.asarray(b, float))) > threshold)


@dataclass
class IncrementalTrack:
    """One iSAM2 over one track (see the module docstring).  Build with :meth:`create`."""

    config: IsamConfig
    isam: gtsam.ISAM2
    betas_key: int
    frame_keys: list[FrameKeys] = field(default_factory=list)
    updates: list[UpdateStats] = field(default_factory=list)
    factors: gtsam.NonlinearFactorGraph = field(default_factory=gtsam.NonlinearFactorGraph)
    """Every factor added so far (for errors, diagnostics and marginals)."""
    finalized: bool = False
    final_values: gtsam.Values | None = None
    """The smoothed estimate once :meth:`finalize` ran."""
    linearized: list[_LinearizedFrame] = field(default_factory=list)
    """The frames whose own factors iSAM2 holds linearised (``IsamConfig.linearize_frame_factors``)."""
    rotation_keys: set[int] = field(default_factory=set)
    """The keys of the frames' root orientations (``Rot3``)."""
    thresholds: dict[int, float] = field(default_factory=dict)
    """Relinearisation threshold of every variable (``IsamConfig.relinearize_threshold_*``)."""

    @staticmethod
    def create(config: IsamConfig | None = None, betas_key: int | None = None) -> "IncrementalTrack":
        config = config or IsamConfig()
        key = FrameKeys.for_frame(0).betas if betas_key is None else int(betas_key)
        return IncrementalTrack(config=config, isam=make_isam(config), betas_key=key)

    def _update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, hold_shape: bool,
                force: bool = False, hold_old_frames: bool = False, remove: list[int] | None = None
                ) -> tuple[UpdateStats, gtsam.ISAM2Result]:
        t0 = time.perf_counter()
        params = gtsam.ISAM2UpdateParams()
        held = gtsam.KeyList()
        if hold_shape and self.isam.valueExists(self.betas_key):
            held.push_back(self.betas_key)
        window = self.config.relinearize_window
        if hold_old_frames and window > 0 and len(self.frame_keys) > window:
            for keys in self.frame_keys[:-window]:
                held.push_back(keys.root)
                held.push_back(keys.trans)
                held.push_back(keys.body_pose)
        if held.size():
            params.noRelinKeys = held
        if remove:
            params.removeFactorIndices = list(remove)
        params.force_relinearize = bool(force)
        result = self.isam.update(graph, values, params)
        elapsed = time.perf_counter() - t0
        stats = UpdateStats(seconds=elapsed, relinearized=int(result.getVariablesRelinearized()),
                            isam_seconds=elapsed)
        return stats, result

    def add_frame(self, frame_keys: FrameKeys, factors: gtsam.NonlinearFactorGraph,
                  new_values: gtsam.Values, presolve_factors: gtsam.NonlinearFactorGraph | None = None
                  ) -> UpdateStats:
        """Add one frame: its factors (own terms, temporal prior to the previous frame, and on the first
        frame the shape prior) and the initial values of the variables not yet in the system.

        ``presolve_factors``: the factors the presolve uses (default: all of ``factors``), e.g. without the
        costly LiDAR chamfer term (:attr:`StreamConfig.presolve_exclude`).  The same as
        :meth:`presolve` then :meth:`commit_frame`."""
        t0 = time.perf_counter()
        new_values = self.presolve(frame_keys, factors if presolve_factors is None else presolve_factors,
                                   new_values)
        stats = self.commit_frame(frame_keys, factors, new_values)
        stats.seconds = time.perf_counter() - t0
        return stats

    def presolve(self, frame_keys: FrameKeys, factors: gtsam.NonlinearFactorGraph, new_values: gtsam.Values,
                 system: tuple | None = None) -> gtsam.Values:
        """The new variables optimised on ``factors`` with the existing ones held at their estimate
        (``IsamConfig.presolve_iterations``; ``new_values`` when 0).

        ``system``: ``(H, eta)``, the normal equations of further factors of the frame (columns ``[root,
        trans, body_pose, betas]`` of ``frame_keys``) at ``new_values`` with the shape at its estimate,
        formed elsewhere (:mod:`pedx_graph.solvers.frame_system`); only with one Gauss-Newton iteration."""
        if self.finalized:
            raise RuntimeError("cannot add frames to a finalised track")
        self.rotation_keys.add(int(frame_keys.root))
        if self.config.presolve_iterations > 0:
            own = None if system is None else (frame_keys.as_list(), system[0], system[1])
            return self._presolve(factors, new_values, own)
        return new_values

    def commit_frame(self, frame_keys: FrameKeys, factors: gtsam.NonlinearFactorGraph, new_values: gtsam.Values,
                     own_system: tuple | None = None) -> UpdateStats:
        """The iSAM2 update of one frame (see :meth:`add_frame`) from its (presolved) ``new_values``.

        ``own_system``: ``(H, eta, f)``, the normal equations of the frame's own factors (columns ``[root,
        trans, body_pose, betas]``) at ``new_values`` with the shape at its estimate, formed elsewhere
        (:mod:`pedx_graph.solvers.frame_system`, the same system as ``graph.linearize``); with
        ``IsamConfig.linearize_frame_factors`` they then enter iSAM2 without being linearised here."""
        if self.finalized:
            raise RuntimeError("cannot add frames to a finalised track")
        n = len(self.updates) + 1
        every = self.config.shape_relinearize_every
        hold = every <= 0 or n % every != 0
        t0 = time.perf_counter()
        cfg = self.config
        self.rotation_keys.add(int(frame_keys.root))
        self.thresholds.update({int(frame_keys.root): cfg.relinearize_threshold_rad,
                                int(frame_keys.trans): cfg.relinearize_threshold_m,
                                int(frame_keys.body_pose): cfg.relinearize_threshold_rad,
                                int(frame_keys.betas): cfg.shape_relinearize_threshold})
        skip = max(int(self.config.relinearize_skip), 1)
        check = n % skip == 0
        t1 = time.perf_counter()
        graph, linearized, remove = factors, [], []
        if self.config.linearize_frame_factors:
            graph, own = self._split_own(frame_keys, factors)
            new_frame = None
            if own.size():
                new_frame = _LinearizedFrame(frame_keys, own, self._with_estimates(new_values, own.keyVector()))
                linearized.append(new_frame)
            if check:
                for frame in self._to_relinearize(hold):
                    remove.append(frame.slot)
                    frame.point = self._with_estimates(gtsam.Values(), frame.factors.keyVector())
                    linearized.append(frame)
            for frame in linearized:
                if frame is new_frame and own_system is not None:
                    linear = hessian_factor(frame_keys, own.keyVector(), *own_system)
                else:
                    linear = gtsam.HessianFactor(frame.factors.linearize(frame.point))
                graph.add(gtsam.LinearContainerFactor(linear, frame.point))
        linearize_seconds = time.perf_counter() - t1
        stats, result = self._update(graph, new_values, hold_shape=hold, hold_old_frames=check, remove=remove)
        if linearized:
            slots = list(result.getNewFactorsIndices())[-len(linearized):]
            for frame, slot in zip(linearized, slots):
                frame.slot = int(slot)
            if linearized[0].keys is frame_keys:
                self.linearized.append(linearized[0])
        stats.relinearized += 3 * len(remove)
        stats.isam_seconds += linearize_seconds
        stats.seconds = time.perf_counter() - t0
        self.frame_keys.append(frame_keys)
        self.updates.append(stats)
        for j in range(factors.size()):
            self.factors.add(factors.at(j))
        return stats

    @staticmethod
    def _split_own(frame_keys: FrameKeys, factors: gtsam.NonlinearFactorGraph
                   ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.NonlinearFactorGraph]:
        """``factors`` split into (the others, the frame's own: on its variables and at most the shape)."""
        own_keys = {int(k) for k in frame_keys.as_list()}
        frame_only = own_keys - {int(frame_keys.betas)}
        rest, own = gtsam.NonlinearFactorGraph(), gtsam.NonlinearFactorGraph()
        for j in range(factors.size()):
            keys = {int(k) for k in factors.at(j).keys()}
            (own if keys <= own_keys and keys & frame_only else rest).add(factors.at(j))
        return rest, own

    def _to_relinearize(self, hold_shape: bool) -> list[_LinearizedFrame]:
        """The linearised frames iSAM2 would relinearise now: within the relinearisation window, a variable's
        estimate beyond its threshold from the linearisation point (the shape's only when not held)."""
        window = self.config.relinearize_window
        candidates = self.linearized[-window:] if window > 0 else self.linearized
        estimates: dict[int, object] = {}

        def beyond(key: int, point: gtsam.Values) -> bool:
            if key == self.betas_key and hold_shape:
                return False
            rotation = key in self.rotation_keys
            if key not in estimates:
                estimates[key] = self.isam.calculateEstimateRot3(key) if rotation else \
                    self.isam.calculateEstimateVector(key)
            if rotation:
                delta = point.atRot3(key).localCoordinates(estimates[key])
                return bool(np.max(np.abs(delta)) > self.thresholds[key])
            return _vector_exceeds(estimates[key], point.atVector(key), self.thresholds[key])

        return [frame for frame in candidates if any(beyond(int(k), frame.point) for k in frame.point.keys())]

    def _with_estimates(self, values: gtsam.Values, keys) -> gtsam.Values:
        """A copy of ``values`` plus the current estimate of each of ``keys`` it lacks."""
        out = gtsam.Values(values)
        for key in keys:
            if not out.exists(key):
                if int(key) in self.rotation_keys:
                    out.insert(key, self.isam.calculateEstimateRot3(key))
                else:
                    out.insert(key, np.asarray(self.isam.calculateEstimateVector(key), float).reshape(-1))
        return out

    def _unlinearize(self) -> None:
        """Give iSAM2 the frames' own factors back as nonlinear factors (e.g. to finalise with iSAM2)."""
        if not self.linearized:
            return
        graph = gtsam.NonlinearFactorGraph()
        for frame in self.linearized:
            for j in range(frame.factors.size()):
                graph.add(frame.factors.at(j))
        self._update(graph, gtsam.Values(), hold_shape=False, remove=[f.slot for f in self.linearized])
        self.linearized = []

    def _presolve(self, factors: gtsam.NonlinearFactorGraph, new_values: gtsam.Values, system: tuple | None = None
                  ) -> gtsam.Values:
        """Optimise the new variables on the new factors (and ``system``: ``(keys, H, eta)`` at the starting
        point, see :meth:`presolve`) with the existing ones held at their estimate."""
        free = [int(k) for k in new_values.keys()]
        keys = list(factors.keyVector()) + ([] if system is None else list(system[0]))
        local = self._with_estimates(new_values, keys)
        if system is not None and (self.config.presolve_method != "gn" or self.config.presolve_iterations != 1):
            raise ValueError("a presolve with a precomputed system takes one Gauss-Newton iteration")
        if self.config.presolve_method == "lm":
            local, _ = python_lm(factors, local, local_config(self.config.presolve_iterations), free_keys=free)
        elif self.config.presolve_method == "gn":
            for _ in range(self.config.presolve_iterations):
                local = gauss_newton_step(factors, local, free, system=system)
        else:
            raise ValueError(f"presolve_method must be 'gn' or 'lm', got {self.config.presolve_method!r}")
        out = gtsam.Values()
        for key in free:
            if key in self.rotation_keys:
                out.insert(key, local.atRot3(key))
            else:
                out.insert(key, np.asarray(local.atVector(key), float))
        return out

    def estimate(self) -> gtsam.Values:
        """Current estimate of every variable (a full back-substitution, not limited by
        ``IsamConfig.wildfire_threshold``; cost grows with the track; see :meth:`frame_estimate`)."""
        return self.isam.calculateBestEstimate()

    def frame_estimate(self, frame_keys: FrameKeys) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Current ``(world_R_body (3, 3), trans (3,), body_pose (69,), betas (B,))`` of one frame."""
        rot = self.isam.calculateEstimateRot3(frame_keys.root).matrix()
        trans = np.asarray(self.isam.calculateEstimateVector(frame_keys.trans), float).reshape(-1)
        body_pose = np.asarray(self.isam.calculateEstimateVector(frame_keys.body_pose), float).reshape(-1)
        betas = np.asarray(self.isam.calculateEstimateVector(self.betas_key), float).reshape(-1)
        return rot, trans, body_pose, betas

    def finalize(self, solver_config=None) -> gtsam.Values:
        """Smooth the whole track (``config.finalize``): batch LM from the iSAM2 estimate, or extra forced
        iSAM2 updates (shape not held) until the error stops decreasing."""
        if self.config.finalize == "lm":
            t0 = time.perf_counter()
            values, report = python_lm(self.factors, self.isam.calculateBestEstimate(), solver_config)
            self.updates.append(UpdateStats(seconds=time.perf_counter() - t0, relinearized=-1,
                                            error_after=report.final_error))
            self.finalized = True
            self.final_values = values
            return values
        if self.config.finalize != "isam":
            raise ValueError(f"finalize must be 'lm' or 'isam', got {self.config.finalize!r}")
        self._unlinearize()
        error = self.factors.error(self.isam.calculateBestEstimate())
        for _ in range(self.config.finalize_max_updates):
            stats, _ = self._update(gtsam.NonlinearFactorGraph(), gtsam.Values(), hold_shape=False, force=True)
            new_error = self.factors.error(self.isam.calculateBestEstimate())
            stats.error_after = float(new_error)
            self.updates.append(stats)
            if stats.relinearized == 0 or abs(error - new_error) <= self.config.finalize_relative_tol * max(error, 1e-12):
                break
            error = new_error
        self.finalized = True
        self.final_values = self.isam.calculateBestEstimate()
        return self.final_values
