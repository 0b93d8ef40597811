"""The Gauss-Newton system of new frames' own factors, for all pedestrians of a sample in one batched pass.

A streamed frame's own factors (stereo reprojection, LiDAR chamfer, translation, heading, pose and
joint-limit priors: those on its root, translation and body pose and at most the shape) are linearised
twice per frame: for the presolve (at the initial values, without the chamfer) and for iSAM2 (at the
presolved values).  Through ``graph.linearize`` each factor is a GTSAM callback that evaluates its term for
one frame.  Here the terms of every pedestrian of the sample are evaluated together instead, by the
batched body model's term cache (:class:`pedx_graph.graph.batch.BatchedBodyModel`: stereo pixels, chamfer
matches and matched-vertex Jacobians, pose-prior residuals of all frames in batched calls; the small priors
from their specs), and each frame's whitened normal equations ``(A^T A, A^T b, b^T b)`` over its columns
``[root (3), trans (3), body_pose (69), betas (B)]`` are formed in batched products, whitened exactly as
the factors' GTSAM noise models do (the same arithmetic as
:class:`pedx_graph.solvers.batched.BatchedLinearizer`).  The result equals the ``HessianFactor`` of
``graph.linearize`` at the same point (tested to round-off).

The streamed frames of different tracks use the same keys (``r0``, ``t0``, ...), so the factors register
their specs with a per-frame :class:`SpecRecorder` (given to the factors through :class:`RecordingBody`),
and :func:`register_sample` files them in the body model's registry under one set of keys per pedestrian
(``FrameKeys.for_frame(j, j)``, the keys the stream prefetches the sample with).  The registry then only
ever holds one sample's terms.
"""
from __future__ import annotations

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, FrameKeys, row_loss_and_weight
from factors.heading_prior import heading_prior_batch
from factors.joint_limits import joint_limit_batch
from factors.stereo_reprojection import reprojection_normal_equations, reprojection_rows, reprojection_whiten
from factors.temporal_prior import temporal_prior_batch
from factors.translation_prior import translation_prior_batch
from pedx_graph.solvers.batched import chamfer_normal_equations

#: Factor kinds whose frame systems are formed here (a frame's own factors).
OWN_KINDS = ("stereo_reprojection", "lidar_chamfer", "translation_prior", "heading_prior", "pose_prior",
             "joint_limits")
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
    body._specs = {}
    out = []
    for j, (real, specs) in enumerate(frames):
        fake = FrameKeys.for_frame(j, j)
        to_fake = dict(zip(real.as_list(), fake.as_list()))
        for kind, keys, spec in specs:
            if kind in OWN_KINDS:
                body.register(kind, [to_fake[k] for k in keys], spec)
        out.append(fake)
    return out


def _kernels(specs) -> list[tuple[str, float]]:
    return [(sp.robust, sp.robust_scale) for sp in specs]


def _weights(white: np.ndarray, kernels: list[tuple[str, float]]) -> np.ndarray:
    """IRLS weights of whitened rows ``white`` (F, m), one kernel per frame."""
    if len(set(kernels)) == 1:
        return row_loss_and_weight(white, *kernels[0])[1]
    return np.stack([row_loss_and_weight(white[n], *kernels[n])[1] for n in range(len(kernels))])


