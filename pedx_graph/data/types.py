"""In-memory types shared by the reader, the simulator and the estimator.

Data flows one way: dataset -> :class:`Track` -> graph -> solver -> result -> report.

Frames
------
* ``world``: the LiDAR (range) frame of the capture vehicle, metres. Every 3D quantity of a
  :class:`Track` and of a result is in this frame (one world frame per sequence).  No axis of it is assumed
  to point up (real PedX: z points *down*): up, ground and headings come from the track's
  :class:`~pedx_graph.data.ground.GroundFrame`, derived from the data.
* ``cam``: the left (reference) camera of a stereo pair before rectification, x right, y down, z forward.
* ``rect``: the rectified left camera frame, ``rect_p = R_rect_00 @ cam_p``.
* image coordinates are pixels of the rectified images, ``uv = project(P_rect @ [rect_p; 1])``.

KITTI-style calibration: ``P_rect_00`` / ``P_rect_01`` are the 3x4 projections of the rectified left
and right cameras (the right one carries ``-f * baseline`` in ``[0, 3]``), both applied to points in
the rectified *left* frame.  ``world_T_cam`` is the 4x4 rigid transform mapping left-camera points into
the LiDAR frame (the file's ``R``/``T`` or ``Tr``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from pedx_graph.data.ground import GroundFrame, ground_from_calibrations
from pedx_graph.keypoints import EVAL_JOINTS, PEDX_KEYPOINTS  # noqa: F401  (re-exported)


class DataFormatError(ValueError):
    """A release file (or one field of it) is malformed; the message names the file and the field."""

    def __init__(self, path, field: str | None, message: str):
        self.path = str(path)
        self.field = field
        where = f"{self.path}: field '{field}'" if field else self.path
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True)
class RawCamera:
    """One camera's raw (distorted) image model and its rectification, from the KITTI raw keys
    ``K_0x``, ``D_0x``, ``R_rect_0x``, ``P_rect_0x`` (x = 0 left, 1 right) of ``calib_cam_to_cam``."""

    raw_K: np.ndarray
    """(3, 3) intrinsic matrix of the raw image, pixels."""
    raw_D: np.ndarray
    """(N,) OpenCV radial-tangential distortion ``k1 k2 p1 p2 [k3 ...]`` (N = 4, 5, 8, 12 or 14)."""
    rect_R_cam: np.ndarray
    """(3, 3) rotation: this camera's frame -> its rectified frame (``R_rect_0x``)."""
    P_rect: np.ndarray
    """(3, 4) rectified projection of this camera (``P_rect_0x``); its left 3x3 maps rectified rays to pixels."""
    image_size: tuple[int, int] | None = None
    """(width, height) of the raw image in pixels (``S_0x``), None when the file does not give it."""


