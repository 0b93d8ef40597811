"""Shared pieces of the pedx-graph factors: key bundles, noise models, Jacobian stacking, max-mixtures.

Conventions used by every factor in this package
------------------------------------------------
* Variables of one frame (keys chosen by the graph builder, bundled in :class:`FrameKeys`):

  ========== ================ ============= ===========================================================
  variable   GTSAM type       tangent dim   meaning
  ========== ================ ============= ===========================================================
  root       ``gtsam.Rot3``   3             ``world_R_body``, right perturbation ``R @ Exp(delta)``
  trans      ``np.ndarray``   3             SMPL ``trans`` in metres (world frame), read with ``atVector``
  body_pose  ``np.ndarray``   69            axis-angle of SMPL joints 1..23, radians
  betas      ``np.ndarray``   B (10)        shape coefficients, one vector per track
  ========== ================ ============= ===========================================================

* The error of a factor is ``h(x) - z`` (prediction minus measurement), whitened by its noise model.
* Jacobians are filled only when GTSAM asks (``H is not None``), one float64 C-contiguous array per key
  with shape ``(m, tangent dim)``: GTSAM does not check shapes, so :func:`set_jacobians` asserts them.
* Robust kernels are applied **per residual row** (``mEstimator.ReweightScheme.Scalar``): with GTSAM's
  default ``Block`` scheme one bad keypoint down-weights the whole frame, because the kernel then sees the
  norm of the factor's entire residual vector.  With ``Scalar`` both the factor error (sum of per-row
  losses) and the linearisation (per-row IRLS weights) are per row (checked in the tests).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol, Sequence

import gtsam
import numpy as np

from pedx_graph.body.rotation import log_so3
from pedx_graph.priors.gmm import MaxMixture  # noqa: F401  (the max-mixture residual, defined with the priors)

#: Tangent dimensions of the per-frame variables.
ROOT_DIM = 3
TRANS_DIM = 3
BODY_POSE_DIM = 69

#: Robust kernels accepted by :func:`make_noise` (``"none"`` = Gaussian).
ROBUST_KERNELS = ("none", "gemanmcclure", "huber", "cauchy")


class BodyModelLike(Protocol):
    """What the factors need of ``pedx_graph.body.BodyModel`` (see docs/architecture.md).

    ``point_jacobians(pose (72,), betas (B,), trans (3,), vertex_ids=None)`` returns an object with fields
    ``points (N,3)``, ``d_root (N,3,3)`` (right perturbation of ``world_R_body``), ``d_body_pose (N,3,69)``,
    ``d_trans (N,3,3)``, ``d_betas (N,3,B)``: the 18 PEDX keypoints when ``vertex_ids`` is None, else the
    given vertices.  ``forward(pose, betas, trans)`` returns an object with ``vertices (V,3)``,
    ``joints (24,3)`` and ``keypoints (18,3)``, world frame, metres.  ``rest_joints(betas)`` gives the rest
    (T-pose) joints (24, 3), linear in ``betas``; the posed pelvis is ``rest_joints(betas)[0] + trans``.
    """

    def point_jacobians(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray,
                        vertex_ids: np.ndarray | None = None) -> Any: ...

    def forward(self, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray) -> Any: ...

    def rest_joints(self, betas: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class FrameKeys:
    """GTSAM keys of the variables of one frame (the shape key is shared by every frame of a track)."""

    root: int
    """Key of ``world_R_body`` (``gtsam.Rot3``)."""
    trans: int
    """Key of ``trans`` (vector, 3)."""
    body_pose: int
    """Key of the 69-d body pose (vector)."""
    betas: int
    """Key of the track's shape coefficients (vector, B)."""

    def as_list(self) -> list[int]:
        """Keys in the order every body factor uses: ``[root, trans, body_pose, betas]``."""
        return [self.root, self.trans, self.body_pose, self.betas]

    @staticmethod
    def for_frame(index: int, betas_index: int = 0) -> "FrameKeys":
        """Default symbols: ``r<i>`` root, ``t<i>`` trans, ``p<i>`` body pose, ``b<betas_index>`` shape."""
        return FrameKeys(root=gtsam.symbol("r", index), trans=gtsam.symbol("t", index),
                         body_pose=gtsam.symbol("p", index), betas=gtsam.symbol("b", betas_index))