def frame_systems(body, keys: list[FrameKeys], kinds) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The whitened normal equations of the registered factors of ``kinds`` of each frame of ``keys`` at the
    body's last prefetch (which must have evaluated these kinds, with Jacobians): ``H`` (F, D, D),
    ``g = A^T b`` (F, D) and ``f = b^T b`` (F,), columns ``[root, trans, body_pose, betas]`` (D = 75 + B).
    None when the cache does not hold them all in batched form (then linearise with GTSAM)."""
    num_betas = int(body.num_betas)
    dim = _FRAME_DIM + num_betas
    n = len(keys)
    hess, grad, const = np.zeros((n, dim, dim)), np.zeros((n, dim)), np.zeros(n)
    position: dict[int, int] = {}
    for j, k in enumerate(keys):
        position[int(k.root)] = position[int(k.trans)] = position[int(k.body_pose)] = j
    registry = body._specs
    arrays = body.frame_arrays
    for kind in kinds:
        specs = registry.get(kind)
        if not specs:
            continue
        if kind in ("translation_prior", "heading_prior", "joint_limits"):
            fkeys = list(specs)
            frames = np.array([position[fk[0]] for fk in fkeys], dtype=np.int64)
            _add_direct(kind, [specs[fk] for fk in fkeys], frames, arrays, hess, grad, const)
            continue
        groups = body.batch(kind)
        if {fk for g in groups for fk in g["keys"]} != set(specs):
            return None
        for group in groups:
            frames = np.array([position[fk[0]] for fk in group["keys"]], dtype=np.int64)
            if kind == "stereo_reprojection":
                h, gr, f = _stereo(group, [specs[fk] for fk in group["keys"]])
            elif kind == "lidar_chamfer":
                if group.get("a") is None:
                    return None
                h, gr, f = chamfer_normal_equations(group)
            elif kind == "pose_prior":
                h, gr, f = _pose_prior(group)
                hess[frames, ROOT_DIM + TRANS_DIM:_FRAME_DIM, ROOT_DIM + TRANS_DIM:_FRAME_DIM] += h
                grad[frames, ROOT_DIM + TRANS_DIM:_FRAME_DIM] += gr
                const[frames] += f
                continue
            else:
                return None
            hess[frames] += h
            grad[frames] += gr
            const[frames] += f
    return hess, grad, const


def _stereo(group: dict, specs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Reprojection factors through their keypoints, by the factor module's own batched normal equations
    (:func:`factors.stereo_reprojection.reprojection_normal_equations`, as the batch linearizer)."""
    meas, inv_sigma = reprojection_rows([sp.setup for sp in specs], group["uv"].shape[1])
    white, _, weight, inv = reprojection_whiten(group["uv"], meas, inv_sigma, _kernels(specs))
    return reprojection_normal_equations(group["d_uv"], group["jac"], white, weight, inv)


_GRAMS: dict[int, tuple] = {}


def _gram(mixture) -> np.ndarray:
    """``J_k^T J_k`` (K, D, D) of every component's residual Jacobian (cached per mixture)."""
    hit = _GRAMS.get(id(mixture))
    if hit is None or hit[0] is not mixture:
        jac = mixture.jacobians(np.arange(mixture.num_components))
        hit = _GRAMS[id(mixture)] = (mixture, np.swapaxes(jac, 1, 2) @ jac)
    return hit[1]