@dataclass(frozen=True)
class StereoCalibration:
    """Calibration of one rectified stereo pair and its placement in the LiDAR (world) frame."""

    name: str
    """Pair name as in the release, ``"<left>-<right>"`` (e.g. ``"ylw79D0-red707B"``)."""
    left_P_rect: np.ndarray
    """(3, 4) projection of the rectified left camera, pixels per metre, applied to ``rect`` points."""
    right_P_rect: np.ndarray
    """(3, 4) projection of the rectified right camera, applied to points in the rectified *left* frame."""
    rect_R_cam: np.ndarray
    """(3, 3) rectifying rotation of the left camera (``R_rect_00``)."""
    world_T_cam: np.ndarray
    """(4, 4) rigid transform: left camera frame -> LiDAR (world) frame."""
    image_size: tuple[int, int]
    """(width, height) of the rectified images in pixels."""
    left_raw: RawCamera | None = None
    """The left camera's raw image model (``K_00``, ``D_00``), None when the file has no raw keys."""
    right_raw: RawCamera | None = None
    """The right camera's raw image model (``K_01``, ``D_01``, ``R_rect_01``), None when absent."""

    @property
    def focal_px(self) -> float:
        """Focal length of the rectified pair in pixels."""
        return float(self.left_P_rect[0, 0])

    @property
    def baseline_m(self) -> float:
        """Stereo baseline in metres, ``-P_rect_01[0, 3] / P_rect_01[0, 0]`` (relative to the left)."""
        return float(-(self.right_P_rect[0, 3] - self.left_P_rect[0, 3]) / self.right_P_rect[0, 0])

    @cached_property
    def rect_T_world(self) -> np.ndarray:
        """(4, 4) transform: LiDAR (world) frame -> rectified left camera frame (computed once, read-only)."""
        rect_T_cam = np.eye(4)
        rect_T_cam[:3, :3] = self.rect_R_cam
        out = rect_T_cam @ np.linalg.inv(self.world_T_cam)
        out.setflags(write=False)
        return out

    def world_to_rect(self, world_p: np.ndarray) -> np.ndarray:
        """Map (..., 3) world points into the rectified left camera frame."""
        rect_T_world = self.rect_T_world
        return world_p @ rect_T_world[:3, :3].T + rect_T_world[:3, 3]

    @cached_property
    def world_R_rect(self) -> np.ndarray:
        """(3, 3) orientation of the rectified left frame in the world: its columns are the rectified x (image
        right), y (image down) and z (optical axis) directions in world coordinates (computed once,
        read-only)."""
        out = np.asarray(self.world_T_cam, dtype=float)[:3, :3] @ np.asarray(self.rect_R_cam, dtype=float).T
        out.setflags(write=False)
        return out

    def rect_to_world(self, rect_p: np.ndarray) -> np.ndarray:
        """Map (..., 3) points of the rectified left camera frame into the world (the inverse of
        :meth:`world_to_rect`; the rectified frame shares the left camera's origin)."""
        world_t = np.asarray(self.world_T_cam, dtype=float)[:3, 3]
        return np.asarray(rect_p, dtype=float) @ self.world_R_rect.T + world_t

    def camera_centre(self, side: str) -> np.ndarray:
        """(3,) optical centre of the pair's ``side`` (``"left"`` / ``"right"``) camera in the world frame: the
        right one is the left one moved by the baseline along the rectified x axis."""
        centre = np.asarray(self.world_T_cam, dtype=float)[:3, 3].copy()
        if side == "right":
            centre = centre + self.world_R_rect[:, 0] * self.baseline_m
        elif side != "left":
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        return centre

    def project(self, world_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (..., 3) world points into the left and right rectified images: two (..., 2) arrays.

        Points behind the camera give non-finite or meaningless pixels; check depth with
        :meth:`world_to_rect` when it matters.
        """
        rect_p = self.world_to_rect(np.asarray(world_p, dtype=float))
        hom = np.concatenate([rect_p, np.ones(rect_p.shape[:-1] + (1,))], axis=-1)
        left = hom @ self.left_P_rect.T
        right = hom @ self.right_P_rect.T
        return left[..., :2] / left[..., 2:3], right[..., :2] / right[..., 2:3]


@dataclass
class View2D:
    """2D labels of one pedestrian in one rectified image."""

    keypoints: np.ndarray
    """(18, 2) pixel coordinates in PEDX_KEYPOINTS order; NaN where the joint is not labelled."""
    visible: np.ndarray
    """(18,) bool, the annotator's ``visible`` flag (False also where not labelled)."""
    polygon: np.ndarray | None = None
    """(K, 2) pixel polygon of the instance silhouette, or None when the label has none."""
    keypoint_set: str = "pedx18"
    """Which keypoints :attr:`keypoints` holds, in that set's order (``pedx18``: the 18 PedX keypoints;
    ``coco17``, ``body25``, ...: a detector's, see ``pedx_graph/body/data/keypoint_sets``).  With another
    set, ``keypoints``, ``visible`` and :attr:`sigma_px` have that set's length instead of 18.  A detector
    track laid out for the fit (``pedx_graph.detections.fit_layout``) has ``pedx18`` views of 18 + E rows:
    the 18 PedX rows, then the set's keypoints without a PedX row (:meth:`pedx_rows`: the first 18)."""
    sigma_px: np.ndarray | None = None
    """(K,) per-keypoint pixel noise (per axis) from the label file (a detector's confidence turned into
    noise by ``pedx-graph import``), NaN where the file gives none; None: the config's noise for all."""
    confidence: np.ndarray | None = None
    """(K,) the detector's confidence per keypoint as imported (kept for reports), or None."""

    @property
    def labelled(self) -> np.ndarray:
        """(18,) bool (K in another keypoint set): the joint has a 2D position."""
        return np.all(np.isfinite(self.keypoints), axis=-1)

    def pedx_rows(self) -> "View2D":
        """This view's 18 PedX rows (a fit layout's first 18, :attr:`keypoint_set`); itself when it has 18
        rows (or is in another set)."""
        count = len(PEDX_KEYPOINTS)
        if self.keypoint_set != "pedx18" or len(self.keypoints) == count:
            return self

        def cut(arr):
            return None if arr is None else arr[:count]
        return dataclasses.replace(self, keypoints=self.keypoints[:count], visible=self.visible[:count],
                                   sigma_px=cut(self.sigma_px), confidence=cut(self.confidence))


@dataclass
class TrackFrame:
    """Everything observed of one pedestrian at one synchronised stereo + LiDAR sample.

    ``pair`` / ``left`` / ``right`` are the *primary* stereo pair (the one with the most labelled keypoints);
    the labels of any other pair that saw the pedestrian at this frame are in :attr:`other_views`.
    :meth:`labelled_views` lists them all.  A frame labelled in one camera only has one of ``left`` /
    ``right`` None.
    """

    frame: int
    """Frame number as in the release file names."""
    timestamp: float
    """Seconds (from the timestamps file, or ``frame / fps`` when it is absent)."""
    pair: str
    """Name of the primary stereo pair (key into :attr:`Track.calibrations`) that saw this instance."""
    left: View2D | None
    """Labels in the primary pair's rectified left image, or None when the instance is not labelled there."""
    right: View2D | None
    """Labels in the primary pair's rectified right image, or None."""
    world_lidar_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    """(M, 3) LiDAR points assigned to this instance (segment PLY), world frame, metres."""
    other_views: dict[str, tuple[View2D | None, View2D | None]] = field(default_factory=dict)
    """Labels of the same instance at this frame in other stereo pairs: pair name (a key into
    :attr:`Track.calibrations`, never :attr:`pair`) -> (left, right) views, either None when not labelled
    there.  Empty when only the primary pair saw it."""

    def pedx_rows(self) -> "TrackFrame":
        """This frame with every view cut to its 18 PedX rows (:meth:`View2D.pedx_rows`): the steps that look
        keypoints up by PedX name or row (initialisation, triangulation, body-size depth); itself when every
        view has 18 rows."""

        def cut(view):
            return None if view is None else view.pedx_rows()
        views = [self.left, self.right] + [v for pair in self.other_views.values() for v in pair]
        if all(v is None or v.pedx_rows() is v for v in views):
            return self
        return dataclasses.replace(self, left=cut(self.left), right=cut(self.right),
                                   other_views={p: (cut(a), cut(b)) for p, (a, b) in self.other_views.items()})

    @property
    def pairs(self) -> list[str]:
        """The primary pair, then the other pairs in name order."""
        return [self.pair] + sorted(p for p in self.other_views if p != self.pair)

    def labelled_views(self, all_pairs: bool = True) -> list[tuple[str, str, View2D]]:
        """``(pair name, side, view)`` of every image labelling the instance at this frame (side ``"left"`` or
        ``"right"``): the primary pair's left and right first, then the other pairs' (name order, left
        before right); views that are None are left out.  ``all_pairs=False``: the primary pair only."""
        out = []
        for pair in (self.pairs if all_pairs else [self.pair]):
            left, right = (self.left, self.right) if pair == self.pair else self.other_views[pair]
            for side, view in (("left", left), ("right", right)):
                if view is not None:
                    out.append((pair, side, view))
        return out


#: :attr:`Track.identity_review`'s ``other`` for a stretch where the track came close to detections no track
#: holds (:mod:`pedx_graph.detections.review`).
UNTRACKED = "untracked"


@dataclass
class Track:
    """One pedestrian (one ``tracking_id``) over a sequence: frames sorted by frame number."""

    sequence: str
    """Sequence name, e.g. ``"20171207T2024"``."""
    tracking_id: str
    """The release's 32-hex tracking id (any string for simulated data)."""
    frames: list[TrackFrame]
    """Observed frames in increasing frame order (gaps allowed)."""
    calibrations: dict[str, StereoCalibration]
    """Stereo pairs by name; every ``TrackFrame.pair`` and every key of ``TrackFrame.other_views`` is a key."""
    ground: GroundFrame | None = None
    """The sequence's up axis, ground plane and viewpoint (the reader derives it per sequence from the
    calibration and point clouds); None here = derived from ``calibrations`` alone on construction."""
    identity_review: list[dict] = field(default_factory=list)
    """Stretches of frames where ``pedx-graph import`` found this track close to another, so that who is who
    is worth a check there: ``{"other": track id, "first_frame", "last_frame"}``, ``other`` being
    :data:`UNTRACKED` where it was close to detections no track holds (from the dataset's
    ``import_summary.json``, :mod:`pedx_graph.detections.review`); empty for hand labels."""

    def __post_init__(self) -> None:
        if self.ground is None and self.calibrations:
            self.ground = ground_from_calibrations(self.calibrations, self.sequence)

    def __len__(self) -> int:
        return len(self.frames)

    @property
    def keypoint_set(self) -> str:
        """The keypoint set of the track's 2D labels (the reader keeps one set per track): ``pedx18`` unless
        the labels were imported from a detector."""
        for fr in self.frames:
            for _, _, view in fr.labelled_views():
                return view.keypoint_set
        return "pedx18"


@dataclass
class SmplLabel:
    """One SMPL label as in ``labels/3d/smpl``: parameters in the LiDAR (world) frame.

    The body model is evaluated as ``BodyModel.forward(pose, betas, trans)``, i.e. vertices in the
    world frame (``pose[:3]`` is the world orientation of the root).
    """

    sequence: str
    frame: int
    tracking_id: str
    betas: np.ndarray
    """(10,) shape coefficients."""
    pose: np.ndarray
    """(72,) axis-angle, root first."""
    trans: np.ndarray
    """(3,) metres, added after skinning (smplx convention)."""
    extra: dict = field(default_factory=dict)
    """Our own fields (3D keypoints, covariances, errors, ...), JSON-serialisable."""
