"""A track's error and Gauss-Newton system from the batched term cache, without a GTSAM callback per factor.

``graph.linearize`` calls every factor's Python callback and builds one ``JacobianFactor`` per factor; even
when the callbacks only look up results that :class:`pedx_graph.graph.batch.BatchedBodyModel` computed for
all frames at once, that round trip (~350 callbacks plus reading every factor's ``A`` back for the chain
solve) costs more than the numerics.  :class:`BatchedLinearizer` builds the same quantities directly:

* for the cached terms (stereo reprojection, LiDAR chamfer, pose prior, temporal prior) it takes each
  factor's residual and Jacobian blocks from the cache, whitens them exactly as the factor's GTSAM noise
  model does (per-row sigmas; per-row robust kernels with their IRLS weights, see
  :func:`factors.common.row_loss_and_weight`; unit noise for the terms that whiten inside the callback) and
  adds ``A^T A`` / ``A^T b`` into the chain system in batched products;
* every other factor (translation and heading priors, joint limits, shape prior) stays in a small GTSAM
  subgraph that is linearised and assembled as usual.

The result is the system ``ChainLayout.assemble(graph.linearize(values))`` and the error
``graph.error(values)`` of the whole graph (tested to round-off), so the LM iterates are the same.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import row_loss_and_weight
from pedx_graph.solvers.chain import ChainLayout, ChainSystem

#: Factor kinds served from the batched cache.
BATCHED_KINDS = ("stereo_reprojection", "lidar_chamfer", "pose_prior", "temporal_prior")


class BatchedLinearizer:
    """Error and chain system of a :class:`~pedx_graph.graph.build.TrackProblem` at any values."""

    def __init__(self, problem, layout: ChainLayout | None = None) -> None:
        self.problem = problem
        self.body = problem.body
        self.layout = layout or problem.layout
        specs = getattr(self.body, "_specs", {})
        self.rest = gtsam.NonlinearFactorGraph()
        self.served: dict[str, list[tuple[int, ...]]] = {kind: [] for kind in BATCHED_KINDS}
        for j, kind in enumerate(problem.factor_kinds):
            factor = problem.graph.at(j)
            keys = tuple(int(k) for k in factor.keys())
            if kind in self.served and keys in specs.get(kind, {}):
                self.served[kind].append(keys)
            else:
                self.rest.add(factor)
        self._gram: dict[int, np.ndarray] = {}

    def _terms(self, values: gtsam.Values, jacobians: bool) -> dict:
        self.problem.prefetch(values, jacobians)
        return self.body._terms

    # -- error -----------------------------------------------------------------------------------------
    def error(self, values: gtsam.Values, jacobians: bool = False) -> float:
        """``graph.error(values)``; ``jacobians`` also prefetches the derivatives (for a linearisation at the
        same values next)."""
        terms = self._terms(values, jacobians)
        total = self.rest.error(values) if self.rest.size() else 0.0
        for kind, keys_list in self.served.items():
            if not keys_list:
                continue
            specs = self.body._specs[kind]
            for keys in keys_list:
                r = terms[(kind, keys)][0]
                if kind == "stereo_reprojection":
                    spec = specs[keys]
                    loss, _ = row_loss_and_weight(r / spec.setup.sigmas, spec.robust, spec.robust_scale)
                    total += float(loss.sum())
                elif kind == "lidar_chamfer" and not specs[keys].robust_per_point:
                    spec = specs[keys]
                    loss, _ = row_loss_and_weight(r / spec.sigma_m, spec.robust, spec.robust_scale)
                    total += float(loss.sum())
                else:
                    total += 0.5 * float(r @ r)
        return total

    # -- linear system ---------------------------------------------------------------------------------
    def system(self, values: gtsam.Values) -> ChainSystem:
        """The whitened Gauss-Newton system of the whole graph at ``values`` in chain form."""
        layout = self.layout
        if self.rest.size():
            system = layout.assemble(self.rest.linearize(values))
        else:
            t, d, nb = layout.num_frames, 75, layout.num_betas
            system = ChainSystem(np.zeros((t, d, d)), np.zeros((max(t - 1, 0), d, d)), np.zeros((t, d, nb)),
                                 np.zeros((nb, nb)), np.zeros((t, d)), np.zeros(nb))
        terms = self._terms(values, True)
        for kind, keys_list in self.served.items():
            if keys_list:
                getattr(self, "_add_" + kind)(system, terms, keys_list)
        return system

    def _firsts(self, keys_list) -> np.ndarray:
        return np.array([self.layout.segments(keys)[0][2] for keys in keys_list])

    def _add_rows(self, system: ChainSystem, keys_list, a_rows: list[np.ndarray], b_rows: list[np.ndarray]):
        """Add factors given by whitened rows (A_i (m_i, c), b_i (m_i,)) that share one key pattern."""
        pattern = self.layout.segments(keys_list[0])
        rel = tuple((c, w, f - pattern[0][2] if f >= 0 else -1, o) for c, w, f, o in pattern)
        rows = {a.shape[0] for a in a_rows}
        if len(rows) == 1:
            a_all = np.stack(a_rows)
            b_all = np.stack(b_rows)
            a_t = np.swapaxes(a_all, 1, 2)
            hess = a_t @ a_all
            grad = (a_t @ b_all[:, :, None])[:, :, 0]
        else:
            hess = np.stack([a.T @ a for a in a_rows])
            grad = np.stack([a.T @ b for a, b in zip(a_rows, b_rows)])
        self.layout._scatter(system, rel, self._firsts(keys_list), hess, grad)

    def _add_stereo_reprojection(self, system, terms, keys_list) -> None:
        specs = self.body._specs["stereo_reprojection"]
        a_rows, b_rows = [], []
        width = max(specs[k].setup.rows for k in keys_list)
        for keys in keys_list:
            spec = specs[keys]
            r, blocks = terms[("stereo_reprojection", keys)]
            white = r / spec.setup.sigmas
            _, weight = row_loss_and_weight(white, spec.robust, spec.robust_scale)
            scale = np.sqrt(weight)
            a = np.zeros((width, 75 + blocks[3].shape[1]))    # zero rows pad to a common height
            b = np.zeros(width)
            m = len(r)
            a[:m] = np.concatenate(blocks, axis=1) * (scale / spec.setup.sigmas)[:, None]
            b[:m] = -scale * white
            a_rows.append(a)
            b_rows.append(b)
        self._add_rows(system, keys_list, a_rows, b_rows)

    def _add_lidar_chamfer(self, system, terms, keys_list) -> None:
        specs = self.body._specs["lidar_chamfer"]
        a_rows, b_rows = [], []
        for keys in keys_list:
            spec = specs[keys]
            r, blocks = terms[("lidar_chamfer", keys)]
            a = np.concatenate(blocks, axis=1)
            if spec.robust_per_point:                 # whitened and robustified inside the factor
                a_rows.append(a)
                b_rows.append(-r)
            else:
                white = r / spec.sigma_m
                _, weight = row_loss_and_weight(white, spec.robust, spec.robust_scale)
                scale = np.sqrt(weight)
                a_rows.append(a * (scale / spec.sigma_m)[:, None])
                b_rows.append(-scale * white)
        self._add_rows(system, keys_list, a_rows, b_rows)

    def _add_pose_prior(self, system, terms, keys_list) -> None:
        a_rows = [terms[("pose_prior", keys)][1][0] for keys in keys_list]
        b_rows = [-terms[("pose_prior", keys)][0] for keys in keys_list]
        self._add_rows(system, keys_list, a_rows, b_rows)

    def _add_temporal_prior(self, system, terms, keys_list) -> None:
        a_rows, b_rows = [], []
        for keys in keys_list:
            r, blocks = terms[("temporal_prior", keys)]
            a_rows.append(np.concatenate(blocks, axis=1))
            b_rows.append(-r)
        self._add_rows(system, keys_list, a_rows, b_rows)
