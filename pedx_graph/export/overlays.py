"""Fitted meshes and keypoints with their uncertainty drawn over one camera image (OpenCV).

:func:`draw_overlay` draws, for every person of a frame seen by the camera: the fitted mesh, shaded and
blended over the image (:func:`~pedx_graph.export.raster.paint_meshes`: painter's order across people), the
outline of its silhouette, the fitted keypoints and skeleton with the 95 % ellipse of each keypoint's pixel
covariance ``J Sigma J^T`` (``Sigma``: the keypoint's 3x3 marginal covariance ``cov_keypoints_3d``, ``J``: the
camera's 2x3 Jacobian, :meth:`~pedx_graph.export.camera.Camera.image_covariance`), and the 2D labels of the
dataset (``+`` visible, ``x`` occluded, the polygon).  Without an image the canvas is blank grey at the
calibration's size (:func:`blank_canvas`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedx_graph.data.types import View2D
from pedx_graph.export.raster import PaintedMesh, paint_meshes, silhouette_mask
from pedx_graph.keypoints import PEDX_KEYPOINTS

#: chi-square quantile of 2 degrees of freedom at 0.95: the 95 % ellipse is ``x^T S^-1 x = CHI2_2_95``.
CHI2_2_95 = 5.991464547107979
#: Skeleton drawn between the fitted keypoints (PEDX_KEYPOINTS names).
SKELETON = (("head", "neck"), ("neck", "lsho"), ("neck", "rsho"), ("lsho", "lelb"), ("lelb", "lwri"),
            ("rsho", "relb"), ("relb", "rwri"), ("lsho", "lhip"), ("rsho", "rhip"), ("lhip", "rhip"),
            ("lhip", "lknee"), ("lknee", "lankl"), ("rhip", "rknee"), ("rknee", "rankl"))
#: Blank canvas grey level (no image file).
BLANK_GREY = 96
#: Weight of the painted meshes over the image.
MESH_ALPHA = 0.55
_IDX = {name: i for i, name in enumerate(PEDX_KEYPOINTS)}


@dataclass
class PersonInView:
    """One fitted person to draw in one camera image."""

    tracking_id: str
    colour_bgr: tuple[int, int, int]
    """Colour of this track (mesh, outline, keypoints)."""
    world_vertices: np.ndarray
    """(V, 3) fitted mesh vertices, LiDAR frame, metres."""
    faces: np.ndarray
    """(F, 3) faces, counter-clockwise seen from outside."""
    world_keypoints: np.ndarray | None = None
    """(18, 3) fitted keypoints, LiDAR frame (``keypoints_3d``), or None."""
    world_keypoint_cov: np.ndarray | None = None
    """(18, 3, 3) their marginal covariances, m^2 (``cov_keypoints_3d``), or None."""
    label: View2D | None = None
    """The dataset's 2D label of this person in this image, or None."""


def blank_canvas(image_size: tuple[int, int], scale: float = 1.0) -> np.ndarray:
    """(H, W, 3) grey BGR canvas of the calibration's ``image_size`` (width, height) times ``scale``."""
    width, height = (max(1, int(round(v * scale))) for v in image_size)
    return np.full((height, width, 3), BLANK_GREY, np.uint8)


def line_width(image: np.ndarray) -> int:
    """Line thickness in pixels for an image of this size (1 px per 1,200 px of width, at least 1)."""
    return max(1, int(round(image.shape[1] / 1200)))


def ellipse_axes(cov2: np.ndarray, chi2: float = CHI2_2_95) -> tuple[tuple[float, float], float] | None:
    """Semi-axes (px) and angle (degrees, OpenCV's, from the image x axis) of the ellipse ``x^T C^-1 x = chi2``
    of a 2x2 pixel covariance, or None when it is not finite."""
    if not np.all(np.isfinite(cov2)):
        return None
    w, v = np.linalg.eigh(0.5 * (cov2 + cov2.T))
    w = np.clip(w, 0.0, None)
    angle = float(np.degrees(np.arctan2(v[1, 1], v[0, 1])))
    return (float(np.sqrt(chi2 * w[1])), float(np.sqrt(chi2 * w[0]))), angle


def _pt(uv: np.ndarray, shift: int = 4) -> tuple[int, int]:
    return int(round(uv[0] * (1 << shift))), int(round(uv[1] * (1 << shift)))