def _pose_prior(group: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose-prior factors (max-mixture, unit noise): the body-pose block only."""
    mixture, best, r = group["mixture"], group["best"], group["r"]
    jac_t = np.swapaxes(mixture.jacobians(best), 1, 2)                  # (G, D, D+1)
    return _gram(mixture)[best], -(jac_t @ r[:, :, None])[:, :, 0], np.sum(r * r, axis=1)


def _add_direct(kind: str, specs: list, frames: np.ndarray, arrays: dict, hess: np.ndarray, grad: np.ndarray,
                const: np.ndarray) -> None:
    """Translation / heading / joint-limit factors from their specs and the prefetched states, whitened as
    their GTSAM noise models (as ``BatchedLinearizer._direct``)."""
    if kind == "joint_limits":
        groups: dict[tuple, list[int]] = {}
        for n, spec in enumerate(specs):
            groups.setdefault((spec.limits, spec.sigma_rad), []).append(n)
        for (limits, sigma), members in groups.items():
            rows = frames[np.array(members)]
            r, idx, active = joint_limit_batch(arrays["pose"][rows, 3:], limits)       # (G, L)
            coef = active / sigma
            cols = np.broadcast_to(ROOT_DIM + TRANS_DIM + idx, r.shape)
            at = np.broadcast_to(rows[:, None], r.shape)
            np.add.at(hess, (at, cols, cols), coef * coef)
            np.add.at(grad, (at, cols), coef * (-r / sigma))
            np.add.at(const, rows, np.sum((r / sigma) ** 2, axis=1))
        return
    if kind == "heading_prior":
        r, jac = heading_prior_batch(arrays["world_R_body"][frames], np.stack([sp.level_heading for sp in specs]),
                                     np.stack([sp.world_R_level for sp in specs]))
        jac, r = jac[:, None, :], r[:, None]
        sig = np.array([sp.sigma_rad for sp in specs])[:, None]
        cols = np.arange(ROOT_DIM)
    else:                                                                # translation_prior
        sp = specs[0]
        r, d_trans, d_betas = translation_prior_batch(
            arrays["trans"][frames], arrays["betas"][frames], sp.pelvis_rest, sp.pelvis_shapedirs,
            np.stack([s.world_p_mean for s in specs]), np.stack([s.world_R_ray for s in specs]),
            np.stack([s.offsets for s in specs]))
        jac = np.concatenate([d_trans, d_betas], axis=2)
        sig = np.stack([s.sigmas for s in specs])
        cols = np.concatenate([np.arange(ROOT_DIM, ROOT_DIM + TRANS_DIM),
                               np.arange(_FRAME_DIM, _FRAME_DIM + d_betas.shape[2])])
    white = r / sig
    weight = _weights(white, _kernels(specs))
    scale = np.sqrt(weight)
    a = jac * (scale / sig)[:, :, None]
    b = -scale * white
    a_t = np.swapaxes(a, 1, 2)
    np.add.at(hess, (frames[:, None, None], cols[None, :, None], cols[None, None, :]), a_t @ a)
    np.add.at(grad, (frames[:, None], cols[None, :]), (a_t @ b[:, :, None])[:, :, 0])
    np.add.at(const, frames, np.sum(b * b, axis=1))


def temporal_terms(pairs: list[tuple]) -> list[tuple[np.ndarray, list[np.ndarray]]]:
    """Temporal-prior residuals and six Jacobian blocks (as the factor's callback returns them) of several
    pairs of frames in batched calls: ``pairs`` of ``(previous (world_R_body, trans, body_pose), next (the
    same), mixture, gap)``."""
    out: list = [None] * len(pairs)
    by_mixture: dict[int, list[int]] = {}
    for n, pair in enumerate(pairs):
        by_mixture.setdefault(id(pair[2]), []).append(n)
    for members in by_mixture.values():
        items = [pairs[n] for n in members]
        states = [np.stack([np.asarray(it[side][n], float) for it in items]) for side in (0, 1) for n in range(3)]
        r, blocks = temporal_prior_batch(*states, items[0][2], np.array([it[3] for it in items], float), True)
        for m, n in enumerate(members):
            out[n] = (np.ascontiguousarray(r[m]), [np.ascontiguousarray(b[m]) for b in blocks])
    return out


def add_temporal_new_frame(system: tuple[np.ndarray, np.ndarray, np.ndarray], frames: list[int],
                           terms: list[tuple[np.ndarray, list[np.ndarray]]]) -> None:
    """Add to ``system`` (:func:`frame_systems`' ``(H, g, f)``) the temporal priors between frames and their
    tracks' previous frames, held: ``terms`` (:func:`temporal_terms`) of frame ``frames[n]``; only the rows
    on the new frame's columns (the presolve's free block); unit noise (the mixture whitens)."""
    hess, grad, const = system
    for j, (r, blocks) in zip(frames, terms):
        a = np.concatenate(blocks[3:], axis=1)                           # (76, 75): the new frame's columns
        hess[j, :_FRAME_DIM, :_FRAME_DIM] += a.T @ a
        grad[j, :_FRAME_DIM] -= a.T @ r
        const[j] += float(r @ r)


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
