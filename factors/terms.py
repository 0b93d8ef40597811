"""How an energy term is declared once, and the one assembler from whitened rows to Gauss-Newton equations.

A term (one ``factors/<term>.py`` file) declares, next to its residual and Jacobians:

* its noise model as a :class:`RowNoise` — per-row sigmas in physical units (px, m, rad) or ``None`` when
  the residual is whitened inside (the max-mixtures, the per-point robust chamfer, the per-keypoint robust
  reprojection), and a robust kernel acting on each whitened row (GTSAM's ``ReweightScheme.Scalar``).  The
  GTSAM factor takes its noise model from it (:meth:`RowNoise.model`); the batched paths whiten with it
  (:meth:`RowNoise.weigh`);
* a :class:`Term`: its kind, whether it acts on one frame's variables only (the stream's frame systems form
  those in a batch), and its *assembler* ``assemble(cache, keys_list, jacobians)``: the terms of the
  factors ``keys_list`` at the term cache's last prefetch as :class:`NormalEquations`.

Whoever needs a term's contribution — the batched linearizer of a track (``pedx_graph.solvers.batched``),
the stream's per-frame systems (``pedx_graph.solvers.frame_system``), the marginals — calls its assembler
through the registry (:mod:`factors.registry`) and scatters the result; nobody re-writes a term's
weighting.  The assembler of most terms is :func:`rows_normal_equations` (stacked whitened rows -> ``A^T A``,
``A^T b``, ``b^T b`` and the factor's error); terms with exploitable structure (reprojection through its
keypoints, chamfer groups, max-mixtures, the temporal pair) assemble themselves and say so in their files.

``cache`` is the track's term cache (:class:`pedx_graph.graph.batch.BatchedBodyModel`, duck-typed here:
the factors never import the solver layers): ``specs(kind)``, ``batch(kind)``, ``factor_terms(kind, keys)``,
``frame_index(keys_list)``, ``frame_arrays``, ``has_jacobians`` and ``memo(name, builder)``; a term's
batched evaluation at a prefetch (:attr:`Term.evaluate`, given a :class:`Prefetched`) files its results with
``add_batch(kind, group)`` / ``set_factor_terms(kind, keys, terms)`` and reads them back per factor with
:attr:`Term.materialise` — the cache itself names no term.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, Callable, Sequence

import gtsam
import numpy as np

from factors.common import BODY_POSE_DIM, ROOT_DIM, TRANS_DIM, make_noise, row_loss_and_weight, set_jacobians


@dataclass(frozen=True)
class RowNoise:
    """A factor's noise model, declared once by its term (see the module docstring)."""

    sigmas: np.ndarray | None
    """(m,) per-row standard deviations in the residual's physical units; None: unit noise (the residual is
    already whitened, e.g. a max-mixture or the per-point robust chamfer)."""
    robust: str = "none"
    """Robust kernel per whitened row (:data:`factors.common.ROBUST_KERNELS`)."""
    robust_scale: float = 1.0
    """The kernel's scale in whitened units."""

    def model(self, rows: int | None = None) -> gtsam.noiseModel.Base:
        """The GTSAM noise model (:func:`factors.common.make_noise`; ``gtsam.noiseModel.Unit`` when the
        sigmas are None and no kernel is set); ``rows`` repeats a scalar sigma."""
        if self.sigmas is None:
            if self.robust != "none":
                return make_noise(np.ones(int(rows)), robust=self.robust, robust_scale=self.robust_scale)
            return gtsam.noiseModel.Unit.Create(int(rows))
        return make_noise(self.sigmas, dim=rows, robust=self.robust, robust_scale=self.robust_scale)

    @property
    def kernel(self) -> tuple[str, float]:
        return self.robust, float(self.robust_scale)

    def inverse_sigmas(self, rows: int) -> np.ndarray:
        """(rows,) ``1 / sigma`` of every row (ones for unit noise)."""
        if self.sigmas is None:
            return np.ones(rows)
        return np.broadcast_to(1.0 / np.asarray(self.sigmas, dtype=np.float64), (rows,))


def robust_rows(white: np.ndarray, kernels: Sequence[tuple[str, float]]) -> tuple[np.ndarray, np.ndarray]:
    """Per-row losses ``rho(e)`` and IRLS weights of whitened rows ``white`` (G, m), factor g with kernel
    ``kernels[g]`` (:func:`factors.common.row_loss_and_weight`; one call when all kernels agree)."""
    if len(set(kernels)) == 1:
        return row_loss_and_weight(white, *kernels[0])
    pairs = [row_loss_and_weight(white[n], *kernels[n]) for n in range(len(kernels))]
    return np.stack([a for a, _ in pairs]), np.stack([b for _, b in pairs])


