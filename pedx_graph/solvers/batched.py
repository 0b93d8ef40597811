"""A track's error and Gauss-Newton system from the batched term cache, without a GTSAM callback per factor.

``graph.linearize`` calls every factor's Python callback and builds one ``JacobianFactor`` per factor; even
when the callbacks only look up results that :class:`pedx_graph.graph.batch.BatchedBodyModel` computed for
all frames at once, that round trip (~350 callbacks plus reading every factor's ``A`` back for the chain
solve) costs more than the numerics.  :class:`BatchedLinearizer` builds the same quantities directly: for
every registered term (:data:`factors.registry.TERMS`) it asks the term's assembler for the normal equations
of all its factors at the prefetched values (:class:`factors.terms.NormalEquations`: the term's own
residual, Jacobians, noise model and robust kernel, declared once in its ``factors/`` file) and scatters
them into the chain system; factors of unregistered kinds (the shape prior) stay in a small GTSAM
subgraph, linearised and assembled as usual.

The result is the system ``ChainLayout.assemble(graph.linearize(values))`` and the error
``graph.error(values)`` of the whole graph (tested against a fresh graph to round-off), so the LM iterates
are the same.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.registry import TERMS
from factors.temporal_prior import pair_dense
from factors.terms import NormalEquations
from pedx_graph.solvers.chain import FRAME_DIM, ChainLayout, ChainSystem


class BatchedLinearizer:
    """Error and chain system of a :class:`~pedx_graph.graph.build.TrackProblem` at any values."""

    def __init__(self, problem, layout: ChainLayout | None = None) -> None:
        self.problem = problem
        self.body = problem.body
        self.layout = layout or problem.layout
        self.rest = gtsam.NonlinearFactorGraph()
        self.served: dict[str, list[tuple[int, ...]]] = {kind: [] for kind in TERMS}
        """Kind -> the key tuples of the graph's factors of that kind assembled by their term."""
        for j, kind in enumerate(problem.factor_kinds):
            factor = problem.graph.at(j)
            keys = tuple(int(k) for k in factor.keys())
            if kind in self.served and keys in self.body.specs(kind):
                self.served[kind].append(keys)
            else:
                self.rest.add(factor)

    def _prefetch(self, values: gtsam.Values, jacobians: bool) -> None:
        self.problem.prefetch(values, jacobians)

    def normal_equations(self, kind: str, jacobians: bool = True) -> NormalEquations:
        """The served factors of ``kind`` at the last prefetch, from their term's assembler."""
        return TERMS[kind].assemble(self.body, self.served[kind], jacobians)

    # -- error -----------------------------------------------------------------------------------------
    def error(self, values: gtsam.Values, jacobians: bool = False) -> float:
        """``graph.error(values)``; ``jacobians`` also prefetches the derivatives (for a linearisation at the
        same values next)."""
        self._prefetch(values, jacobians)
        total = self.rest.error(values) if self.rest.size() else 0.0
        for kind, keys_list in self.served.items():
            if keys_list:
                total += float(self.normal_equations(kind, False).error.sum())
        return total

    # -- linear system ---------------------------------------------------------------------------------
    def system(self, values: gtsam.Values, skip=()) -> ChainSystem:
        """The whitened Gauss-Newton system of the whole graph at ``values`` in chain form (without the
        served factors of the kinds in ``skip``)."""
        layout = self.layout
        if self.rest.size():
            system = layout.assemble(self.rest.linearize(values))
        else:
            t, d, nb = layout.num_frames, FRAME_DIM, layout.num_betas
            system = ChainSystem(np.zeros((t, d, d)), np.zeros((max(t - 1, 0), d, d)), np.zeros((t, d, nb)),
                                 np.zeros((nb, nb)), np.zeros((t, d)), np.zeros(nb))
        self._prefetch(values, True)
        for kind, keys_list in self.served.items():
            if keys_list and kind not in skip:
                self.add(system, self.normal_equations(kind, True))
        return system

    def add(self, system: ChainSystem, ne: NormalEquations) -> None:
        """Scatter a term's normal equations into ``system`` (the temporal pair's compact form in place)."""
        if ne.hess is None and ne.structure is not None:
            self._add_pair(system, ne.keys, ne.structure)
        elif ne.columns is not None:
            self._add_columns(system, ne)
        else:
            self.scatter(system, ne.keys, ne.hess, ne.grad)

    def _add_columns(self, system: ChainSystem, ne: NormalEquations) -> None:
        """Normal equations on a few of their factors' columns (:attr:`NormalEquations.columns`): added entry by
        entry into the blocks of one frame and the shape when they lie there, else expanded to all columns and
        scattered."""
        pattern = self.layout.segments(ne.keys[0])
        where = [next((f, o + c - start) for start, w, f, o in pattern if start <= c < start + w) for c in ne.columns]
        frame = next(f for _, _, f, _ in pattern if f >= 0)
        if any(f >= 0 and f != frame for f, _ in where):
            width = sum(w for _, w, _, _ in pattern)
            hess, grad = np.zeros((len(ne.keys), width, width)), np.zeros((len(ne.keys), width))
            hess[:, ne.columns[:, None], ne.columns[None, :]] = ne.hess
            grad[:, ne.columns] = ne.grad
            self.scatter(system, ne.keys, hess, grad)
            return
        in_frame = np.array([f >= 0 for f, _ in where])
        fc, sc = np.flatnonzero(in_frame), np.flatnonzero(~in_frame)
        fo = np.array([o for f, o in where if f >= 0], dtype=np.int64)
        so = np.array([o for f, o in where if f < 0], dtype=np.int64)
        firsts = np.array([next(f for _, _, f, _ in self.layout.segments(keys) if f >= 0) for keys in ne.keys])
        hess, grad = ne.hess, ne.grad
        add = add_at if len(np.unique(firsts)) == len(firsts) else np.add.at
        add(system.frame, (firsts[:, None, None], fo[None, :, None], fo[None, None, :]), hess[:, fc[:, None], fc[None, :]])
        add(system.grad_frame, (firsts[:, None], fo[None, :]), grad[:, fc])
        if len(sc):
            add(system.frame_shape, (firsts[:, None, None], fo[None, :, None], so[None, None, :]),
                hess[:, fc[:, None], sc[None, :]])
            system.shape[np.ix_(so, so)] += hess[:, sc[:, None], sc[None, :]].sum(axis=0)
            system.grad_shape[so] += grad[:, sc].sum(axis=0)

    def _firsts(self, keys_list) -> np.ndarray:
        return np.array([self.layout.segments(keys)[0][2] for keys in keys_list])

    def scatter(self, system: ChainSystem, keys_list, hess: np.ndarray, grad: np.ndarray) -> None:
        """Add the (G, c, c) Hessians and (G, c) gradients of G factors with one key pattern (columns: their
        keys in order) into ``system``."""
        pattern = self.layout.segments(keys_list[0])
        rel = tuple((c, w, f - pattern[0][2] if f >= 0 else -1, o) for c, w, f, o in pattern)
        self.layout.scatter_group(system, rel, self._firsts(keys_list), hess, grad)

    def _add_pair(self, system: ChainSystem, keys_list, pair: dict) -> None:
        """Temporal factors in the compact form of :func:`factors.temporal_prior.pair_normal_equations`: on
        consecutive frames (the usual case) added block by block in place (no (P, 150, 150) temporary)."""
        num = len(keys_list)
        firsts = self._firsts(keys_list)
        if not np.array_equal(firsts, np.arange(firsts[0], firsts[0] + num)):
            self.scatter(system, keys_list, *pair_dense(pair))
            return
        utu, utl, ltl, ub, lb = pair["utu"], pair["utl"], pair["ltl"], pair["ub"], pair["lb"]
        fi, fj = slice(firsts[0], firsts[0] + num), slice(firsts[0] + 1, firsts[0] + 1 + num)
        frame, nxt, grad = system.frame, system.next, system.grad_frame
        utl_i, utl_j = utl[:, :6], utl[:, 6:]
        frame[fi, :6, :6] += utu[:, :6, :6]
        frame[fi, :6, 6:] -= utl_i
        frame[fi, 6:, :6] -= np.swapaxes(utl_i, 1, 2)
        frame[fi, 6:, 6:] += ltl
        frame[fj, :6, :6] += utu[:, 6:, 6:]
        frame[fj, :6, 6:] += utl_j
        frame[fj, 6:, :6] += np.swapaxes(utl_j, 1, 2)
        frame[fj, 6:, 6:] += ltl
        nxt[fi, :6, :6] += utu[:, :6, 6:]
        nxt[fi, :6, 6:] += utl_i
        nxt[fi, 6:, :6] -= np.swapaxes(utl_j, 1, 2)
        nxt[fi, 6:, 6:] -= ltl
        grad[fi, :6] += ub[:, :6]
        grad[fi, 6:] -= lb
        grad[fj, :6] += ub[:, 6:]
        grad[fj, 6:] += lb


def add_at(target: np.ndarray, index: tuple, values: np.ndarray) -> None:
    """``target[index] += values`` for an index without repeated entries (``np.add.at`` is the slow general case)."""
    target[index] += values
