"""Joint marginal covariances of a track from its information (linear algebra only).

Gaussian (Laplace) approximation at the estimate: the information matrix ``Lambda = A^T A`` of the
whitened Jacobian ``A`` of the graph linearised there.  Never a full joint over all variables: only the
joint of each frame's variables with the shape,

    z_i = [delta_root_i (3, rad, right perturbation), trans_i (3, m), body_pose_i (69, rad), betas (B)]

is formed, as a (75 + B, 75 + B) block ``Sigma_i`` of ``Lambda^-1``:

* :func:`chain_marginals`: the track's graph is a chain of frames (the temporal prior links frame i - 1 and
  i) plus the shared shape (an "arrow").  A forward pass eliminates frame after frame (each passes
  information to the next frame and to the shape, exactly like a Kalman filter on ``(x_i, b)``), a backward
  pass (Rauch-Tung-Striebel) turns the conditionals ``x_i = K_i [x_{i+1}; b] + w_i`` into the joint
  marginals: ``Sigma_i = K_i Sigma_{i+1} K_i^T + W_i`` on the frame block, ``K_i Sigma_{i+1}[:, b]`` across.
  O(T (75 + B)^3), about a millisecond per frame.  When a frame's information block is not positive
  definite (no LiDAR and one view, a missing term), a diffuse information is added on its diagonal so the
  pass carries on, and the frame is flagged ``regularised``.
* :func:`gtsam_marginals`: ``gtsam.Marginals(graph, values).jointMarginalCovariance(frame keys + shape)``
  per frame (slow on long tracks: each query re-eliminates the graph; kept as the reference).
* :func:`isam_frame_covariance`: ``ISAM2.jointMarginalCovariance`` on the Bayes tree at the current
  linearisation point, at any time.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.linalg import cho_factor, cho_solve, LinAlgError

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM
from pedx_graph.solvers.chain import FRAME_DIM, ChainLayout, ChainSystem

ROOT_SLICE = slice(0, 3)
TRANS_SLICE = slice(3, 6)
POSE_SLICE = slice(6, FRAME_DIM)


#: The information of a track in chain + arrow block form (75-d frames, one B-d shape): the ``frame``,
#: ``next``, ``frame_shape`` and ``shape`` blocks of a :class:`~pedx_graph.solvers.chain.ChainSystem`.
ChainInformation = ChainSystem


@dataclass
class TrackMarginals:
    """Joint marginal covariance of each frame's variables with the shape."""

    frame_covariances: np.ndarray
    """(T, 75 + B, 75 + B) over ``[root (3), trans (3), body_pose (69), betas (B)]``."""
    regularised: np.ndarray
    """(T,) bool: the frame's information block needed the diffuse regulariser."""
    seconds: float = 0.0
    method: str = "chain"
    linearize_seconds: float = 0.0
    """Part of ``seconds`` spent linearising the graph (the factor callbacks; chain method)."""

    @property
    def shape_covariance(self) -> np.ndarray:
        """(B, B) marginal covariance of the shape."""
        return self.frame_covariances[0, FRAME_DIM:, FRAME_DIM:]


def key_dims(values: gtsam.Values, key: int) -> int:
    """Tangent dimension of ``key`` in ``values`` (3 for a rotation, else the vector's length)."""
    try:
        values.atRot3(key)
        return 3
    except RuntimeError:
        return int(np.asarray(values.atVector(key)).shape[0])


def chain_information(linear: gtsam.GaussianFactorGraph, keys, num_betas: int,
                      replace_rows: dict | None = None) -> ChainInformation:
    """The Hessians ``A^T A`` of the (whitened) linear factors in chain form
    (:meth:`pedx_graph.solvers.chain.ChainLayout.assemble`).

    ``keys`` are the track's :class:`FrameKeys` (frame order); ``replace_rows``: factor index -> whitened
    Jacobian to use instead of the factor's own (same columns).  Raises :class:`NotAChainError` when a
    factor links frames more than one apart.
    """
    return ChainLayout(keys, num_betas).assemble(linear, replace_rows)


