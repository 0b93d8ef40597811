"""A track's linear system in chain + arrow block form: where each key lives, and the assembly of a
linearised graph into the blocks.

A track's graph links each frame's variables ``x_i = [root_i (3), trans_i (3), body_pose_i (69)]`` (75) to
the next frame's (the temporal prior) and to the one shared shape ``b`` (B) — a block-tridiagonal chain
with an "arrow".  The Gauss-Newton system of the whitened linear factors ``||A delta - b||^2`` is

    (A^T A + lambda I) delta = A^T b,

with ``A^T A`` made of ``frame`` (T, 75, 75), ``next`` (T - 1, 75, 75: rows frame i, columns frame i + 1),
``frame_shape`` (T, 75, B) and ``shape`` (B, B) blocks (:class:`ChainSystem`).  :class:`ChainLayout` maps
the track's keys to the blocks; the solvers solve the system (:mod:`pedx_graph.solvers.chain`).
"""
from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM

#: Dimension of one frame's variables (root, trans, body pose).
FRAME_DIM = ROOT_DIM + TRANS_DIM + BODY_POSE_DIM          # 75
_OFFSETS = (0, ROOT_DIM, ROOT_DIM + TRANS_DIM)


class NotAChainError(ValueError):
    """A factor links frames that are not consecutive, or a key outside the track's layout."""


@dataclass
class ChainSystem:
    """``A^T A`` and ``A^T b`` of a track's whitened linear factors in chain + arrow block form."""

    frame: np.ndarray
    """(T, 75, 75) information of each frame's variables."""
    next: np.ndarray
    """(T - 1, 75, 75) cross information between frame i (rows) and i + 1 (columns)."""
    frame_shape: np.ndarray
    """(T, 75, B) cross information between frame i and the shape."""
    shape: np.ndarray
    """(B, B) information of the shape."""
    grad_frame: np.ndarray
    """(T, 75) ``A^T b`` of each frame's variables."""
    grad_shape: np.ndarray
    """(B,) ``A^T b`` of the shape."""


