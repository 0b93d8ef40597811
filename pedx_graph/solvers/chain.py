"""The direct damped solve of a track's chain + arrow system (:mod:`pedx_graph.graph.layout`).

:func:`solve_chain` solves ``(A^T A + lambda I) delta = A^T b`` exactly by a block Cholesky sweep along the
frames with the shape eliminated last (Schur complement): O(T (75^3 + 75^2 B)), no fill-in beyond the
blocks.  GTSAM's ``GaussianFactorGraph.optimize`` solves the same system by sparse QR on the stacked
Jacobians (every row of every factor), several times slower on these tall factors (measured in
benchmarks/results/bench_fit.md).
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import LinAlgError
from scipy.linalg.blas import dsyrk, dtrsm
from scipy.linalg.lapack import dpotrf

# the layout's names, imported from here by the solvers that assemble and solve a chain system
from pedx_graph.graph.layout import FRAME_DIM, ChainLayout, ChainSystem, NotAChainError

__all__ = ["FRAME_DIM", "ChainLayout", "ChainSystem", "NotAChainError", "solve_chain"]


def _potrf(matrix: np.ndarray, overwrite: bool = False) -> np.ndarray:
    """Lower Cholesky factor (LAPACK ``dpotrf`` on the lower triangle, no Python-level checks; the upper
    triangle is left as it was); LinAlgError when not PD.  ``overwrite``: factor a Fortran-ordered
    ``matrix`` in place."""
    low, info = dpotrf(matrix, lower=1, clean=0, overwrite_a=1 if overwrite else 0)
    if info != 0:
        raise LinAlgError(f"matrix is not positive definite (dpotrf info {info})")
    return low


def _damped_block(block: np.ndarray, damping: float) -> np.ndarray:
    """A Fortran-ordered copy of a symmetric block's transpose (the same matrix when exactly symmetric) with
    ``damping`` added on the diagonal."""
    out = block.T.copy(order="F")
    out.flat[::out.shape[0] + 1] += damping
    return out


def solve_chain(system: ChainSystem, damping: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Solve ``(A^T A + damping I) delta = A^T b``; returns (delta_frames (T, 75), delta_shape (B,)).

    The forward sweep keeps each frame's right-hand sides ``[g_i, H_i,shape, H_i,i+1]`` (75, 1 + B + 75) in
    one row-major array, i.e. column-major transposes, and solves them in place with a right-side
    triangular solve (``X L^-T``, ~1.6x faster in OpenBLAS than the left-side solve at these sizes); the
    next frame's block is updated with a symmetric rank-k product (``dsyrk``, half the flops of a general
    product).  Raises ``scipy.linalg.LinAlgError`` when the damped system is not positive definite.
    """
    t, d = system.frame.shape[:2]
    nb = system.shape.shape[0]
    width = 1 + nb
    work = np.empty((t, d, width + d))
    work[:, :, 0] = system.grad_frame
    work[:, :, 1:width] = system.frame_shape
    work[:t - 1, :, width:] = system.next
    work[t - 1, :, width:] = 0.0
    lowers = []
    block = _damped_block(system.frame[0], damping)
    for i in range(t):
        low = _potrf(block, overwrite=True)
        lowers.append(low)
        # [y_i, w_i] = L_i^-1 [rhs_i, next_i], as [rhs_i, next_i]^T L_i^-T on the transposed (column-major) view
        work[i] = dtrsm(1.0, low, work[i].T, side=1, lower=1, trans_a=1, overwrite_b=1).T
        if i + 1 < t:
            w = work[i, :, width:]
            block = dsyrk(-1.0, w.T, beta=1.0, c=_damped_block(system.frame[i + 1], damping), trans=0, lower=1,
                          overwrite_c=1)                                   # H_i+1 + damping - w^T w
            work[i + 1, :, :width] -= w.T @ work[i, :, :width]
    sol = np.empty((t, d, width))
    for i in range(t - 1, -1, -1):
        rhs = work[i, :, :width] if i == t - 1 else work[i, :, :width] - work[i, :, width:] @ sol[i + 1]
        sol[i] = dtrsm(1.0, lowers[i], rhs.T, side=1, lower=1, trans_a=0).T            # L_i^-T rhs
    # Shape by the Schur complement: sol[:, :, 0] = H_ff^-1 g_f, sol[:, :, 1:] = H_ff^-1 H_fb.
    schur = system.shape + damping * np.eye(nb) - np.einsum("tdb,tdc->bc", system.frame_shape, sol[:, :, 1:])
    schur_rhs = system.grad_shape - np.einsum("tdb,td->b", system.frame_shape, sol[:, :, 0])
    low = _potrf(0.5 * (schur + schur.T))
    delta_shape = dtrsm(1.0, low, dtrsm(1.0, low, schur_rhs[:, None], lower=1), lower=1, trans_a=1)[:, 0]
    delta_frames = sol[:, :, 0] - sol[:, :, 1:] @ delta_shape
    if not (np.all(np.isfinite(delta_frames)) and np.all(np.isfinite(delta_shape))):
        raise LinAlgError("non-finite step")
    return delta_frames, delta_shape