def _chol(matrix: np.ndarray, diffuse: float) -> tuple[tuple, bool]:
    """Cholesky factor of a symmetric matrix; adds ``diffuse * I`` (once, then 1e3x) when not PD."""
    sym = 0.5 * (matrix + matrix.T)
    try:
        return cho_factor(sym, lower=True, check_finite=True), False
    except LinAlgError:
        pass
    eps = diffuse
    for _ in range(6):
        try:
            return cho_factor(sym + eps * np.eye(len(sym)), lower=True), True
        except LinAlgError:
            eps *= 1e3
    raise LinAlgError("information block is not positive definite even after regularisation")


def chain_marginals(info: ChainInformation, diffuse: float = 1e-6) -> TrackMarginals:
    """Joint marginals ``Sigma_i`` of ``(x_i, betas)`` for every frame by forward elimination + RTS pass."""
    t0 = time.perf_counter()
    t, d, b = info.frame.shape[0], FRAME_DIM, info.shape.shape[0]
    regularised = np.zeros(t, bool)
    gains, noises = [], []
    acc_xx = info.frame[0].copy()
    acc_xb = info.frame_shape[0].copy()
    acc_bb = info.shape.copy()
    for i in range(t - 1):
        factor, regularised[i] = _chol(acc_xx, diffuse)
        rhs = np.concatenate([info.next[i], acc_xb], axis=1)            # (D, D + B)
        g = cho_solve(factor, rhs)                                       # Lambda_ii^-1 [L_{i,i+1}, L_ib]
        gains.append(-g)
        noises.append(cho_solve(factor, np.eye(d)))
        cross_next = info.next[i]
        next_xx = info.frame[i + 1] - cross_next.T @ g[:, :d]
        next_xb = info.frame_shape[i + 1] - cross_next.T @ g[:, d:]
        acc_bb = acc_bb - acc_xb.T @ g[:, d:]
        acc_xx, acc_xb = next_xx, next_xb
    joint = np.block([[acc_xx, acc_xb], [acc_xb.T, acc_bb]])
    factor, regularised[t - 1] = _chol(joint, diffuse)
    covs = np.empty((t, d + b, d + b))
    covs[t - 1] = cho_solve(factor, np.eye(d + b))
    for i in range(t - 2, -1, -1):
        nxt = covs[i + 1]
        gain = gains[i]                                                 # (D, D + B)
        cov_xx = gain @ nxt @ gain.T + noises[i]
        cov_xb = gain @ nxt[:, d:]
        covs[i, :d, :d] = cov_xx
        covs[i, :d, d:] = cov_xb
        covs[i, d:, :d] = cov_xb.T
        covs[i, d:, d:] = nxt[d:, d:]
    covs = 0.5 * (covs + np.swapaxes(covs, 1, 2))
    return TrackMarginals(frame_covariances=covs, regularised=regularised, seconds=time.perf_counter() - t0,
                          method="chain")


def _frame_query_keys(k) -> list[int]:
    return [int(k.root), int(k.trans), int(k.body_pose), int(k.betas)]


def joint_marginal_matrix(joint, keys: list[int], dims: list[int]) -> np.ndarray:
    """Assemble a gtsam ``JointMarginal`` into one dense matrix in the order of ``keys``."""
    offsets = np.concatenate([[0], np.cumsum(dims)])
    out = np.zeros((offsets[-1], offsets[-1]))
    for a, ka in enumerate(keys):
        for c, kc in enumerate(keys):
            out[offsets[a]:offsets[a + 1], offsets[c]:offsets[c + 1]] = joint.at(ka, kc)
    return out


def gtsam_marginals(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, keys,
                    num_betas: int) -> TrackMarginals:
    """The same joint marginals with ``gtsam.Marginals`` (one joint query per frame; the reference)."""
    t0 = time.perf_counter()
    marginals = gtsam.Marginals(graph, values)
    dims = [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, num_betas]
    covs = np.stack([joint_marginal_matrix(marginals.jointMarginalCovariance(_frame_query_keys(k)),
                                           _frame_query_keys(k), dims) for k in keys])
    return TrackMarginals(frame_covariances=covs, regularised=np.zeros(len(keys), bool),
                          seconds=time.perf_counter() - t0, method="gtsam")


def isam_frame_covariance(isam: gtsam.ISAM2, frame_keys, num_betas: int) -> np.ndarray:
    """(75 + B, 75 + B) joint marginal of one frame's variables and the shape from an iSAM2 Bayes tree."""
    query = _frame_query_keys(frame_keys)
    joint = isam.jointMarginalCovariance(query)
    return joint_marginal_matrix(joint, query, [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, num_betas])
