"""One observation on its way through a streaming update: its factors, values and systems, presolve and
iSAM2 commit."""
from __future__ import annotations

from dataclasses import dataclass

import gtsam

from pedx_graph.data.types import TrackFrame
from pedx_graph.solvers.frame_system import SpecRecorder
from pedx_graph.solvers.stream.state import ActiveTrack


@dataclass
class Step:
    """One observation on its way through :meth:`StreamingEstimator.add_frame`."""

    tid: str
    fr: TrackFrame
    state: ActiveTrack
    i: int
    """The frame's index in its track."""
    n_kinds: int
    """Number of the track's factors before this frame's."""
    graph: gtsam.NonlinearFactorGraph
    presolve_graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    """The new variables' initial values, then their presolved values."""
    specs: list | None = None
    """What the frame's factors measure (their :class:`~pedx_graph.solvers.frame_system.SpecRecorder`), when
    its own factors' systems are formed in a batch (``StreamConfig.batched_frame_systems``)."""
    recorder: SpecRecorder | None = None
    """The frame's factors' term cache (it serves the temporal prior's terms during the iSAM2 update)."""
    presolve_rest: gtsam.NonlinearFactorGraph | None = None
    """The presolve's factors outside the batched system (the shape prior)."""
    temporal: tuple | None = None
    """``(keys, (mixture, gap))`` of the frame's temporal prior (in the presolve's batched system)."""
    presolve_system: tuple | None = None
    """``(H, eta, f)`` in the presolve, at the initial values (batched): the frame's own factors but those
    of ``StreamConfig.presolve_exclude`` and its temporal prior's rows on the frame's variables."""
    own_system: tuple | None = None
    """``(H, eta, f)`` of the frame's own factors at the presolved values (batched), for iSAM2."""
    committed: bool = False
    stats: object = None
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    def point(self, values: gtsam.Values) -> tuple:
        """The frame's ``(world_R_body, trans, body_pose, betas)`` in ``values`` (the shape at its estimate
        when ``values`` lacks it): the state its factors are evaluated at."""
        k, isam = self.state.keys[self.i], self.state.smoother.isam
        betas = values.atVector(k.betas) if values.exists(k.betas) else isam.calculateEstimateVector(k.betas)
        return values.atRot3(k.root), values.atVector(k.trans), values.atVector(k.body_pose), betas

    def presolve(self) -> gtsam.Values:
        """The new variables optimised on the frame's presolve factors (and its batched system), the rest
        of the track held."""
        keys, smoother = self.state.keys[self.i], self.state.smoother
        if self.presolve_system is not None:
            self.values = smoother.presolve(keys, self.presolve_rest, self.values, self.presolve_system[:2])
        else:
            self.values = smoother.presolve(keys, self.presolve_graph, self.values)
        return self.values

    def commit(self):
        """The frame's iSAM2 update (from its presolved values); returns its update statistics."""
        try:
            self.stats = self.state.smoother.commit_frame(self.state.keys[self.i], self.graph, self.values,
                                                          own_system=self.own_system)
        finally:
            if self.recorder is not None:
                self.recorder.served.clear()         # the factors keep their recorder: free the arrays
        self.committed = True
        return self.stats
