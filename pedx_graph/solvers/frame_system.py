"""The Gauss-Newton system of new frames' own factors, for all pedestrians of a sample in one batched pass.

A streamed frame's own factors (every registered term acting on one frame's root, translation and body
pose and at most the shape: :data:`factors.registry.OWN_FRAME_KINDS`) are linearised twice per frame: for
the presolve (at the initial values, without the chamfer) and for iSAM2 (at the presolved values).  Through
``graph.linearize`` each factor is a GTSAM callback that evaluates its term for one frame.  Here the terms
of every pedestrian of the sample are evaluated together instead, by the batched body model's term cache
(:class:`pedx_graph.graph.batch.BatchedBodyModel`), and each term's assembler (the same one the batch
linearizer uses, :class:`factors.terms.Term`) gives the whitened normal equations ``(A^T A, A^T b, b^T b)``
of all its factors, added here into each frame's columns ``[root (3), trans (3), body_pose (69),
betas (B)]``.  The result equals the ``HessianFactor`` of ``graph.linearize`` at the same point (tested to
round-off).

The streamed frames of different tracks use the same keys (``r0``, ``t0``, ...), so the factors register
their specs with a per-frame :class:`SpecRecorder` (given to the factors through :class:`RecordingBody`),
and :func:`register_sample` files them in the body model's registry under one set of keys per pedestrian
(``FrameKeys.for_frame(j, j)``, the keys the stream prefetches the sample with).  The registry then only
ever holds one sample's terms.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, FrameKeys
from factors.registry import OWN_FRAME_KINDS, TERMS
from factors.terms import NormalEquations
from pedx_graph.solvers.batched import add_at

#: Factor kinds whose frame systems are formed here (a frame's own factors: every registered term that acts
#: on one frame's variables).
OWN_KINDS = OWN_FRAME_KINDS
_FRAME_DIM = ROOT_DIM + TRANS_DIM + BODY_POSE_DIM          # 75: the columns before the shape's


class SpecRecorder:
    """Term cache of one frame's factors: records what each factor measures (:attr:`specs`) and serves the
    terms computed for it in a batch (:meth:`serve`) to the factors' callbacks while the values they are
    called with are exactly those the terms were computed at (otherwise the callbacks compute them)."""

    def __init__(self) -> None:
        self.specs: list[tuple[str, tuple[int, ...], object]] = []
        self.served: dict[tuple, tuple] = {}

    def register(self, kind: str, keys, spec) -> None:
        self.specs.append((kind, tuple(int(k) for k in keys), spec))

    def serve(self, kind: str, keys, point: list[np.ndarray], residual: np.ndarray, blocks: list[np.ndarray]) -> None:
        """Serve ``(residual, blocks)`` to the factor ``kind`` on ``keys`` at ``point`` (the value of each key:
        a rotation matrix (3, 3) or a vector)."""
        self.served[(kind, tuple(int(k) for k in keys))] = (point, residual, blocks)

    def lookup(self, kind, keys, values, jacobians):
        hit = self.served.get((kind, tuple(int(k) for k in keys))) if self.served else None
        if hit is None:
            return None
        point, residual, blocks = hit
        for key, expected in zip(keys, point):
            current = values.atRot3(key).matrix() if expected.ndim == 2 else values.atVector(key)
            if not np.array_equal(current, expected):
                return None
        return residual, (blocks if jacobians else None)


class RecordingBody:
    """``body`` as one frame's factors see it: every attribute is ``body``'s, except ``term_cache``, the
    frame's :class:`SpecRecorder`."""

    def __init__(self, body, recorder: SpecRecorder) -> None:
        self._body = body
        self.term_cache = recorder

    def __getattr__(self, name):
        return getattr(self._body, name)


def register_sample(body, frames: list[tuple[FrameKeys, list]]) -> list[FrameKeys]:
    """Replace ``body``'s term registry with the own-factor specs of one sample's frames: ``frames`` holds
    per pedestrian its real keys and its recorder's specs; pedestrian ``j``'s specs are filed under
    ``FrameKeys.for_frame(j, j)``.  Returns those keys."""
    body.clear_registry()
    out = []
    for j, (real, specs) in enumerate(frames):
        fake = FrameKeys.for_frame(j, j)
        to_fake = dict(zip(real.as_list(), fake.as_list()))
        for kind, keys, spec in specs:
            if kind in OWN_KINDS:
                body.register(kind, [to_fake[k] for k in keys], spec)
        out.append(fake)
    return out


def _columns(keys: tuple[int, ...], frame_keys: FrameKeys, num_betas: int) -> np.ndarray:
    """The columns of a frame system ``[root, trans, body_pose, betas]`` of a factor's keys (in their order)."""
    starts = {int(frame_keys.root): (0, ROOT_DIM), int(frame_keys.trans): (ROOT_DIM, TRANS_DIM),
              int(frame_keys.body_pose): (ROOT_DIM + TRANS_DIM, BODY_POSE_DIM),
              int(frame_keys.betas): (_FRAME_DIM, num_betas)}
    return np.concatenate([np.arange(starts[k][0], starts[k][0] + starts[k][1]) for k in keys])