@dataclass
class NormalEquations:
    """The whitened Gauss-Newton contribution of G factors of one kind, as GTSAM linearises them (rows scaled
    by the square roots of their IRLS weights): per factor ``A^T A``, ``A^T b`` (``b`` = minus the weighted
    whitened residual), ``b^T b`` and the factor's error (``graph.error``'s term: ``sum rho(e)``).

    Columns: the factor's keys in their order, each key's tangent dimension (``[root 3, trans 3, body_pose
    69, betas B]`` for a frame's keys).  ``hess`` / ``grad`` / ``bb`` are None when only the error was asked.
    ``structure``: a term's own compact form (e.g. the temporal pair's blocks) when it did not form ``hess``.
    """

    keys: list[tuple[int, ...]]
    error: np.ndarray
    """(G,) each factor's error."""
    hess: np.ndarray | None = None
    """(G, c, c)."""
    grad: np.ndarray | None = None
    """(G, c)."""
    bb: np.ndarray | None = None
    """(G,)."""
    structure: dict | None = field(default=None, repr=False)
    columns: np.ndarray | None = None
    """(c',) the factor columns ``hess`` and ``grad`` cover when the Jacobian touches only those (e.g. the
    joint limits' few body-pose components): ``hess`` (G, c', c'), ``grad`` (G, c'); None: all columns."""


def concatenate(parts: Sequence[NormalEquations]) -> NormalEquations:
    """One :class:`NormalEquations` of several groups of factors with the same key pattern (in order)."""
    if len(parts) == 1:
        return parts[0]
    out = NormalEquations([k for p in parts for k in p.keys], np.concatenate([p.error for p in parts]))
    columns = parts[0].columns
    if any((p.columns is None) != (columns is None) or (columns is not None and not np.array_equal(p.columns, columns))
           for p in parts):
        raise ValueError("concatenate: the parts cover different columns")
    out.columns = columns
    if all(p.hess is not None for p in parts):
        out.hess = np.concatenate([p.hess for p in parts])
        out.grad = np.concatenate([p.grad for p in parts])
        out.bb = np.concatenate([p.bb for p in parts])
    return out


def rows_normal_equations(keys: list[tuple[int, ...]], residual: np.ndarray, jacobian: np.ndarray | None,
                          inverse_sigmas: np.ndarray, kernels: Sequence[tuple[str, float]],
                          columns: np.ndarray | None = None) -> NormalEquations:
    """The assembler of stacked rows: G factors' unwhitened residuals (G, m) and Jacobians (G, m, c) over their
    key columns (None: error only), per-row inverse sigmas (G, m) (0 drops a row) and each factor's kernel.

    ``e = r / sigma``, ``w`` its IRLS weight, ``A = sqrt(w) J / sigma``, ``b = -sqrt(w) e``: the factor of a
    GTSAM ``noiseModel.Robust`` (``Scalar``) over ``Diagonal.Sigmas`` linearised.  ``columns``: the factor
    columns the Jacobian's (G, m, c') columns are (the others are zero; :attr:`NormalEquations.columns`)."""
    white = residual * inverse_sigmas
    loss, weight = robust_rows(white, kernels)
    used = inverse_sigmas > 0
    error = np.sum(loss * used, axis=1)
    if jacobian is None:
        return NormalEquations(keys, error)
    scale = np.sqrt(weight) * used
    a = jacobian * (scale * inverse_sigmas)[:, :, None]
    b = -scale * white
    a_t = np.swapaxes(a, 1, 2)
    return NormalEquations(keys, error, a_t @ a, (a_t @ b[:, :, None])[:, :, 0], np.sum(b * b, axis=1),
                           columns=columns)


def factor_normal_equations(cache, kind: str, keys_list: list[tuple[int, ...]], noise_of: Callable[[Any], RowNoise],
                            jacobians: bool) -> NormalEquations:
    """Factor by factor (when a batch does not hold them, or their rows differ in number): each factor's
    ``(residual, blocks)`` at the cache's last prefetch (``cache.factor_terms``) and its declared noise
    (``noise_of(spec)``) through :func:`rows_normal_equations`."""
    specs = cache.specs(kind)
    parts = []
    for keys in keys_list:
        r, blocks = cache.factor_terms(kind, keys)
        noise = noise_of(specs[keys])
        jac = np.concatenate(blocks, axis=1)[None] if jacobians else None
        parts.append(rows_normal_equations([keys], np.asarray(r)[None], jac,
                                           noise.inverse_sigmas(len(r))[None], [noise.kernel]))
    return concatenate(parts)


def frame_dims(blocks: Sequence[np.ndarray]) -> list[int]:
    """Tangent dimensions of a frame's keys ``[root, trans, body_pose, betas]`` (B from the last block)."""
    return [ROOT_DIM, TRANS_DIM, BODY_POSE_DIM, int(np.shape(blocks[3])[1])]


def cached_callback(kind: str, cache, compute: Callable, dims: Callable[[Sequence[np.ndarray]], list[int]],
                    finish: Callable | None = None):
    """The ``gtsam.CustomFactor`` callback of a term the term cache may serve: the cache's ``(residual,
    blocks)`` when it holds them at exactly the values GTSAM passes (``cache.lookup``), else
    ``compute(keys, values, jacobians)``; the Jacobian blocks are stored with their shapes checked against
    ``dims(blocks)`` (:func:`factors.common.set_jacobians`).  ``finish(residual, blocks or None)``: the
    term's last step on either (e.g. a kernel applied inside the factor), given the blocks only when GTSAM
    asks for the Jacobians."""
    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        keys = this.keys()
        hit = None if cache is None else cache.lookup(kind, keys, values, H is not None)
        r, blocks = hit if hit is not None else compute(keys, values, H is not None)
        if finish is not None:
            r, blocks = finish(r, blocks if H is not None else None)
        if H is not None:
            set_jacobians(H, blocks, len(r), dims(blocks))
        return r
    return error


