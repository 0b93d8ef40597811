"""E_J (PedX): reprojection of the body model's N keypoint rows into every rectified image that labels them.

The factor kind is still called ``stereo_reprojection`` (E_J,l + E_J,r of the paper), but one factor holds
all K >= 1 labelled images of the pedestrian at that frame: the left and right images of the frame's
primary stereo pair, the images of any other pair that labelled it too (PedX: the two left cameras are
~0.93 m apart, a baseline 3x the in-pair ones), or a single camera.

Measurement model, for each labelled keypoint k of image c = 1..K (pixels of the rectified image):

    image_P_world_c = P_rect_c @ rect_T_world(pair of c)                          (3, 4): world -> pixels
    [u w, v w, w]   = image_P_world_c @ [world_p_k(root, trans, body_pose, betas); 1]
    r_k,c           = [u, v] - z_k,c                                              (2,) pixels

``P_rect_c`` is the pair's ``left_P_rect`` or ``right_P_rect`` (both act on points of the pair's rectified
left frame ``rect``), ``rect_T_world`` the pair's world -> rectified-left transform (world = LiDAR frame,
metres).  ``world_p_k`` comes from ``BodyModel.point_jacobians``.  Rows: image by image in the order given,
each image's labelled keypoints (u, v) in row order.  The depth ``w`` is clamped to
``min_depth`` metres (its derivative is then dropped) so points behind a camera stay finite.

Keypoint rows: N = 18 for PedX labels (PEDX_KEYPOINTS order); a track labelled in a detector's keypoint set
is fitted through a *fit layout* of N = 18 + E rows (``pedx_graph.detections.fit_layout``: the 18 PedX rows,
then the set's E keypoints without a PedX row), the body model's keypoints in the same rows.  The term takes
N from the labels (every image of a factor has the same N); the per-keypoint arrays below have N entries.

Noise: per-row sigma ``sigma_px`` for keypoints flagged visible and ``sigma_occluded_px`` for labelled but
not visible ones — each a scalar or an (N,) array of pixels per keypoint (e.g. click noise estimated per
keypoint from the labels) — divided by ``sqrt(weight_k)`` (``keypoint_weights``: relative weight of each
keypoint's squared error, (N,); 0 drops it; by default the hips get 0.25 because the annotators click the
hip surface while the model's hip joints sit inside the pelvis, and rows past the 18th get 1).  A label's
own per-keypoint sigma (``ImageKeypoints.sigma_px``: imported detections, from their confidences)
replaces ``sigma_px`` / ``sigma_occluded_px`` for that row and image (the keypoint weight still applies).
Robust per keypoint and image (Geman-McClure by default, scale ``c`` in whitened units): the kernel acts on
the whitened 2D offset ``e_k,c = r_k,c / sigma_k,c`` as a whole, ``rho(|e_k,c|)``, so a keypoint is kept or
rejected with both its coordinates.  (A kernel on each row alone could reject a wrong label's column and
keep its row — a left/right swap keeps about its row —, leaving the fit in a wrong minimum whose
covariance, formed from the kept row, claims centimetres.)  The kernel is applied inside the factor under a
unit noise model, the way GTSAM's ``noiseModel.Robust`` applies it to rows (:func:`reprojection_residual`):

* evaluated for its error, the factor's rows are ``s_k,c = g(|e|) e`` with ``|s|^2 / 2 = rho(|e|)``
  (:func:`factors.common.robustify_groups`), so the factor's error is ``sum rho`` and the residual tables
  recover each ``|e|`` from it;
* linearised, its rows and Jacobians are those of iteratively reweighted least squares: ``sqrt(w) e`` and
  ``sqrt(w) de/dx`` with ``w = rho'(|e|) / |e|`` (:func:`factors.common.row_loss_and_weight` of the norm).
  ``A^T b`` is then the gradient of ``sum rho`` and ``A^T A`` the reweighted Gauss-Newton matrix, whose
  steps decrease a kernel concave in ``|e|^2`` (all of :data:`factors.common.ROBUST_KERNELS`) even without
  damping (iSAM2).  The exact Jacobian of ``s`` would give an outlier a radial curvature ``(w/g)^2``
  that vanishes faster than its gradient: undamped steps then overshoot.

Jacobians: ``d[u,v]/d world_p = (M[:2] - [u,v] M[2]) / w`` with ``M = image_P_world[:, :3]``, chained with the
body-model point Jacobians.

Batched paths (the track's term cache, the batch linearizer, the stream's frame systems) evaluate T frames
with different K at once by padding every frame to the batch's largest K with images whose projection is
``[0 0 0 0; 0 0 0 0; 0 0 0 1]`` (pixels 0, derivative 0) and whose rows carry inverse sigma 0
(:func:`stereo_dense_rows`).  The residual, its whitening and kernel and the normal equations of those batches
are defined here once (:func:`stereo_pixels`, :func:`reprojection_whiten`, :func:`reprojection_normal_equations`;
one factor's rows: :func:`reprojection_residual`)
and reach the batch linearizer and the stream's frame systems through this term's assembler
(:func:`assemble`, registered in :mod:`factors.registry`); the term cache (:mod:`pedx_graph.graph.batch`)
evaluates the pixels.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Mapping, Protocol, Sequence

import gtsam
import numpy as np

from factors.common import (BodyModelLike, FrameKeys, FrameState, as_f64, frame_key_list, read_frame_state,
                            robustify_groups, row_loss_and_weight)
from factors.terms import (NormalEquations, Prefetched, RowNoise, Term, cached_callback, concatenate, frame_dims,
                           jacobian_rows)
from pedx_graph.keypoints import PEDX_KEYPOINTS

#: The factor kind (``TrackProblem.factor_kinds``, the term cache's registry).
KIND = "stereo_reprojection"


class StereoCalibration(Protocol):
    """What the term reads of a stereo pair's calibration (``pedx_graph.data.types.StereoCalibration``)."""

    name: str
    left_P_rect: np.ndarray
    """(3, 4) rectified left projection (pixels from points of the rectified left frame)."""
    right_P_rect: np.ndarray
    """(3, 4) rectified right projection (same frame)."""
    rect_T_world: np.ndarray
    """(4, 4) world (LiDAR) -> rectified left frame."""