class ChainLayout:
    """Where each key of a track lives in the chain system (frame index and offset, or the shape)."""

    def __init__(self, keys, num_betas: int) -> None:
        """``keys``: the track's :class:`factors.common.FrameKeys` in frame order (one shared shape key)."""
        self.keys = list(keys)
        self.num_frames = len(self.keys)
        self.num_betas = int(num_betas)
        self.shape_key = int(self.keys[0].betas)
        self._where: dict[int, tuple[int, int, int]] = {self.shape_key: (-1, 0, self.num_betas)}
        for i, k in enumerate(self.keys):
            if int(k.betas) != self.shape_key:
                raise NotAChainError("every frame must share one shape key")
            for key, off, dim in ((k.root, _OFFSETS[0], ROOT_DIM), (k.trans, _OFFSETS[1], TRANS_DIM),
                                  (k.body_pose, _OFFSETS[2], BODY_POSE_DIM)):
                self._where[int(key)] = (i, off, dim)
        self._plans: dict[tuple[int, ...], list[tuple[int, int, int, int]]] = {}

    def segments(self, factor_keys: tuple[int, ...]) -> list[tuple[int, int, int, int]]:
        """Column segments ``(col_start, width, frame (-1 = shape), offset)`` of a factor's ``A``, adjacent
        keys of one frame merged (cached per key tuple)."""
        plan = self._plans.get(factor_keys)
        if plan is not None:
            return plan
        plan, col = [], 0
        for key in factor_keys:
            try:
                frame, off, dim = self._where[key]
            except KeyError:
                raise NotAChainError(f"key {gtsam.DefaultKeyFormatter(key)} is not a frame or shape key") from None
            if plan and plan[-1][2] == frame and frame >= 0 and plan[-1][3] + plan[-1][1] == off \
                    and plan[-1][0] + plan[-1][1] == col:
                start, width, _, off0 = plan[-1]
                plan[-1] = (start, width + dim, frame, off0)
            else:
                plan.append((col, dim, frame, off))
            col += dim
        frames = sorted({s[2] for s in plan if s[2] >= 0})
        if len(frames) > 2 or (len(frames) == 2 and frames[1] - frames[0] != 1):
            raise NotAChainError(f"a factor links frames {frames}")
        self._plans[factor_keys] = plan
        return plan

    def assemble(self, linear: gtsam.GaussianFactorGraph, replace_rows: dict | None = None) -> ChainSystem:
        """Scatter ``A^T A`` and ``A^T b`` of every (whitened) factor of ``linear`` into a :class:`ChainSystem`.

        ``replace_rows``: factor index -> whitened Jacobian (same columns, any number of rows) used instead
        of that factor's own ``A`` for the information; such a factor adds nothing to ``A^T b``.

        Factors with the same key pattern (e.g. every frame's stereo factor) are grouped and their
        ``A^T A`` / ``A^T b`` added into the blocks of their frames with one indexed add per block.
        """
        t, d, nb = self.num_frames, FRAME_DIM, self.num_betas
        system = ChainSystem(frame=np.zeros((t, d, d)), next=np.zeros((max(t - 1, 0), d, d)),
                             frame_shape=np.zeros((t, d, nb)), shape=np.zeros((nb, nb)),
                             grad_frame=np.zeros((t, d)), grad_shape=np.zeros(nb))
        groups: dict[tuple, list] = {}
        seen: dict[tuple, int] = {}
        for j in range(linear.size()):
            factor = linear.at(j)
            if factor is None:
                continue
            if replace_rows and j in replace_rows:
                a_mat = np.asarray(replace_rows[j], dtype=float)
                b_vec = np.zeros(a_mat.shape[0])
            else:
                a_mat, b_vec = factor.jacobian()
            plan = self.segments(tuple(int(k) for k in factor.keys()))
            first = min((seg[2] for seg in plan if seg[2] >= 0), default=0)
            pattern = tuple((c, w, f - first if f >= 0 else -1, o) for c, w, f, o in plan)
            # n-th factor of this pattern on this frame -> group n: every group has distinct frames
            nth = seen[(pattern, first)] = seen.get((pattern, first), -1) + 1
            groups.setdefault((pattern, nth), []).append((first, a_mat, b_vec))
        for (pattern, _), items in groups.items():
            firsts = np.array([f for f, _, _ in items])
            hess = np.stack([a.T @ a for _, a, _ in items])
            grad = np.stack([a.T @ b for _, a, b in items])
            self.scatter_group(system, pattern, firsts, hess, grad)
        return system

    @staticmethod
    def scatter_group(system: ChainSystem, pattern: tuple, firsts: np.ndarray, hess: np.ndarray,
                      grad: np.ndarray) -> None:
        """Add a group's (G, c, c) Hessians and (G, c) gradients into ``system`` (``firsts``: each factor's
        first frame; ``pattern``: its segments with frames relative to that first frame)."""
        start = int(firsts[0])
        if np.array_equal(firsts, np.arange(start, start + len(firsts))):
            def frames(offset):                  # consecutive frames (the usual case): a plain slice
                return slice(start + offset, start + offset + len(firsts))

            def add(target, index, values):
                target[index] += values
        else:                                    # any order, repeats allowed
            def frames(offset):
                return firsts + offset
            add = np.add.at
        for ca, wa, fa, oa in pattern:
            sa = slice(ca, ca + wa)
            if fa < 0:
                system.grad_shape += grad[:, sa].sum(axis=0)
            else:
                add(system.grad_frame, (frames(fa), slice(oa, oa + wa)), grad[:, sa])
            for cb, wb, fb, ob in pattern:
                block = hess[:, sa, cb:cb + wb]
                if fa < 0:
                    if fb < 0:
                        system.shape += block.sum(axis=0)
                elif fb < 0:
                    add(system.frame_shape, (frames(fa), slice(oa, oa + wa)), block)
                elif fa == fb:
                    add(system.frame, (frames(fa), slice(oa, oa + wa), slice(ob, ob + wb)), block)
                elif fb == fa + 1:
                    add(system.next, (frames(fa), slice(oa, oa + wa), slice(ob, ob + wb)), block)

    def to_vector_values(self, delta_frames: np.ndarray, delta_shape: np.ndarray) -> gtsam.VectorValues:
        """A ``gtsam.VectorValues`` (tangent step per key) from per-frame (T, 75) and shape (B,) steps."""
        out = gtsam.VectorValues()
        for i, k in enumerate(self.keys):
            row = delta_frames[i]
            out.insert(k.root, row[0:3].copy())
            out.insert(k.trans, row[3:6].copy())
            out.insert(k.body_pose, row[6:FRAME_DIM].copy())
        out.insert(self.shape_key, np.asarray(delta_shape, dtype=float).copy())
        return out