def draw_label(image: np.ndarray, label: View2D, colour: tuple[int, int, int], scale: float, width: int,
               size: int | None = None) -> None:
    """The 2D label: polygon (thin, in the track's colour), ``+`` on visible and ``x`` on occluded clicks
    (``size`` pixels across; default from the line width)."""
    import cv2

    from pedx_graph.export.camera import to_image_pixels

    if label.polygon is not None and len(label.polygon) >= 3:
        poly = np.round(to_image_pixels(np.asarray(label.polygon, float), scale) * 16).astype(np.int32)
        cv2.polylines(image, [poly], True, colour, width, cv2.LINE_AA, 4)
    kp = to_image_pixels(np.asarray(label.keypoints, float), scale)
    size = size or 6 * width + 4
    for i in np.flatnonzero(label.labelled):
        marker = cv2.MARKER_CROSS if label.visible[i] else cv2.MARKER_TILTED_CROSS
        centre = tuple(int(round(c)) for c in kp[i])
        cv2.drawMarker(image, centre, (0, 0, 0), marker, size, width + 2, cv2.LINE_AA)
        cv2.drawMarker(image, centre, (255, 255, 255) if label.visible[i] else (60, 60, 255), marker, size, width,
                       cv2.LINE_AA)


def draw_overlay(image: np.ndarray, camera, people: list[PersonInView], scale: float = 1.0,
                 title: str = "") -> np.ndarray:
    """A new image: ``image`` with ``people`` drawn as in the module docstring; ``scale`` = the image's width over
    the calibration's."""
    import cv2

    width = line_width(image)
    layer = image.copy()
    paint_meshes(layer, camera, [PaintedMesh(p.world_vertices, p.faces, p.colour_bgr) for p in people], scale)
    out = cv2.addWeighted(image, 1.0 - MESH_ALPHA, layer, MESH_ALPHA, 0.0)
    size = (image.shape[1], image.shape[0])
    for p in people:
        mask = silhouette_mask(camera, PaintedMesh(p.world_vertices, p.faces, p.colour_bgr), size, scale)
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(out, contours, -1, p.colour_bgr, width, cv2.LINE_AA)
    for p in people:
        box = person_box(camera, p.world_vertices, scale)
        tall = float(box[1, 1] - box[0, 1]) if box is not None else 1e9     # person height in pixels
        marker = int(np.clip(tall / 12, 4, 6 * width + 4))
        dot = int(np.clip(16 * tall / 80, 16, 16 * (width + 1)))
        if p.label is not None:
            draw_label(out, p.label, p.colour_bgr, scale, max(1, min(width, marker // 4)), marker)
        if p.world_keypoints is None:
            continue
        uv, depth = camera.project(p.world_keypoints, scale)
        front = (depth > 0.1) & np.all(np.isfinite(uv), axis=1)
        for a, b in SKELETON:
            i, j = _IDX[a], _IDX[b]
            if front[i] and front[j]:
                cv2.line(out, _pt(uv[i]), _pt(uv[j]), p.colour_bgr, width, cv2.LINE_AA, 4)
        cov2 = (camera.image_covariance(p.world_keypoints, p.world_keypoint_cov, scale)
                if p.world_keypoint_cov is not None else None)
        for i in np.flatnonzero(front):
            cv2.circle(out, _pt(uv[i]), dot + 16, (0, 0, 0), -1, cv2.LINE_AA, 4)
            cv2.circle(out, _pt(uv[i]), dot, p.colour_bgr, -1, cv2.LINE_AA, 4)
            if cov2 is None:
                continue
            axes = ellipse_axes(cov2[i])
            if axes is None:
                continue
            (major, minor), angle = axes
            cv2.ellipse(out, _pt(uv[i]), (int(round(major * 16)), int(round(minor * 16))), angle, 0, 360,
                        (255, 255, 255), width, cv2.LINE_AA, 4)
    if title:
        font_scale = 0.5 * max(1.0, image.shape[1] / 1200)
        cv2.putText(out, title, (8 * width, int(24 * font_scale / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, font_scale,
                    (0, 0, 0), width + 2, cv2.LINE_AA)
        cv2.putText(out, title, (8 * width, int(24 * font_scale / 0.5)), cv2.FONT_HERSHEY_SIMPLEX, font_scale,
                    (255, 255, 255), width, cv2.LINE_AA)
    return out


def person_box(camera, world_vertices: np.ndarray, scale: float = 1.0) -> np.ndarray | None:
    """(2, 2) pixel box ``[[u0, v0], [u1, v1]]`` of the mesh's projection, or None when behind the camera."""
    uv, depth = camera.project(world_vertices, scale)
    uv = uv[depth > 0.1]
    if not len(uv):
        return None
    return np.stack([uv.min(axis=0), uv.max(axis=0)])