class View2D(Protocol):
    """What the term reads of one image's labels (``pedx_graph.data.types.View2D``)."""

    keypoints: np.ndarray
    """(N, 2) pixels, NaN where not labelled (N = 18: PedX's; 18 + E: a fit layout)."""
    visible: np.ndarray
    """(N,) bool."""

#: The PedX keypoint rows (the first rows of every layout; K of plain PedX labels).
NUM_KEYPOINTS = len(PEDX_KEYPOINTS)

#: Relative weights of the 18 keypoints' squared errors (PEDX_KEYPOINTS order): hips 0.25, others 1.
DEFAULT_KEYPOINT_WEIGHTS = np.array([0.25 if name in ("lhip", "rhip") else 1.0 for name in PEDX_KEYPOINTS])


def default_keypoint_weights(count: int = NUM_KEYPOINTS) -> np.ndarray:
    """(count,) default weights: :data:`DEFAULT_KEYPOINT_WEIGHTS` on the 18 PedX rows, 1 on the rows after."""
    return np.concatenate([DEFAULT_KEYPOINT_WEIGHTS, np.ones(max(int(count) - NUM_KEYPOINTS, 0))])[:int(count)]

#: Projection of a padding image in the batched paths: every point maps to pixel (0, 0) at depth 1.
_PAD_PROJECTION = np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]])

SIDES = ("left", "right")


def image_projection(calibration: StereoCalibration, side: str) -> np.ndarray:
    """``image_P_world`` (3, 4) of the ``side`` (``"left"``/``"right"``) rectified image of a pair:
    ``P_rect @ rect_T_world``, world (LiDAR) points in metres -> homogeneous pixels."""
    if side not in SIDES:
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    proj = calibration.left_P_rect if side == "left" else calibration.right_P_rect
    return as_f64(as_f64(proj) @ calibration.rect_T_world)


@dataclass(frozen=True)
class ImageKeypoints:
    """2D keypoint labels of one pedestrian in one rectified image, with that image's projection."""

    uv: np.ndarray
    """(N, 2) pixels, NaN where not labelled (N: the keypoint rows, see the module docstring)."""
    visible: np.ndarray
    """(N,) bool, the annotator's visible flag."""
    image_P_world: np.ndarray
    """(3, 4) projection of world (LiDAR) points in metres to homogeneous pixels (:func:`image_projection`)."""
    name: str = ""
    """Which image, e.g. ``"ylw79D0-red707B/left"`` (for messages only)."""
    sigma_px: np.ndarray | None = None
    """(N,) the labels' own pixel sigma per keypoint (imported detections: from their confidences), NaN where
    the label file gives none; where finite it replaces the configured sigma of that row (the keypoint weight
    still divides it).  None: the configured sigmas for every row."""

    @staticmethod
    def from_view(view: View2D, calibration: StereoCalibration, side: str) -> "ImageKeypoints":
        """The labels ``view`` of the ``side`` image of the pair ``calibration``."""
        own = getattr(view, "sigma_px", None)
        return ImageKeypoints(as_f64(view.keypoints), np.asarray(view.visible, dtype=bool),
                              image_projection(calibration, side), f"{calibration.name}/{side}",
                              None if own is None else as_f64(own))