@dataclass(frozen=True)
class FrameState:
    """The current estimate of one frame as plain numpy arrays (float64)."""

    world_R_body: np.ndarray
    """(3, 3) root orientation."""
    root_rotvec: np.ndarray
    """(3,) ``Log(world_R_body)``, radians (SMPL ``pose[:3]``)."""
    trans: np.ndarray
    """(3,) metres."""
    body_pose: np.ndarray
    """(69,) axis-angle, radians."""
    betas: np.ndarray
    """(B,) shape coefficients."""

    @property
    def full_pose(self) -> np.ndarray:
        """(72,) SMPL pose: ``[Log(world_R_body), body_pose]``."""
        return np.concatenate([self.root_rotvec, self.body_pose])

    @staticmethod
    def from_arrays(world_R_body: np.ndarray, trans: np.ndarray, body_pose: np.ndarray,
                    betas: np.ndarray) -> "FrameState":
        """State from a rotation matrix (3, 3), trans (3,), body pose (69,), betas (B,)."""
        rot = as_f64(world_R_body)
        return FrameState(world_R_body=rot, root_rotvec=log_so3(rot), trans=as_f64(trans),
                          body_pose=as_f64(body_pose), betas=as_f64(betas))


def frame_key_list(keys: "FrameKeys | Sequence[int]") -> list[int]:
    """``[root, trans, body_pose, betas]`` from a :class:`FrameKeys` or a sequence of 4 keys."""
    out = keys.as_list() if isinstance(keys, FrameKeys) else [int(k) for k in keys]
    if len(out) != 4:
        raise ValueError(f"expected 4 frame keys (root, trans, body_pose, betas), got {len(out)}")
    return out


def read_frame_state(values: gtsam.Values, keys: Sequence[int]) -> FrameState:
    """Read ``[root, trans, body_pose, betas]`` (keys in that order) from GTSAM ``values``."""
    k_root, k_trans, k_pose, k_betas = keys
    rot = values.atRot3(k_root)
    return FrameState(world_R_body=rot.matrix(), root_rotvec=np.asarray(gtsam.Rot3.Logmap(rot)),
                      trans=np.asarray(values.atVector(k_trans), dtype=np.float64),
                      body_pose=np.asarray(values.atVector(k_pose), dtype=np.float64),
                      betas=np.asarray(values.atVector(k_betas), dtype=np.float64))


def as_f64(array: Any) -> np.ndarray:
    """``array`` as a C-contiguous float64 ndarray (no copy when it already is one)."""
    return np.ascontiguousarray(array, dtype=np.float64)


def set_jacobians(H: list, blocks: Sequence[np.ndarray], rows: int, dims: Sequence[int]) -> None:
    """Store one Jacobian block per key into GTSAM's ``H`` list, checking each shape ``(rows, dims[i])``.

    GTSAM does not check these shapes (too few rows segfaults, a wrong column count silently corrupts the
    solve), so a mismatch raises ``ValueError`` here instead.
    """
    for i, (block, dim) in enumerate(zip(blocks, dims)):
        block = as_f64(block)
        if block.shape != (rows, dim):
            raise ValueError(f"Jacobian block {i} has shape {block.shape}, expected {(rows, dim)}")
        H[i] = block


def make_noise(sigmas: np.ndarray | float, dim: int | None = None, robust: str = "none",
               robust_scale: float = 1.0) -> gtsam.noiseModel.Base:
    """Diagonal noise model with per-row ``sigmas`` (physical units), optionally robust per row.

    ``robust`` is one of :data:`ROBUST_KERNELS`; ``robust_scale`` is the kernel's scale in *whitened* units
    (e.g. 3 means "rows beyond ~3 sigma count less").  The kernel is wrapped with
    ``ReweightScheme.Scalar`` so it acts on each row separately (see the module docstring).
    """
    sig = np.atleast_1d(np.asarray(sigmas, dtype=np.float64))
    if dim is not None and sig.size == 1:
        sig = np.full(dim, float(sig[0]))
    if not np.all(np.isfinite(sig)) or np.any(sig <= 0):
        raise ValueError(f"noise sigmas must be finite and > 0, got {sig}")
    base = gtsam.noiseModel.Diagonal.Sigmas(as_f64(sig))
    kernel = robust.lower()
    if kernel == "none":
        return base
    if not robust_scale > 0:
        raise ValueError(f"robust_scale must be > 0, got {robust_scale}")
    scheme = gtsam.noiseModel.mEstimator.Base.ReweightScheme.Scalar
    est = gtsam.noiseModel.mEstimator
    if kernel == "gemanmcclure":
        m = est.GemanMcClure.Create(float(robust_scale), scheme)
    elif kernel == "huber":
        m = est.Huber.Create(float(robust_scale), scheme)
    elif kernel == "cauchy":
        m = est.Cauchy.Create(float(robust_scale), scheme)
    else:
        raise ValueError(f"unknown robust kernel {robust!r}; expected one of {ROBUST_KERNELS}")
    return gtsam.noiseModel.Robust.Create(m, base)


