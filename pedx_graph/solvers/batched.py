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
* the small factors (translation and heading priors, joint limits) are evaluated here for all frames at
  once from the specs they registered and the prefetched states (``*_batch`` functions of their modules,
  whitened as their noise models);
* any other factor (the shape prior) stays in a small GTSAM subgraph, linearised and assembled as usual.

The result is the system ``ChainLayout.assemble(graph.linearize(values))`` and the error
``graph.error(values)`` of the whole graph (tested to round-off), so the LM iterates are the same.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import row_loss_and_weight
from factors.heading_prior import heading_prior_batch
from factors.joint_limits import joint_limit_batch
from factors.translation_prior import translation_prior_batch
from factors.stereo_reprojection import reprojection_normal_equations, reprojection_rows, reprojection_whiten
from pedx_graph.solvers.chain import ChainLayout, ChainSystem

#: Factor kinds served from the batched cache.
BATCHED_KINDS = ("stereo_reprojection", "lidar_chamfer", "pose_prior", "temporal_prior")
#: Small factor kinds evaluated here in batch from their registered specs and the prefetched states.
DIRECT_KINDS = ("translation_prior", "heading_prior", "joint_limits")


class BatchedLinearizer:
    """Error and chain system of a :class:`~pedx_graph.graph.build.TrackProblem` at any values."""

    def __init__(self, problem, layout: ChainLayout | None = None) -> None:
        self.problem = problem
        self.body = problem.body
        self.layout = layout or problem.layout
        specs = getattr(self.body, "_specs", {})
        self.rest = gtsam.NonlinearFactorGraph()
        self.served: dict[str, list[tuple[int, ...]]] = {kind: [] for kind in BATCHED_KINDS + DIRECT_KINDS}
        for j, kind in enumerate(problem.factor_kinds):
            factor = problem.graph.at(j)
            keys = tuple(int(k) for k in factor.keys())
            if kind in self.served and keys in specs.get(kind, {}):
                self.served[kind].append(keys)
            else:
                self.rest.add(factor)
        self._gram: dict[int, tuple] = {}
        self._dense: dict[tuple, tuple] = {}
        self._setups: dict[str, dict] = {}

    def _prefetch(self, values: gtsam.Values, jacobians: bool) -> None:
        self.problem.prefetch(values, jacobians)

    def _groups(self, kind: str) -> list[dict] | None:
        """The cache's batched groups of ``kind`` when they hold exactly the factors this graph serves."""
        groups = self.body.batch(kind)
        held = {keys for g in groups for keys in g["keys"]}
        return groups if held == set(self.served[kind]) else None

    def _factor(self, kind: str, keys) -> tuple:
        """One served factor's ``(residual, blocks)`` (materialised from the cache)."""
        name = (kind, keys)
        hit = self.body._terms.get(name)
        if hit is None:
            hit = self.body._terms[name] = self.body._materialise(kind, *self.body._where[name])
        return hit

    def _stereo_rows(self, group: dict) -> tuple[np.ndarray, np.ndarray, list[tuple[str, float]]]:
        """Dense measurements and inverse sigmas (G, K, 18, 2) of a reprojection group (K: its largest number
        of images; padding rows have inverse sigma 0), and its kernels (cached)."""
        tag = tuple(group["keys"])
        hit = self._dense.get(tag)
        if hit is None:
            specs = self.body._specs["stereo_reprojection"]
            meas, inv_sigma = reprojection_rows([specs[keys].setup for keys in group["keys"]], group["uv"].shape[1])
            kernels = [(specs[keys].robust, specs[keys].robust_scale) for keys in group["keys"]]
            hit = self._dense[tag] = (meas, inv_sigma, kernels)
        return hit

    def _stereo_white(self, group: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residual rows ``e`` (G, K * 36), per-row losses and IRLS weights, and inverse sigmas
        (:func:`factors.stereo_reprojection.reprojection_whiten`)."""
        return reprojection_whiten(group["uv"], *self._stereo_rows(group))

    # -- error -----------------------------------------------------------------------------------------
    def error(self, values: gtsam.Values, jacobians: bool = False) -> float:
        """``graph.error(values)``; ``jacobians`` also prefetches the derivatives (for a linearisation at the
        same values next)."""
        self._prefetch(values, jacobians)
        total = self.rest.error(values) if self.rest.size() else 0.0
        for kind, keys_list in self.served.items():
            if not keys_list:
                continue
            if kind in DIRECT_KINDS:
                total += float(self._direct(kind, keys_list, False)[0])
                continue
            groups = self._groups(kind)
            if kind == "stereo_reprojection" and groups is not None:
                total += sum(float(self._stereo_white(g)[1].sum()) for g in groups)
            elif kind == "lidar_chamfer" and groups is not None:
                total += sum(0.5 * float(np.sum(g["s"] ** 2)) for g in groups)
            elif kind in ("pose_prior", "temporal_prior") and groups is not None:
                total += sum(0.5 * float(np.sum(g["r"] ** 2)) for g in groups)
            else:
                total += sum(self._factor_error(kind, keys) for keys in keys_list)
        return total

    def _factor_error(self, kind: str, keys) -> float:
        r = self._factor(kind, keys)[0]
        spec = self.body._specs[kind][keys]
        if kind == "stereo_reprojection":
            return float(row_loss_and_weight(r / spec.setup.sigmas, spec.robust, spec.robust_scale)[0].sum())
        if kind == "lidar_chamfer" and not spec.robust_per_point:
            return float(row_loss_and_weight(r / spec.sigma_m, spec.robust, spec.robust_scale)[0].sum())
        return 0.5 * float(r @ r)

    # -- linear system ---------------------------------------------------------------------------------
    def system(self, values: gtsam.Values, skip=()) -> ChainSystem:
        """The whitened Gauss-Newton system of the whole graph at ``values`` in chain form (without the
        served factors of the kinds in ``skip``)."""
        layout = self.layout
        if self.rest.size():
            system = layout.assemble(self.rest.linearize(values))
        else:
            t, d, nb = layout.num_frames, 75, layout.num_betas
            system = ChainSystem(np.zeros((t, d, d)), np.zeros((max(t - 1, 0), d, d)), np.zeros((t, d, nb)),
                                 np.zeros((nb, nb)), np.zeros((t, d)), np.zeros(nb))
        self._prefetch(values, True)
        for kind, keys_list in self.served.items():
            if not keys_list or kind in skip:
                continue
            if kind in DIRECT_KINDS:
                self._direct(kind, keys_list, True, system)
                continue
            groups = self._groups(kind)
            if groups is not None:
                for group in groups:
                    getattr(self, "_add_" + kind)(system, group)
            else:
                self._add_factors(system, kind, keys_list)
        return system

    def _direct_setup(self, kind: str, keys_list) -> dict:
        """Per kind, once: the frame index of every served factor and its specs stacked into arrays."""
        setup = self._setups.get(kind)
        if setup is not None:
            return setup
        fkeys, _ = self.body.frame_states
        index = {}
        for i, k in enumerate(fkeys):
            index[int(k.root)] = index[int(k.trans)] = index[int(k.body_pose)] = i
        specs = [self.body._specs[kind][keys] for keys in keys_list]
        setup = {"frames": np.array([index[keys[0]] for keys in keys_list], dtype=np.int64), "specs": specs,
                 "kernels": sorted({(sp.robust, sp.robust_scale) for sp in specs}) if kind != "joint_limits"
                 else None}
        if kind == "joint_limits":
            groups: dict[tuple, list[int]] = {}
            for n, spec in enumerate(specs):
                groups.setdefault((spec.limits, spec.sigma_rad), []).append(n)
            setup["groups"] = [(limits, sigma, np.array(members)) for (limits, sigma), members in groups.items()]
        elif kind == "heading_prior":
            setup["heading"] = np.stack([sp.level_heading for sp in specs])
            setup["level"] = np.stack([sp.world_R_level for sp in specs])
            setup["sigma"] = np.array([sp.sigma_rad for sp in specs])[:, None]
        else:
            for name in ("world_p_mean", "world_R_ray", "offsets", "sigmas"):
                setup[name] = np.stack([getattr(sp, name) for sp in specs])
        self._setups[kind] = setup
        return setup

    def _direct(self, kind: str, keys_list, linearize: bool, system: ChainSystem | None = None) -> tuple:
        """Error of the small factors of ``kind`` (and, when ``linearize``, their rows added to ``system``),
        from their specs and the prefetched frame states, whitened as their GTSAM noise models."""
        setup = self._direct_setup(kind, keys_list)
        frames = setup["frames"]
        arrays = self.body.frame_arrays
        if kind == "joint_limits":
            total = 0.0
            for limits, sigma, members in setup["groups"]:
                r, idx, active = joint_limit_batch(arrays["pose"][frames[members], 3:], limits)
                total += 0.5 * float(np.sum((r / sigma) ** 2))
                if linearize and active.any():
                    # row l of A is (active_l / sigma) e_idx[l]: A^T A is diagonal, A^T b sits on idx
                    keys = [keys_list[n] for n in members]
                    (_, _, _, offset), = self.layout.segments(keys[0])
                    firsts, cols, coef = self._firsts(keys)[:, None], offset + idx[None], active / sigma
                    np.add.at(system.frame, (firsts, cols, cols), coef * coef)
                    np.add.at(system.grad_frame, (firsts, cols), coef * (-r / sigma))
            return (total,)
        if kind == "heading_prior":
            r, jac = heading_prior_batch(arrays["world_R_body"][frames], setup["heading"], setup["level"])
            jac = jac[:, None, :]
            r = r[:, None]
            sig = setup["sigma"]
        else:                                                            # translation_prior
            sp = setup["specs"][0]
            r, d_trans, d_betas = translation_prior_batch(
                arrays["trans"][frames], arrays["betas"][frames], sp.pelvis_rest, sp.pelvis_shapedirs,
                setup["world_p_mean"], setup["world_R_ray"], setup["offsets"])
            jac = np.concatenate([d_trans, d_betas], axis=2)
            sig = setup["sigmas"]
        white = r / sig
        if len(setup["kernels"]) == 1:
            loss, weight = row_loss_and_weight(white, *setup["kernels"][0])
        else:
            pairs = [row_loss_and_weight(white[n], spec.robust, spec.robust_scale)
                     for n, spec in enumerate(setup["specs"])]
            loss, weight = np.stack([a for a, _ in pairs]), np.stack([b for _, b in pairs])
        if linearize:
            scale = np.sqrt(weight)
            self._add_dense(system, keys_list, jac * (scale / sig)[:, :, None], -scale * white)
        return (float(loss.sum()),)

    def _add_dense(self, system: ChainSystem, keys_list, a: np.ndarray, b: np.ndarray) -> None:
        """Add factors of one key pattern given as stacked whitened rows ``a`` (G, m, c) and ``b`` (G, m)."""
        a_t = np.swapaxes(a, 1, 2)
        self._scatter(system, keys_list, a_t @ a, (a_t @ b[:, :, None])[:, :, 0])

    def _firsts(self, keys_list) -> np.ndarray:
        return np.array([self.layout.segments(keys)[0][2] for keys in keys_list])

    def _scatter(self, system: ChainSystem, keys_list, hess: np.ndarray, grad: np.ndarray) -> None:
        pattern = self.layout.segments(keys_list[0])
        rel = tuple((c, w, f - pattern[0][2] if f >= 0 else -1, o) for c, w, f, o in pattern)
        self.layout._scatter(system, rel, self._firsts(keys_list), hess, grad)

    def _add_factors(self, system: ChainSystem, kind: str, keys_list) -> None:
        """Factor by factor (chamfer: rows differ per frame): whitened ``A``, ``b`` of each, then one scatter."""
        hess, grad = [], []
        for keys in keys_list:
            r, blocks = self._factor(kind, keys)
            spec = self.body._specs[kind][keys]
            a = np.concatenate(blocks, axis=1)
            if kind == "stereo_reprojection":
                white = r / spec.setup.sigmas
                scale = np.sqrt(row_loss_and_weight(white, spec.robust, spec.robust_scale)[1])
                a, b = a * (scale / spec.setup.sigmas)[:, None], -scale * white
            elif kind == "lidar_chamfer" and not spec.robust_per_point:
                white = r / spec.sigma_m
                scale = np.sqrt(row_loss_and_weight(white, spec.robust, spec.robust_scale)[1])
                a, b = a * (scale / spec.sigma_m)[:, None], -scale * white
            else:                                       # unit noise: whitened inside the factor
                b = -r
            hess.append(a.T @ a)
            grad.append(a.T @ b)
        self._scatter(system, keys_list, np.stack(hess), np.stack(grad))

    def _add_lidar_chamfer(self, system: ChainSystem, group: dict) -> None:
        """Chamfer factors from the cache's all-frames group (rows already whitened and robustified)."""
        hess, grad, _ = chamfer_normal_equations(group)
        self._scatter(system, group["keys"], hess, grad)

    def _add_stereo_reprojection(self, system: ChainSystem, group: dict) -> None:
        """Reprojection factors through their keypoints
        (:func:`factors.stereo_reprojection.reprojection_normal_equations`: 54 keypoint rows per frame)."""
        white, _, weight, inv = self._stereo_white(group)
        hess, grad, _ = reprojection_normal_equations(group["d_uv"], group["jac"], white, weight, inv)
        self._scatter(system, group["keys"], hess, grad)

    def _gram_of(self, mixture, start: int = 0) -> np.ndarray:
        """``J_k^T J_k`` (K, D - start, D - start) of every component's residual Jacobian, rows and columns
        from ``start`` on (contiguous; cached per mixture and start)."""
        gram = self._gram.get((id(mixture), start))
        if gram is None or gram[0] is not mixture:
            jac = mixture.jacobians(np.arange(mixture.num_components))[:, :, start:]
            gram = self._gram[(id(mixture), start)] = (mixture, np.swapaxes(jac, 1, 2) @ jac)
        return gram[1]

    def _add_pose_prior(self, system: ChainSystem, group: dict) -> None:
        mixture = group["mixture"]
        best, dim = group["best"], mixture.dim
        # residual Jacobian of component k: [L_k^T; 0] = [mixture.lt[k]; 0]
        grad = -np.einsum("fri,fr->fi", mixture.lt[best], group["r"][:, :dim])
        self._scatter(system, group["keys"], self._gram_of(mixture)[group["best"]], grad)

    def _add_temporal_prior(self, system: ChainSystem, group: dict) -> None:
        """Temporal factors, using the structure of their Jacobian ``A = [U_i, -L, U_j, L]`` (U: the root and
        translation columns of frames i and j, 76 x 6 each; L: the pose columns, the same up to sign for
        both frames), so ``A^T A`` costs ``L^T L`` once instead of a full 150-column product."""
        blocks = group["blocks"]                                          # six (P, 76, k)
        r = group["r"]                                                    # (P, 76); b = -r
        u = np.concatenate([blocks[0], blocks[1], blocks[3], blocks[4]], axis=2)   # (P, 76, 12)
        lm = blocks[2]                                                    # -L (P, 76, 69), contiguous
        # (a strided view, like blocks[5] = L, would make numpy's batched matmul skip BLAS)
        u_t = np.swapaxes(u, 1, 2)
        utu = u_t @ u
        utl = u_t @ lm
        utl *= -1.0
        # L = J_k[:, 6:] / gap of the selected component k: L^T L from the component's Gram matrix
        ltl = self._gram_of(group["mixture"], 6)[group["best"]]
        if np.any(group["gap"] != 1.0):
            ltl /= (group["gap"] ** 2)[:, None, None]
        ub = -(u_t @ r[:, :, None])[:, :, 0]
        lb = (np.swapaxes(lm, 1, 2) @ r[:, :, None])[:, :, 0]             # L^T b = (-L)^T r
        num = len(group["keys"])
        firsts = self._firsts(group["keys"])
        if np.array_equal(firsts, np.arange(firsts[0], firsts[0] + num)):
            # consecutive pairs (the usual case): add the blocks in place, no (P, 150, 150) temporary
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
            return
        si, pi, sj, pj = slice(0, 6), slice(6, 75), slice(75, 81), slice(81, 150)
        hess = np.empty((num, 150, 150))
        hess[:, si, si], hess[:, si, sj] = utu[:, :6, :6], utu[:, :6, 6:]
        hess[:, sj, si], hess[:, sj, sj] = utu[:, 6:, :6], utu[:, 6:, 6:]
        hess[:, si, pi], hess[:, si, pj] = -utl[:, :6], utl[:, :6]
        hess[:, sj, pi], hess[:, sj, pj] = -utl[:, 6:], utl[:, 6:]
        hess[:, pi, si], hess[:, pj, si] = np.swapaxes(hess[:, si, pi], 1, 2), np.swapaxes(hess[:, si, pj], 1, 2)
        hess[:, pi, sj], hess[:, pj, sj] = np.swapaxes(hess[:, sj, pi], 1, 2), np.swapaxes(hess[:, sj, pj], 1, 2)
        hess[:, pi, pi], hess[:, pj, pj] = ltl, ltl
        hess[:, pi, pj], hess[:, pj, pi] = -ltl, -ltl
        grad = np.concatenate([ub[:, :6], -lb, ub[:, 6:], lb], axis=1)
        self._scatter(system, group["keys"], hess, grad)


def chamfer_normal_equations(group: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened normal equations of a term cache's chamfer group: per factor ``(A^T A, A^T b, b^T b)``.

    ``group["a"]`` (P, 3, D) the points' whitened, robustified rows over the factor's columns,
    ``group["s"]`` (P, 3) their whitened residuals, ``group["offsets"]`` (F + 1,) where each factor's
    points start.  Every factor's points are padded with zero rows to the largest count, so all factors
    take one batched product.  Returns hess (F, D, D), grad (F, D) = ``-A^T s``, cost (F,) = ``s^T s``."""
    offsets, a, s = group["offsets"], group["a"], group["s"]
    counts = np.diff(offsets)
    num, width = len(counts), int(counts.max())
    frame = np.repeat(np.arange(num), counts)
    slot = np.arange(len(a)) - offsets[frame]
    rows = np.zeros((num, width, 3, a.shape[2]))
    rhs = np.zeros((num, width, 3))
    rows[frame, slot] = a
    rhs[frame, slot] = s
    rows = rows.reshape(num, 3 * width, a.shape[2])
    rows_t = np.swapaxes(rows, 1, 2)
    return (rows_t @ rows, -(rows_t @ rhs.reshape(num, 3 * width, 1))[:, :, 0],
            np.bincount(frame, weights=np.sum(s * s, axis=1), minlength=num))