@dataclass(frozen=True)
class Prefetched:
    """What the term cache's prefetch hands each term's batched evaluation (:attr:`Term.evaluate`): the
    frames it evaluated and the body-model quantities every term shares."""

    keys: list
    """The frames' keys (``factors.common.FrameKeys``), in frame order."""
    states: list
    """Each frame's ``factors.common.FrameState``."""
    keypoint_jacobians: Any | None
    """The keypoints of all frames with their Jacobians (a ``PointJacobians`` with leading dimension T), or
    None when the prefetch has no Jacobians."""
    keypoints: np.ndarray | None
    """(T, K, 3) world keypoints, metres, when the prefetch has no Jacobians (else None)."""
    setup: Any | None
    """The body model's ``JacobianSetup`` of all frames (with Jacobians), else None."""
    subset_vertices: np.ndarray | None
    """(T, C, 3) posed vertices of the cache's vertex subset, metres, or None."""

    @property
    def jacobians(self) -> bool:
        """Whether the terms are evaluated with their Jacobians."""
        return self.keypoint_jacobians is not None

    @cached_property
    def frame_of(self) -> dict[int, int]:
        """Root key -> frame index."""
        return {k.root: i for i, k in enumerate(self.keys)}


def jacobian_rows(jacobians, index) -> Any:
    """The frames ``index`` of a ``PointJacobians`` (every field indexed along its leading dimension)."""
    return dataclasses.replace(jacobians, **{f.name: getattr(jacobians, f.name)[index]
                                             for f in dataclasses.fields(jacobians)})


@dataclass(frozen=True)
class Term:
    """One energy term as the solvers see it (declared at the end of its ``factors/<term>.py``)."""

    kind: str
    """The factor kind (``TrackProblem.factor_kinds``, the term cache's registry)."""
    assemble: Callable[[Any, list, bool], NormalEquations]
    """``assemble(cache, keys_list, jacobians)``: the factors ``keys_list`` (registered with ``cache``) at its
    last prefetch as :class:`NormalEquations` (the error only when not ``jacobians``)."""
    own_frame: bool = True
    """The factors act on one frame's variables (and the shape) only: the stream forms their systems per
    frame in a batch.  False for terms linking frames (the temporal prior)."""
    evaluate: Callable[[Any, dict, Prefetched], None] | None = None
    """``evaluate(cache, specs, prefetched)``: the term's registered factors ``specs`` (keys -> spec) at the
    cache's prefetch (:class:`Prefetched`) in batched calls, filed with ``cache.add_batch(kind, group)`` (a
    dict with ``keys`` and the arrays; :attr:`materialise` reads one factor back) or, factor by factor,
    ``cache.set_factor_terms(kind, keys, (residual, blocks))``.  Called by the term cache's prefetch for every
    registered term that has one; None: the term's assembler evaluates it from the cache's frame arrays."""
    materialise: Callable[[dict, int, bool], tuple] | None = None
    """``materialise(group, n, jacobians)``: factor ``n`` of a group filed by :attr:`evaluate` as the
    ``(residual, blocks)`` its GTSAM callback returns (``blocks`` None without ``jacobians``)."""
    subset_vertices: bool = False
    """Its :attr:`evaluate` reads the posed vertex subset (:attr:`Prefetched.subset_vertices`): the prefetch
    poses it when factors of this term are registered."""
    frame_factor: Callable[..., Any] | None = None
    """``frame_factor(keys, frame, model, ctx, config, ground)`` -> a factor of one frame or None, called by
    ``pedx_graph.graph.build.frame_factors`` for every registered term that has one (terms built there
    explicitly, with their own settings, leave it None)."""


def kernels(cache, kind: str, keys_list: list[tuple[int, ...]], noise_of: Callable[[Any], RowNoise]
            ) -> list[tuple[str, float]]:
    """Each factor's robust kernel ``(robust, robust_scale)`` from its declared noise (remembered)."""
    def build():
        specs = cache.specs(kind)
        return [noise_of(specs[k]).kernel for k in keys_list]
    return cache.memo((kind, "kernels", tuple(keys_list)), build)


def stacked(cache, kind: str, keys_list: list[tuple[int, ...]], fields: Sequence[str]) -> dict[str, np.ndarray]:
    """The specs of the factors ``keys_list`` with their ``fields`` stacked into arrays (G, ...), remembered by
    the cache until its registry changes (the specs are fixed at construction)."""
    def build():
        specs = cache.specs(kind)
        return {name: np.stack([np.asarray(getattr(specs[k], name), dtype=np.float64) for k in keys_list])
                for name in fields}
    return cache.memo((kind, "stacked", tuple(keys_list), tuple(fields)), build)