def images_from_views(views: Iterable[tuple[str, str, View2D]],
                      calibrations: Mapping[str, StereoCalibration]) -> list[ImageKeypoints]:
    """:class:`ImageKeypoints` of ``(pair name, side, View2D)`` triples (e.g. ``TrackFrame.labelled_views()``),
    each with the projection of its pair's calibration in ``calibrations``."""
    return [ImageKeypoints.from_view(view, calibrations[pair], side) for pair, side, view in views]


@dataclass(frozen=True)
class StereoKeypoints:
    """2D keypoint labels of one pedestrian in both rectified images of one stereo pair."""

    left_uv: np.ndarray
    """(18, 2) pixels in the rectified left image, NaN where not labelled."""
    right_uv: np.ndarray
    """(18, 2) pixels in the rectified right image, NaN where not labelled."""
    left_visible: np.ndarray
    """(18,) bool, the annotator's visible flag in the left image."""
    right_visible: np.ndarray
    """(18,) bool, the visible flag in the right image."""

    @staticmethod
    def from_views(left: View2D | None, right: View2D | None) -> "StereoKeypoints":
        """From the ``TrackFrame.left`` / ``.right`` labels (either may be None: nothing labelled there)."""
        count = next((len(v.keypoints) for v in (left, right) if v is not None), NUM_KEYPOINTS)

        def parts(view):
            if view is None:
                return np.full((count, 2), np.nan), np.zeros(count, bool)
            return as_f64(view.keypoints), np.asarray(view.visible, dtype=bool)
        luv, lvis = parts(left)
        ruv, rvis = parts(right)
        return StereoKeypoints(luv, ruv, lvis, rvis)

    def images(self, calibration: StereoCalibration) -> list[ImageKeypoints]:
        """The left and right images of the pair as :class:`ImageKeypoints` (left first)."""
        return [ImageKeypoints(self.left_uv, self.left_visible, image_projection(calibration, "left"),
                               f"{calibration.name}/left"),
                ImageKeypoints(self.right_uv, self.right_visible, image_projection(calibration, "right"),
                               f"{calibration.name}/right")]


@dataclass(frozen=True)
class _ImageRows:
    """Pre-selected rows of one image: keypoint indices (n,), measured uv (n, 2), projection (3, 4)."""

    index: np.ndarray
    uv: np.ndarray
    image_P_world: np.ndarray


@dataclass(frozen=True)
class StereoSetup:
    """Everything fixed at construction: the selected rows of each of the K images that have any, their
    sigmas and projections."""

    images: tuple[_ImageRows, ...]
    """The K images with at least one row, in the order given."""
    sigmas: np.ndarray
    """(m,) per-row sigmas in pixels (rows: image by image, (u, v) per keypoint)."""
    min_depth: float
    projections: np.ndarray = field(default=None, repr=False)
    """(K, 3, 4) the images' ``image_P_world`` stacked (filled on construction)."""
    num_keypoints: int = NUM_KEYPOINTS
    """The keypoint rows of every image (18, or 18 + E in a fit layout): the model's keypoints it projects."""

    def __post_init__(self) -> None:
        if self.projections is None:
            stacked = (np.stack([img.image_P_world for img in self.images]) if self.images
                       else np.zeros((0, 3, 4)))
            object.__setattr__(self, "projections", stacked)

    @property
    def rows(self) -> int:
        return int(self.sigmas.size)

    @property
    def num_images(self) -> int:
        """K: the number of images with at least one row."""
        return len(self.images)


@dataclass(frozen=True)
class StereoTerm:
    """A reprojection factor's fixed setup and its noise: per-row sigmas ``setup.sigmas`` (pixels) and the
    robust kernel on each keypoint's whitened 2D offset per image (scale in whitened units)."""

    setup: StereoSetup
    robust: str
    robust_scale: float


def _per_keypoint(value, what: str, count: int) -> np.ndarray:
    """A scalar or a (count,) array of pixels as a (count,) array; every entry finite and > 0."""
    arr = np.broadcast_to(as_f64(value), (count,)) if np.ndim(value) == 0 else as_f64(value)
    if arr.shape != (count,) or not np.all(np.isfinite(arr) & (arr > 0)):
        raise ValueError(f"reprojection: {what} must be a positive scalar or ({count},) array of "
                         f"positive pixels, got {value!r}")
    return arr