def row_loss_and_weight(white: np.ndarray, kernel: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """Per-row loss ``rho(e)`` and IRLS weight ``w(e) = rho'(e) / e`` of whitened rows ``e``, as GTSAM's
    ``mEstimator`` with ``ReweightScheme.Scalar`` uses them (:func:`make_noise`): the factor's error is
    ``sum rho(e_i)`` and its linearisation scales row i of ``A`` and ``b`` by ``sqrt(w(e_i))``.

    Geman-McClure ``rho = c^2 e^2 / (2 (c^2 + e^2))``, ``w = c^4 / (c^2 + e^2)^2``; Huber ``rho = e^2/2``,
    ``w = 1`` for ``|e| <= c``, else ``c |e| - c^2/2`` and ``c / |e|``; Cauchy ``rho = c^2/2 log(1 + e^2/c^2)``,
    ``w = c^2 / (c^2 + e^2)``; ``"none"``: ``e^2/2`` and 1.
    """
    e = np.asarray(white, dtype=np.float64)
    c = float(scale)
    kernel = kernel.lower()
    if kernel == "none":
        return 0.5 * e * e, np.ones_like(e)
    q = c * c + e * e
    if kernel == "gemanmcclure":
        return 0.5 * c * c * e * e / q, (c * c / q) ** 2
    if kernel == "cauchy":
        return 0.5 * c * c * np.log1p(e * e / (c * c)), c * c / q
    if kernel == "huber":
        a = np.abs(e)
        inside = a <= c
        return (np.where(inside, 0.5 * e * e, c * a - 0.5 * c * c),
                np.where(inside, 1.0, c / np.where(inside, 1.0, a)))
    raise ValueError(f"unknown robust kernel {kernel!r}; expected one of {ROBUST_KERNELS}")


def group_robust_weights(norms: np.ndarray, kernel: str, scale: float) -> tuple[np.ndarray, np.ndarray]:
    """``g(n) = sqrt(2 rho(n)) / n`` and ``h(n) = g'(n) / n`` for whitened group norms ``n`` (G,).

    ``rho`` is GTSAM's kernel (``mEstimator``) with scale ``c``: Geman-McClure ``c^2 n^2 / (2 (c^2 + n^2))``,
    Huber ``n^2/2`` (n <= c) else ``c n - c^2/2``, Cauchy ``c^2/2 log(1 + n^2/c^2)``, ``"none"``: ``n^2/2``.
    Both are finite at ``n = 0`` (``g(0) = 1``).  See :func:`robustify_groups`.
    """
    n = np.asarray(norms, dtype=np.float64)
    c = float(scale)
    kernel = kernel.lower()
    if kernel == "none":
        return np.ones_like(n), np.zeros_like(n)
    if not c > 0:
        raise ValueError(f"robust scale must be > 0, got {scale}")
    if kernel == "gemanmcclure":
        q = c * c + n * n
        return c / np.sqrt(q), -c / (q * np.sqrt(q))
    if kernel == "huber":
        out = n > c
        ns = np.where(out, n, 2.0 * c)                           # safe values where inside
        root = np.sqrt(2.0 * c * ns - c * c)
        g = np.where(out, root / ns, 1.0)
        h = np.where(out, c * (c - ns) / (ns ** 3 * root), 0.0)
        return g, h
    if kernel == "cauchy":
        x = (n / c) ** 2
        small = x < 1e-6
        xs = np.where(small, 1.0, x)
        ns = np.where(small, 1.0, n)
        big_l = np.log1p(xs)
        sq = np.sqrt(big_l)
        g = np.where(small, 1.0 - x / 4.0, c * sq / ns)
        h = np.where(small, -1.0 / (2.0 * c * c),
                     c * (ns * ns / ((c * c + ns * ns) * sq) - sq) / ns ** 3)
        return g, h
    raise ValueError(f"unknown robust kernel {kernel!r}; expected one of {ROBUST_KERNELS}")


def group_norms_from_losses(losses: np.ndarray, kernel: str, scale: float) -> np.ndarray:
    """Whitened group norms ``n`` (G,) from their losses ``rho(n)`` (G,): the inverse of the kernel of
    :func:`group_robust_weights` (each is increasing in ``n``), so a factor robustified inside
    (:func:`robustify_groups`, ``rho = |s|^2 / 2``) still tells its residual without the kernel.  A
    Geman-McClure loss at its bound ``c^2 / 2`` gives ``n = 1e8 c`` (the offset is beyond what float64 tells
    apart there)."""
    loss = np.maximum(np.asarray(losses, dtype=np.float64), 0.0)
    c = float(scale)
    kernel = kernel.lower().replace("_", "")
    if kernel == "none":
        return np.sqrt(2.0 * loss)
    if not c > 0:
        raise ValueError(f"robust scale must be > 0, got {scale}")
    if kernel == "gemanmcclure":
        return np.sqrt(2.0 * loss * c * c / np.maximum(c * c - 2.0 * loss, 1e-16 * c * c))
    if kernel == "cauchy":
        return c * np.sqrt(np.expm1(2.0 * loss / (c * c)))
    if kernel == "huber":
        return np.where(loss <= 0.5 * c * c, np.sqrt(2.0 * loss), (loss + 0.5 * c * c) / c)
    raise ValueError(f"unknown robust kernel {kernel!r}; expected one of {ROBUST_KERNELS}")


def robustify_groups(white: np.ndarray, kernel: str, scale: float, blocks: Sequence[np.ndarray] | None = None,
                     block_scale: float = 1.0) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Robust kernel on groups of whitened rows (e.g. the 3 rows of one LiDAR point), inside a factor.

    ``white`` (G, d) whitened residuals, ``blocks`` Jacobians of ``white`` flattened, each (G*d, k).  Each
    group ``r`` becomes ``s = g(|r|) r`` so that ``0.5 |s|^2 = rho(|r|)`` (rotation invariant, unlike a
    per-row kernel), with Jacobian ``ds/dr = g I + h r r^T`` (:func:`group_robust_weights`).  Use with a unit
    noise model.  Returns ``s`` flattened (G*d,) and the transformed blocks.  ``block_scale``: the blocks are
    the Jacobians of ``white / block_scale`` (e.g. unwhitened, with ``block_scale`` = 1 / sigma), folded into
    ``g`` and ``h`` at no extra cost.
    """
    white = np.asarray(white, dtype=np.float64)
    norms = np.sqrt((white * white).sum(axis=1))
    g, h = group_robust_weights(norms, kernel, scale)
    s = (g[:, None] * white).reshape(-1)
    if blocks is None:
        return s, None
    out = []
    num_g, d = white.shape
    g_b, h_b = g * block_scale, h * block_scale
    for block in blocks:
        jr = np.asarray(block, dtype=np.float64).reshape(num_g, d, -1)
        rt_j = np.einsum("gd,gdk->gk", white, jr)
        new = g_b[:, None, None] * jr
        new += (h_b[:, None] * white)[:, :, None] * rt_j[:, None, :]
        out.append(as_f64(new.reshape(num_g * d, -1)))
    return s, out


_GRAMS: dict[tuple[int, int], tuple] = {}


def component_grams(mixture: MaxMixture, start: int = 0) -> np.ndarray:
    """``J_k^T J_k`` (K, D - start, D - start) of every component's max-mixture residual Jacobian, rows and
    columns from ``start`` on: the Gauss-Newton information of a max-mixture factor whose component k is
    selected (remembered per mixture and start; read-only)."""
    hit = _GRAMS.get((id(mixture), start))
    if hit is None or hit[0] is not mixture:
        jac = mixture.jacobians(np.arange(mixture.num_components))[:, :, start:]
        gram = np.swapaxes(jac, 1, 2) @ jac
        gram.setflags(write=False)
        hit = _GRAMS[(id(mixture), start)] = (mixture, gram)
    return hit[1]


def mixture_for(dim: int, what: str, weights=None, means=None, prec_chol=None, mixture: MaxMixture | None = None,
                covariance_scale: float = 1.0) -> MaxMixture:
    """The max-mixture of a factor: ``mixture`` when given (its covariance scale is baked in), else one built
    from the GMM arrays; ValueError unless it is ``dim``-dimensional (``what`` names the factor)."""
    if mixture is None:
        if weights is None or means is None or prec_chol is None:
            raise ValueError(f"{what} needs weights, means and prec_chol, or a mixture")
        mixture = MaxMixture(weights, means, prec_chol, covariance_scale=covariance_scale)
    if mixture.dim != dim:
        raise ValueError(f"{what} mixture must be {dim}-d, got {mixture.dim}")
    return mixture