def frame_systems(body, keys: list[FrameKeys], kinds) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The whitened normal equations of the registered factors of ``kinds`` of each frame of ``keys`` at the
    body's last prefetch (which must have evaluated these kinds, with Jacobians): ``H`` (F, D, D),
    ``g = A^T b`` (F, D) and ``f = b^T b`` (F,), columns ``[root, trans, body_pose, betas]`` (D = 75 + B),
    each kind's factors from its term's assembler (:data:`factors.registry.TERMS`).  None when the prefetch
    had no Jacobians (then linearise with GTSAM)."""
    if not body.has_jacobians:
        return None
    num_betas = int(body.num_betas)
    dim = _FRAME_DIM + num_betas
    n = len(keys)
    hess, grad, const = np.zeros((n, dim, dim)), np.zeros((n, dim)), np.zeros(n)
    position: dict[int, int] = {}
    for j, k in enumerate(keys):
        position[int(k.root)] = position[int(k.trans)] = position[int(k.body_pose)] = j
    for kind in kinds:
        keys_list = list(body.specs(kind))
        if not keys_list:
            continue
        ne = TERMS[kind].assemble(body, keys_list, True)
        frames = np.array([position[next(k for k in fk if k in position)] for fk in ne.keys], dtype=np.int64)
        cols = _columns(ne.keys[0], keys[frames[0]], num_betas)
        if ne.columns is not None:                       # the term's Jacobian touches only these columns
            cols = cols[ne.columns]
        add = add_at if len(np.unique(frames)) == len(frames) else np.add.at
        add(hess, (frames[:, None, None], cols[None, :, None], cols[None, None, :]), ne.hess)
        add(grad, (frames[:, None], cols[None, :]), ne.grad)
        add(const, frames, ne.bb)
    return hess, grad, const


def add_new_frame_rows(system: tuple[np.ndarray, np.ndarray, np.ndarray], frames: list[int],
                       ne: NormalEquations) -> None:
    """Add to ``system`` (:func:`frame_systems`' ``(H, g, f)``) a term's normal equations on the new frames'
    own columns ``[root, trans, body_pose]`` (factor ``n`` into frame ``frames[n]``): the presolve's temporal
    priors to the held previous frames (:func:`factors.temporal_prior.held_normal_equations`)."""
    hess, grad, const = system
    rows = np.asarray(frames, dtype=np.int64)
    add = add_at if len(np.unique(rows)) == len(rows) else np.add.at
    add(hess, (rows, slice(0, _FRAME_DIM), slice(0, _FRAME_DIM)), ne.hess)
    add(grad, (rows, slice(0, _FRAME_DIM)), ne.grad)
    add(const, rows, ne.bb)


def hessian_factor(frame_keys: FrameKeys, present, hess: np.ndarray, grad: np.ndarray, const: float
                   ) -> gtsam.HessianFactor:
    """One frame's system (columns ``[root, trans, body_pose, betas]``) as a ``gtsam.HessianFactor`` on the
    keys of ``frame_keys`` in ``present`` (those its factors touch; the other columns must be zero).  GTSAM's
    Python constructors take at most three keys, so a four-key factor is the sum of three partial ones (their
    blocks split the system's blocks between them) combined into one."""
    present = {int(k) for k in present}
    num_betas = hess.shape[0] - _FRAME_DIM
    bounds = {int(frame_keys.root): (0, ROOT_DIM), int(frame_keys.trans): (ROOT_DIM, ROOT_DIM + TRANS_DIM),
              int(frame_keys.body_pose): (ROOT_DIM + TRANS_DIM, _FRAME_DIM),
              int(frame_keys.betas): (_FRAME_DIM, _FRAME_DIM + num_betas)}
    keys = [k for k in frame_keys.as_list() if int(k) in present]
    sl = [slice(*bounds[int(k)]) for k in keys]

    def blk(i, j):
        return hess[sl[i], sl[j]]

    def vec(i):
        return grad[sl[i]]

    if len(keys) == 1:
        return gtsam.HessianFactor(keys[0], blk(0, 0), vec(0), const)
    if len(keys) == 2:
        return gtsam.HessianFactor(keys[0], keys[1], blk(0, 0), blk(0, 1), vec(0), blk(1, 1), vec(1), const)
    if len(keys) == 3:
        return gtsam.HessianFactor(keys[0], keys[1], keys[2], blk(0, 0), blk(0, 1), blk(0, 2), vec(0),
                                   blk(1, 1), blk(1, 2), vec(1), blk(2, 2), vec(2), const)

    def zero(i, j):
        return np.zeros((sl[i].stop - sl[i].start, sl[j].stop - sl[j].start))

    parts = gtsam.GaussianFactorGraph()
    parts.push_back(gtsam.HessianFactor(keys[0], keys[1], keys[2], blk(0, 0), blk(0, 1), blk(0, 2), vec(0),
                                        blk(1, 1), blk(1, 2), vec(1), blk(2, 2), vec(2), const))
    parts.push_back(gtsam.HessianFactor(keys[0], keys[1], keys[3], zero(0, 0), zero(0, 1), blk(0, 3),
                                        np.zeros(ROOT_DIM), zero(1, 1), blk(1, 3), np.zeros(TRANS_DIM),
                                        blk(3, 3), vec(3), 0.0))
    parts.push_back(gtsam.HessianFactor(keys[2], keys[3], zero(2, 2), blk(2, 3), np.zeros(BODY_POSE_DIM),
                                        zero(3, 3), np.zeros(num_betas), 0.0))
    return gtsam.HessianFactor(parts)
