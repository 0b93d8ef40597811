"""Rectified stereo cameras: calibration of the simulated rig, pixel rays, visibility and silhouettes.

Frames (as in :mod:`pedx_graph.data.types`): ``cam`` = raw left camera (x right, y down, z forward),
``rect`` = rectified left camera, ``rect_p = rect_R_cam @ cam_p``; world = the simulator's internal (sim)
frame (its +z against gravity, LiDAR at the origin) (the written calibration is mapped into the output frame by
:func:`output_calibration`).  A pair is placed either by yaw ``y`` and pitch ``p`` in the sim frame (the
rectified left camera looks along ``(cos p cos y, cos p sin y, sin p)``, its x axis horizontal, to the right
of the viewing direction), or by the raw left camera's optical axis and image-down direction given in the
frame ``CamerasConfig.frame`` (``sim`` or ``output``; see :func:`camera_axes`).  The right camera of a pair
sits at ``rect (b, 0, 0)``:

    uv_left  = project(K @ rect_p),   uv_right = project(K @ (rect_p - (b, 0, 0))),   K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]

which is ``P_rect_00 = K [I | 0]`` and ``P_rect_01 = K [I | (-b, 0, 0)]`` (``P_rect_01[0, 3] = -f b``).

Visibility and silhouettes are ray cast from the camera centres (:class:`~pedx_graph.sim.scene.RayScene`), so
every mesh occludes every other one and a body occludes itself (the far arm behind the torso).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.data.segment_cut import points_in_polygon  # noqa: F401  (the labelling's polygon test)
from pedx_graph.data.types import StereoCalibration
from pedx_graph.sim.config import SimConfig, StereoPairConfig
from pedx_graph.sim.scene import RayScene


def world_R_rect_for(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(3, 3) orientation of the rectified camera: columns = rect x (right), y (down), z (forward) in world."""
    yaw, pitch = np.deg2rad(yaw_deg), np.deg2rad(pitch_deg)
    z_axis = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    x_axis = np.array([np.sin(yaw), -np.cos(yaw), 0.0])
    y_axis = np.cross(z_axis, x_axis)
    return np.stack([x_axis, y_axis, z_axis], axis=1)


def camera_axes(optical_axis, image_down) -> np.ndarray:
    """(3, 3) camera orientation, columns x (right), y (down), z (forward) in the frame of the two vectors.

    ``z`` = the normalised optical axis, ``y`` = ``image_down`` minus its component along ``z``, normalised,
    ``x = y cross z``.
    """
    z_axis = np.asarray(optical_axis, dtype=float)
    z_axis = z_axis / np.linalg.norm(z_axis)
    y_axis = np.asarray(image_down, dtype=float)
    y_axis = y_axis - (y_axis @ z_axis) * z_axis
    y_axis = y_axis / np.linalg.norm(y_axis)
    return np.stack([np.cross(y_axis, z_axis), y_axis, z_axis], axis=1)


def make_calibration(pair: StereoPairConfig, sim_T_frame: np.ndarray | None = None) -> StereoCalibration:
    """The :class:`StereoCalibration` of a simulated pair in the sim frame (ideal rectified rig, see module
    docstring).  ``sim_T_frame`` (4, 4): maps the frame the pair's position and axes are given in
    (``CamerasConfig.frame``) into the sim frame; None = they are given in the sim frame."""
    width, height = pair.image_size
    cx, cy = pair.principal_point if pair.principal_point is not None else (width / 2.0, height / 2.0)
    f = pair.focal_px
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    left_P = np.concatenate([K, np.zeros((3, 1))], axis=1)
    right_P = left_P.copy()
    right_P[0, 3] = -f * pair.baseline_m
    rect_R_cam = Rotation.from_rotvec(np.deg2rad(pair.rectification_deg)).as_matrix()
    frame_T_cam = np.eye(4)
    if pair.optical_axis is None:
        frame_T_cam[:3, :3] = world_R_rect_for(pair.yaw_deg, pair.pitch_deg) @ rect_R_cam
    else:
        frame_T_cam[:3, :3] = camera_axes(pair.optical_axis, pair.image_down)
    frame_T_cam[:3, 3] = pair.left_camera_xyz
    world_T_cam = frame_T_cam if sim_T_frame is None else np.asarray(sim_T_frame, dtype=float) @ frame_T_cam
    return StereoCalibration(name=pair.name, left_P_rect=left_P, right_P_rect=right_P, rect_R_cam=rect_R_cam,
                             world_T_cam=world_T_cam, image_size=(int(width), int(height)))