def build_reprojection_setup(images: Sequence[ImageKeypoints], sigma_px=2.0, sigma_occluded_px=6.0,
                             keypoint_weights: np.ndarray | None = None, min_depth: float = 0.1) -> StereoSetup:
    """Select each image's rows (labelled, finite, weight > 0) and their sigmas; images without any row are
    left out.  ``sigma_px`` / ``sigma_occluded_px``: pixels, scalar or (N,) per keypoint, N the images'
    keypoint rows (every image the same; 18 when there is no image)."""
    count = len(images[0].uv) if len(images) else NUM_KEYPOINTS
    sigma_vis = _per_keypoint(sigma_px, "sigma_px", count)
    sigma_occ = _per_keypoint(sigma_occluded_px, "sigma_occluded_px", count)
    if not min_depth > 0:
        raise ValueError(f"reprojection: min_depth must be > 0, got {min_depth}")
    weights = default_keypoint_weights(count) if keypoint_weights is None else as_f64(keypoint_weights)
    if weights.shape != (count,) or np.any(weights < 0):
        raise ValueError(f"keypoint_weights must be ({count},) and >= 0, got {weights}")
    rows, sigmas = [], []
    for image in images:
        uv = as_f64(image.uv)
        vis = np.asarray(image.visible, dtype=bool)
        proj = as_f64(image.image_P_world)
        if uv.shape != (count, 2) or vis.shape != (count,) or proj.shape != (3, 4):
            raise ValueError(f"image {image.name or len(rows)}: keypoints must be ({count}, 2) with "
                             f"({count},) visible flags and a (3, 4) projection, got {uv.shape}, "
                             f"{vis.shape} and {proj.shape}")
        idx = np.flatnonzero(np.all(np.isfinite(uv), axis=1) & (weights > 0))
        if idx.size == 0:
            continue
        sig = np.where(vis[idx], sigma_vis[idx], sigma_occ[idx])
        if image.sigma_px is not None:                  # the label's own sigma (a detector's confidence)
            own = as_f64(image.sigma_px)[idx]
            sig = np.where(np.isfinite(own) & (own > 0), own, sig)
        sig = sig / np.sqrt(weights[idx])
        sigmas.append(np.repeat(sig, 2))
        rows.append(_ImageRows(index=idx, uv=uv[idx], image_P_world=proj))
    return StereoSetup(images=tuple(rows), sigmas=np.concatenate(sigmas) if sigmas else np.zeros(0),
                       min_depth=float(min_depth), num_keypoints=int(count))


def build_stereo_setup(measurement: StereoKeypoints, calibration: StereoCalibration, sigma_px=2.0,
                       sigma_occluded_px=6.0, keypoint_weights: np.ndarray | None = None,
                       min_depth: float = 0.1) -> StereoSetup:
    """:func:`build_reprojection_setup` of one pair's left and right images."""
    return build_reprojection_setup(measurement.images(calibration), sigma_px, sigma_occluded_px,
                                    keypoint_weights, min_depth)


def _keypoints(model: BodyModelLike, state: FrameState) -> np.ndarray:
    """(K, 3) world keypoints; ``model.keypoints`` (cheap: few vertices) when the model has it."""
    if hasattr(model, "keypoints") and callable(model.keypoints):
        return model.keypoints(state.full_pose, state.betas, state.trans)
    return model.forward(state.full_pose, state.betas, state.trans).keypoints


def batch_images(setups: Sequence[StereoSetup]) -> int:
    """K of a batch: the largest number of images of ``setups`` (at least 1)."""
    return max([1] + [su.num_images for su in setups])


def _stacked_projections(setups: Sequence[StereoSetup], num_images: int) -> np.ndarray:
    """(T, K, 3, 4) projections of every frame's images, padded with :data:`_PAD_PROJECTION`."""
    if all(su.num_images == num_images for su in setups):
        return np.stack([su.projections for su in setups])
    out = np.broadcast_to(_PAD_PROJECTION, (len(setups), num_images, 3, 4)).copy()
    for t, su in enumerate(setups):
        out[t, :su.num_images] = su.projections
    return out