def rig_calibrations(config: SimConfig) -> dict[str, StereoCalibration]:
    """The calibrations of the config's pairs in the sim frame, by pair name (forward slot first)."""
    sim_T_frame = None
    if config.cameras.frame == "output":
        sim_T_frame = np.linalg.inv(config.output_frame.output_T_sim())
    return {pair.name: make_calibration(pair, sim_T_frame) for pair in config.cameras.pairs()}


def output_calibration(calib: StereoCalibration, output_T_sim: np.ndarray) -> StereoCalibration:
    """``calib`` (sim frame) with its placement mapped into the output frame: ``output_T_sim @ world_T_cam``."""
    if np.array_equal(output_T_sim, np.eye(4)):
        return calib
    return dataclasses.replace(calib, world_T_cam=np.asarray(output_T_sim, dtype=float) @ calib.world_T_cam)


def sim_yaw_deg(calib: StereoCalibration) -> float:
    """Bearing (degrees about the sim frame's z, 0 = +x) of the rectified left camera's optical axis."""
    axis = calib.world_R_rect[:, 2]
    return float(np.degrees(np.arctan2(axis[1], axis[0])))


@dataclass(frozen=True)
class CameraView:
    """One rectified camera of a pair, as needed for ray casting: ``side`` is ``"left"`` or ``"right"``."""

    calib: StereoCalibration
    side: str
    camera: str
    """Camera name (e.g. ``ylw79D0``)."""

    @cached_property
    def world_R_rect(self) -> np.ndarray:
        """(3, 3) orientation of the rectified left frame in the world."""
        return self.calib.world_R_rect

    @cached_property
    def _rect_T_world(self) -> np.ndarray:
        return self.calib.rect_T_world

    @cached_property
    def world_center(self) -> np.ndarray:
        """(3,) optical centre in the world frame."""
        return self.calib.camera_centre(self.side)

    @property
    def P_rect(self) -> np.ndarray:
        return self.calib.left_P_rect if self.side == "left" else self.calib.right_P_rect

    def project(self, world_p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(..., 3) world points -> ((..., 2) pixels, (...,) depth along the optical axis in metres)."""
        rect_T_world = self._rect_T_world
        rect_p = np.asarray(world_p, dtype=float) @ rect_T_world[:3, :3].T + rect_T_world[:3, 3]
        hom = rect_p @ self.P_rect[:, :3].T + self.P_rect[:, 3]
        depth = rect_p[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = hom[..., :2] / hom[..., 2:3]
        return uv, depth

    def pixel_rays(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) pixels -> (N, 3) unit world directions of the rays through them."""
        P = self.P_rect
        f, cx, cy = P[0, 0], P[0, 2], P[1, 2]
        rect_d = np.stack([(uv[:, 0] - cx) / f, (uv[:, 1] - cy) / P[1, 1], np.ones(len(uv))], axis=-1)
        world_d = rect_d @ self.world_R_rect.T
        return world_d / np.linalg.norm(world_d, axis=-1, keepdims=True)

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        width, height = self.calib.image_size
        return (uv[..., 0] >= 0) & (uv[..., 0] < width) & (uv[..., 1] >= 0) & (uv[..., 1] < height)


def camera_views(calib: StereoCalibration) -> list[CameraView]:
    """The left and right :class:`CameraView` of a pair."""
    left, right = calib.name.split("-")
    return [CameraView(calib, "left", left), CameraView(calib, "right", right)]


def point_visibility(ray_scene: RayScene, view: CameraView, world_p: np.ndarray,
                     tolerance_m: float) -> np.ndarray:
    """(N,) bool: no surface lies more than ``tolerance_m`` in front of each (N, 3) point seen from ``view``.

    A joint centre sits inside its limb, so the first hit on the ray to a visible joint is the limb's own
    skin, about a limb radius in front of it: ``tolerance_m`` must exceed that radius.
    """
    centre = view.world_center
    delta = np.asarray(world_p, dtype=float) - centre
    dist = np.linalg.norm(delta, axis=-1)
    hit, _ = ray_scene.cast(np.broadcast_to(centre, delta.shape), delta / dist[:, None])
    return hit >= dist - tolerance_m


@dataclass
class Silhouette:
    """The visible part of one object in one image."""

    mask: np.ndarray
    """(H, W) bool grid of cells where the first surface is the object."""
    origin_px: tuple[float, float]
    """Image position of the grid's top-left corner (pixels)."""
    cell_px: float
    """Cell size in pixels."""

    @property
    def area_px(self) -> float:
        """Visible area in pixels^2."""
        return float(self.mask.sum()) * self.cell_px ** 2


def visible_silhouette(ray_scene: RayScene, view: CameraView, object_id: int, world_vertices: np.ndarray,
                       max_cells: int) -> Silhouette | None:
    """Ray cast the visible mask of ``object_id`` over the image box of its (V, 3) vertices.

    The box (clipped to the image) is sampled at pixel-centred cells of size
    ``ceil(max(box_w, box_h) / max_cells)`` px (>= 1).  Returns None when the object is behind the camera
    or outside the image.  The box comes from every 4th vertex of large meshes, widened by 3 % and one cell.
    """
    uv, depth = view.project(world_vertices[::4] if len(world_vertices) > 1000 else world_vertices)
    front = depth > 0.1
    if not front.any():
        return None
    uv = uv[front]
    width, height = view.calib.image_size
    x0, y0 = np.floor(uv.min(axis=0))
    x1, y1 = np.ceil(uv.max(axis=0))
    span = max(x1 - x0, y1 - y0, 1.0)
    cell = float(max(1, int(np.ceil(span / max_cells))))
    widen = cell + 0.03 * span
    x0, y0 = max(np.floor(x0 - widen), 0.0), max(np.floor(y0 - widen), 0.0)
    x1, y1 = min(x1 + widen, float(width)), min(y1 + widen, float(height))
    if x1 <= x0 or y1 <= y0:
        return None
    n_cols, n_rows = int(np.ceil((x1 - x0) / cell)), int(np.ceil((y1 - y0) / cell))
    cols, rows = np.meshgrid(np.arange(n_cols), np.arange(n_rows))
    uv_grid = np.stack([x0 + (cols.ravel() + 0.5) * cell, y0 + (rows.ravel() + 0.5) * cell], axis=-1)
    _, hit_id = ray_scene.cast(view.world_center, view.pixel_rays(uv_grid))
    mask = (hit_id == object_id).reshape(n_rows, n_cols)
    return Silhouette(mask=mask, origin_px=(float(x0), float(y0)), cell_px=cell)


def silhouette_polygon(sil: Silhouette, epsilon_px: float) -> np.ndarray | None:
    """(K, 2) pixel polygon around the largest connected component of a silhouette, or None if empty.

    The cell mask is upsampled (bilinear, threshold 0.5) to cells of <= 2 px before tracing so that the
    outline is not biased half a cell inwards; the outline is simplified with Douglas-Peucker
    (``epsilon_px``).
    """
    if not sil.mask.any():
        return None
    n_comp, labels, stats, _ = cv2.connectedComponentsWithStats(sil.mask.astype(np.uint8), connectivity=8)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    comp = (labels == largest).astype(np.float32)
    factor = max(1, int(np.ceil(sil.cell_px / 2.0)))
    pad = 1
    comp = np.pad(comp, pad)
    if factor > 1:
        comp = cv2.resize(comp, (comp.shape[1] * factor, comp.shape[0] * factor), interpolation=cv2.INTER_LINEAR)
    binary = (comp >= 0.5).astype(np.uint8)
    contours, _ = cv2.findContours(binary, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    contour = max(contours, key=cv2.contourArea)
    sub_px = sil.cell_px / factor
    contour = cv2.approxPolyDP(contour, max(epsilon_px / sub_px, 0.5), closed=True).reshape(-1, 2)
    if len(contour) < 3:
        return None
    x0, y0 = sil.origin_px
    # sub-cell j (of the padded, upsampled grid) has its centre at image x0 + (j + 0.5) * sub_px - pad * cell
    return np.stack([x0 + (contour[:, 0] + 0.5) * sub_px - pad * sil.cell_px,
                     y0 + (contour[:, 1] + 0.5) * sub_px - pad * sil.cell_px], axis=-1)