def stereo_pixels(points: np.ndarray, setups: Sequence[StereoSetup], derivatives: bool = False
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Pixels of all N keypoints of T frames (T, N, 3) in each frame's images, ``uv`` (T, K, N, 2) with
    K = :func:`batch_images` (frames with fewer images padded: pixels 0), and (when ``derivatives``)
    ``d uv / d point`` (T, K, N, 2, 3) (0 on padding images).  N: the keypoint rows (18, or 18 + E in a fit
    layout)."""
    points = as_f64(points)
    proj = _stacked_projections(setups, batch_images(setups))                         # (T, K, 3, 4)
    proj_m, proj_c = proj[..., :3], proj[..., 3]
    min_depth = np.array([su.min_depth for su in setups])[:, None, None]
    hom = points[:, None] @ np.swapaxes(proj_m, 2, 3) + proj_c[:, :, None]          # (T, K, N, 3)
    depth = hom[..., 2]
    clamped = depth < min_depth
    w = np.where(clamped, min_depth, depth)
    uv = hom[..., :2] / w[..., None]                                                 # (T, K, N, 2)
    if not derivatives:
        return uv, None
    keep = np.where(clamped, 0.0, 1.0)[..., None, None]
    d_uv = (proj_m[:, :, None, :2, :] - keep * uv[..., :, None] * proj_m[:, :, None, 2:3, :]) \
        / w[..., None, None]                                                         # (T, K, N, 2, 3)
    return uv, d_uv


def stereo_blocks(d_uv: np.ndarray, jac) -> list[np.ndarray]:
    """``[d uv / d root, trans, body_pose, betas]``, each (T, K, N, 2, k), from :func:`stereo_pixels`'
    ``d_uv`` and the keypoints' ``PointJacobians`` with leading dimension T."""
    return [d_uv @ np.asarray(getattr(jac, name), dtype=np.float64)[:, None]
            for name in ("d_root", "d_trans", "d_body_pose", "d_betas")]


def stereo_project(points: np.ndarray, setups: Sequence[StereoSetup], jac=None
                   ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Pixels of all N keypoints of T frames in their images, ``uv`` (T, K, N, 2), and (when ``jac``, the
    keypoints' ``PointJacobians`` with leading dimension T, is given) ``[d uv / d root, trans, body_pose,
    betas]``, each (T, K, N, 2, k) — every frame with its own setup's projections, in batched products."""
    uv, d_uv = stereo_pixels(points, setups, jac is not None)
    return uv, None if jac is None else stereo_blocks(d_uv, jac)


def stereo_select(uv: np.ndarray, full: list[np.ndarray] | None, setup: StereoSetup, frame: int
                  ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """One frame's factor rows out of :func:`stereo_project`: residual (m,) and blocks (m, k) or None."""
    images = setup.images
    r = np.concatenate([(uv[frame, c, img.index] - img.uv).reshape(-1) for c, img in enumerate(images)]
                       + [np.zeros(0)])
    if full is None:
        return r, None
    return r, [as_f64(np.concatenate([b[frame, c, img.index].reshape(-1, b.shape[-1])
                                      for c, img in enumerate(images)] + [np.zeros((0, b.shape[-1]))]))
               for b in full]


def stereo_reprojection_batch(points: np.ndarray, setups: Sequence[StereoSetup], jac=None
                              ) -> list[tuple[np.ndarray, list[np.ndarray] | None]]:
    """Unwhitened residuals and (when ``jac`` is given) Jacobian blocks of T frames at once.

    ``points`` (T, N, 3) world keypoints (N: the setups' keypoint rows); ``setups`` one :class:`StereoSetup`
    per frame; ``jac`` the keypoints' ``PointJacobians`` with leading dimension T (or None).  Returns per
    frame ``(r (m,), [J_root, J_trans, J_body_pose, J_betas] or None)``: :func:`stereo_project` then
    :func:`stereo_select`.
    """
    uv, full = stereo_project(points, setups, jac)
    return [stereo_select(uv, full, su, f) for f, su in enumerate(setups)]


def stereo_dense_rows(setup: StereoSetup, num_images: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The setup's measurements and inverse sigmas laid out like one frame of :func:`stereo_pixels`' ``uv``:
    (K, N, 2) each (K = ``num_images``, default the setup's own; N = ``setup.num_keypoints``), with inverse
    sigma 0 (and measurement 0) on the rows the factor does not use and on padding images."""
    k = setup.num_images if num_images is None else int(num_images)
    meas = np.zeros((k, setup.num_keypoints, 2))
    inv_sigma = np.zeros((k, setup.num_keypoints, 2))
    start = 0
    for c, img in enumerate(setup.images):
        n = len(img.index)
        meas[c, img.index] = img.uv
        inv_sigma[c, img.index] = 1.0 / setup.sigmas[start:start + 2 * n].reshape(n, 2)
        start += 2 * n
    return meas, inv_sigma


def reprojection_rows(setups: Sequence[StereoSetup], num_images: int) -> tuple[np.ndarray, np.ndarray]:
    """:func:`stereo_dense_rows` of G factors stacked: measurements and inverse sigmas (G, K, N, 2) (every
    factor of a batch has the same N: one track, one body model)."""
    dense = [stereo_dense_rows(su, num_images) for su in setups]
    return np.stack([m for m, _ in dense]), np.stack([i for _, i in dense])


@dataclass(frozen=True)
class WhitenedRows:
    """G factors' rows at one evaluation, laid out like :func:`stereo_pixels`' ``uv`` (G, K, N, 2): the
    whitened offsets ``e``, and per keypoint-image (G, K, N) the inverse sigma (0 on unused rows), the
    kernel's loss ``rho(|e|)`` (0 on unused rows) and IRLS weight ``w(|e|)``
    (:func:`factors.common.row_loss_and_weight` of the norm)."""

    white: np.ndarray
    inv: np.ndarray
    loss: np.ndarray
    weight: np.ndarray


def reprojection_whiten(uv: np.ndarray, meas: np.ndarray, inv_sigma: np.ndarray,
                        kernels: Sequence[tuple[str, float]]) -> WhitenedRows:
    """G factors' whitened rows and kernel (:class:`WhitenedRows`) from the batched pixels ``uv``
    (G, K, N, 2) and :func:`reprojection_rows`; ``kernels``: each factor's ``(robust, robust_scale)``.  A
    keypoint's u and v rows share one sigma, so ``inv`` is the u row's."""
    white = (uv - meas) * inv_sigma
    inv = inv_sigma[..., 0]
    norms = np.sqrt(np.sum(white * white, axis=-1))
    if len(set(kernels)) == 1:
        loss, weight = row_loss_and_weight(norms, *kernels[0])
    else:
        pairs = [row_loss_and_weight(norms[n], *kernels[n]) for n in range(len(kernels))]
        loss, weight = np.stack([a for a, _ in pairs]), np.stack([b for _, b in pairs])
    return WhitenedRows(white, inv, loss * (inv > 0), weight)


def reprojection_normal_equations(d_uv: np.ndarray, jac, rows: WhitenedRows
                                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Whitened normal equations of G reprojection factors as GTSAM linearises them (each keypoint-image's
    two rows scaled by the square root of its IRLS weight, :func:`reprojection_residual`): ``A^T A``
    (G, D, D), ``A^T b`` (G, D) and ``b^T b`` (G,), columns ``[root (3), trans (3), body_pose (69), betas
    (B)]`` (D = 75 + B).

    Formed through the keypoints: the rows of keypoint k in all images are ``D_k J_k`` (D_k: the whitened,
    weighted pixel derivatives (2K, 3) from ``d_uv`` (G, K, N, 2, 3), J_k: the keypoint's Jacobian
    (3, D) from ``jac``, ``PointJacobians`` with leading dimension G), so ``A^T A = sum_k J_k^T (D_k^T D_k)
    J_k`` and ``A^T b = sum_k J_k^T D_k^T b_k`` — 3 N keypoint rows per frame whatever K.  ``rows`` from
    :func:`reprojection_whiten` (unused and padding rows: ``inv`` 0)."""
    num = rows.white.shape[0]
    used = rows.inv > 0
    scale = rows.weight * rows.inv * used                                 # (G, K, N); unused rows: 0
    info = np.einsum("gck,gckri,gckrj->gkij", scale * rows.inv, d_uv, d_uv)          # D_k^T D_k, (G, N, 3, 3)
    pull = np.einsum("gck,gckr,gckri->gki", -scale, rows.white, d_uv)                # (G, N, 3)
    jk = np.concatenate([jac.d_root, np.broadcast_to(jac.d_trans, jac.d_root.shape), jac.d_body_pose,
                         jac.d_betas], axis=3)                            # (G, N, 3, D)
    jrows = jk.reshape(num, -1, jk.shape[3])
    jrows_t = np.swapaxes(jrows, 1, 2)
    bb = np.sum(rows.weight * used * np.sum(rows.white * rows.white, axis=-1), axis=(1, 2))
    return (jrows_t @ (info @ jk).reshape(jrows.shape), (jrows_t @ pull.reshape(num, -1, 1))[:, :, 0], bb)


def reprojection_residual(r: np.ndarray, blocks: list[np.ndarray] | None, term: StereoTerm
                          ) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """One factor's rows under its unit noise model from the pixel residual ``r`` (m,) of
    :func:`stereo_select` and its Jacobian blocks (each (m, k), or None), whitened by
    ``term.setup.sigmas``; per keypoint and image (its (u, v) rows) with the term's kernel (module
    docstring): without blocks ``s = g(|e|) e`` (``|s|^2 / 2 = rho``: the factor's error); with blocks the
    IRLS rows ``sqrt(w(|e|)) e`` and blocks ``sqrt(w) de/dx``, as GTSAM linearises a robust noise model."""
    inv = 1.0 / term.setup.sigmas
    white = (np.asarray(r, dtype=np.float64) * inv).reshape(-1, 2)
    if blocks is None:
        return robustify_groups(white, term.robust, term.robust_scale)[0], None
    _, weight = row_loss_and_weight(np.sqrt(np.sum(white * white, axis=1)), term.robust, term.robust_scale)
    rows = np.repeat(np.sqrt(weight), 2) * inv
    return rows * np.asarray(r, dtype=np.float64), [np.asarray(b, dtype=np.float64) * rows[:, None]
                                                    for b in blocks]


def stereo_reprojection_error(model: BodyModelLike, state: FrameState, setup: StereoSetup,
                              want_jacobians: bool = False) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Unwhitened residual (m,) in pixels and, when asked, ``[J_root, J_trans, J_body_pose, J_betas]``."""
    if want_jacobians:
        jac = model.point_jacobians(state.full_pose, state.betas, state.trans)
        points = np.asarray(jac.points, dtype=np.float64)
        jac = _Leading(jac)
    else:                                    # residual only: the keypoints without their Jacobians
        jac = None
        points = np.asarray(_keypoints(model, state), dtype=np.float64)
    return stereo_reprojection_batch(points[None], [setup], jac)[0]


class _Leading:
    """A single frame's point Jacobians seen with a leading batch dimension of 1."""

    def __init__(self, jac):
        for name in ("d_root", "d_trans", "d_body_pose", "d_betas"):
            setattr(self, name, np.asarray(getattr(jac, name))[None])


def keypoint_losses(points: np.ndarray, setup: StereoSetup, robust: str, robust_scale: float) -> np.ndarray:
    """(K, N) this term's loss per image and keypoint row at the world keypoints ``points`` (N, 3):
    ``rho`` of the keypoint's whitened 2D offset (:func:`reprojection_whiten`, the factor's own kernel), 0 on
    rows the setup does not use.  Summed over every row it is the factor's error; the label screens
    (:mod:`pedx_graph.solvers.mirror`) compare labellings of one image with it."""
    uv, _ = stereo_pixels(np.asarray(points, dtype=np.float64)[None], [setup])
    meas, inv_sigma = stereo_dense_rows(setup)
    rows = reprojection_whiten(uv, meas[None], inv_sigma[None], [(robust, float(robust_scale))])
    return rows.loss[0]


def make_reprojection_factor(keys: FrameKeys | Sequence[int], model: BodyModelLike,
                             images: Sequence[ImageKeypoints], sigma_px=2.0, sigma_occluded_px=6.0,
                             keypoint_weights: np.ndarray | None = None, robust: str = "gemanmcclure",
                             robust_scale: float = 3.44, min_depth: float = 0.1) -> gtsam.CustomFactor | None:
    """Keypoint reprojection factor over K >= 1 labelled images on ``keys = [root, trans, body_pose, betas]``
    (kind ``stereo_reprojection``).

    Returns ``None`` when no keypoint is labelled (with weight > 0) in any image.  ``sigma_px`` /
    ``sigma_occluded_px`` in pixels (scalar or (N,) per keypoint row); ``robust_scale`` in whitened units.
    """
    setup = build_reprojection_setup(images, sigma_px, sigma_occluded_px, keypoint_weights, min_depth)
    if setup.rows == 0:
        return None
    term = StereoTerm(setup, robust, float(robust_scale))
    cache = getattr(model, "term_cache", None)
    if cache is not None:
        cache.register(KIND, frame_key_list(keys), term)

    def compute(keys, values: gtsam.Values, jacobians: bool):
        return stereo_reprojection_error(model, read_frame_state(values, keys), setup, jacobians)

    def finish(r, blocks):
        return reprojection_residual(r, blocks, term)

    error = cached_callback(KIND, cache, compute, frame_dims, finish)
    return gtsam.CustomFactor(noise_of(term).model(setup.rows), frame_key_list(keys), error)


def make_stereo_reprojection_factor(keys: FrameKeys | Sequence[int], model: BodyModelLike,
                                    measurement: StereoKeypoints, calibration: StereoCalibration, sigma_px=2.0,
                                    sigma_occluded_px=6.0, keypoint_weights: np.ndarray | None = None,
                                    robust: str = "gemanmcclure", robust_scale: float = 3.44,
                                    min_depth: float = 0.1) -> gtsam.CustomFactor | None:
    """:func:`make_reprojection_factor` of one stereo pair's left and right images."""
    return make_reprojection_factor(keys, model, measurement.images(calibration), sigma_px, sigma_occluded_px,
                                    keypoint_weights, robust, robust_scale, min_depth)


def noise_of(spec: StereoTerm) -> RowNoise:
    """Unit noise: the rows are whitened by ``setup.sigmas`` (pixels) and the kernel applied per keypoint and
    image inside the factor (:func:`reprojection_residual`)."""
    return RowNoise(None)


def _factor_by_factor(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The factors ``keys_list`` one at a time: each factor's pixel rows at the cache's last prefetch
    (``cache.factor_terms``) through :func:`reprojection_residual`, as its GTSAM callback finishes them."""
    specs = cache.specs(KIND)
    parts = []
    for keys in keys_list:
        r, blocks = cache.factor_terms(KIND, keys)
        s, _ = reprojection_residual(r, None, specs[keys])
        ne = NormalEquations([keys], np.array([0.5 * float(s @ s)]))
        if jacobians:
            b, rows = reprojection_residual(r, blocks, specs[keys])
            a = np.concatenate(rows, axis=1)
            ne.hess, ne.grad, ne.bb = (a.T @ a)[None], -(a.T @ b)[None], np.array([float(b @ b)])
        parts.append(ne)
    return concatenate(parts)


def assemble(cache, keys_list: list[tuple[int, ...]], jacobians: bool) -> NormalEquations:
    """The reprojection factors ``keys_list`` from the cache's batched pixels, through their keypoints
    (:func:`reprojection_normal_equations`), when its groups hold exactly these factors; else factor by factor."""
    groups = cache.batch(KIND)
    if {k for g in groups for k in g["keys"]} != set(keys_list) or (jacobians and not cache.has_jacobians):
        return _factor_by_factor(cache, keys_list, jacobians)
    parts = []
    for g in groups:
        keys = tuple(g["keys"])

        def rows(keys=keys, k=g["uv"].shape[1]):
            specs = cache.specs(KIND)
            meas, inv_sigma = reprojection_rows([specs[fk].setup for fk in keys], k)
            return meas, inv_sigma, [(specs[fk].robust, float(specs[fk].robust_scale)) for fk in keys]

        whitened = reprojection_whiten(g["uv"], *cache.memo((KIND, keys, g["uv"].shape[1]), rows))
        ne = NormalEquations(list(keys), whitened.loss.sum(axis=(1, 2)))
        if jacobians:
            ne.hess, ne.grad, ne.bb = reprojection_normal_equations(g["d_uv"], g["jac"], whitened)
        parts.append(ne)
    return concatenate(parts)


def evaluate(cache, specs: dict, prefetched: Prefetched) -> None:
    """The term cache's batched evaluation (:attr:`factors.terms.Term.evaluate`): the pixels of every factor's
    frame and camera in one :func:`stereo_pixels` call (their derivatives w.r.t. the keypoints with Jacobians),
    filed as one group with the keypoints' Jacobians of those frames."""
    frame_of = prefetched.frame_of
    fkeys = [fk for fk in specs if fk[0] in frame_of]
    idx = np.array([frame_of[fk[0]] for fk in fkeys], dtype=np.int64)
    jac = prefetched.keypoint_jacobians
    sub = None if jac is None else jacobian_rows(jac, idx)
    points = prefetched.keypoints[idx] if jac is None else sub.points
    setups = [specs[fk].setup for fk in fkeys]
    uv, d_uv = stereo_pixels(points, setups, prefetched.jacobians)
    cache.add_batch(KIND, {"keys": fkeys, "uv": uv, "d_uv": d_uv, "jac": sub, "setups": setups})


def materialise(group: dict, n: int, jacobians: bool) -> tuple[np.ndarray, list[np.ndarray] | None]:
    """Factor ``n`` of a group of :func:`evaluate` (its blocks formed for the whole group on first use)."""
    if jacobians and "full" not in group:
        group["full"] = stereo_blocks(group["d_uv"], group["jac"])
    return stereo_select(group["uv"], group.get("full"), group["setups"][n], n)


TERM = Term(KIND, assemble, evaluate=evaluate, materialise=materialise)
