"""A track seen from above: positions and translation-covariance ellipses in the level frame of the ground.

The level frame is the sequence's :class:`~pedx_graph.data.ground.GroundFrame` (derived from the data: no
axis of the LiDAR frame is taken as up): x along the reference forward direction, y to its left, z along the
derived up axis, origin at the sensor.  :func:`render_top_view` draws on an OpenCV canvas a 1 m (or 5 m) grid,
the fitted ``trans`` of every frame joined in time order, the 95 % ellipse of each frame's horizontal position
covariance (the 2x2 level-plane block of ``level_R_world cov_trans world_R_level``), the footprint of one
frame's mesh (``highlight``), the direction to the sensor and a scale bar.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedx_graph.data.ground import GroundFrame
from pedx_graph.export.overlays import CHI2_2_95, ellipse_axes

#: Side of the square top-view canvas, pixels.
CANVAS_PX = 720
#: Margin around the track, metres.
MARGIN_M = 1.5


@dataclass
class TrackPath:
    """What the top view shows of one track (LiDAR frame inputs)."""

    sequence: str
    tracking_id: str
    frames: list[int]
    """Frame numbers, increasing."""
    world_trans: np.ndarray
    """(T, 3) fitted ``trans`` per frame, metres."""
    world_trans_cov: np.ndarray | None
    """(T, 3, 3) marginal covariance of ``trans`` (``cov_trans``), m^2; NaN rows where absent; or None."""
    colour_bgr: tuple[int, int, int] = (40, 90, 230)


def level_covariance(ground: GroundFrame, world_cov: np.ndarray) -> np.ndarray:
    """(..., 2, 2) horizontal block of a (..., 3, 3) world covariance expressed in the level frame."""
    level_R_world = ground.world_R_level.T
    level = level_R_world @ np.asarray(world_cov, float) @ level_R_world.T
    return level[..., :2, :2]


class _Canvas:
    """Level-plane metres -> pixels of a square canvas (x up the image, y to the left: a map seen from above
    with the forward direction up)."""

    def __init__(self, level_xy: np.ndarray, size_px: int, margin_m: float):
        lo, hi = level_xy.min(axis=0) - margin_m, level_xy.max(axis=0) + margin_m
        span = float(max(hi - lo))
        self.centre = 0.5 * (lo + hi)
        self.px_per_m = size_px / span
        self.size = size_px
        self.span = span

    def px(self, level_xy: np.ndarray) -> np.ndarray:
        d = (np.asarray(level_xy, float) - self.centre) * self.px_per_m
        return np.stack([self.size / 2 - d[..., 1], self.size / 2 - d[..., 0]], axis=-1)


def render_top_view(path: TrackPath, ground: GroundFrame, highlight: int | None = None,
                    footprint_world: np.ndarray | None = None, size_px: int = CANVAS_PX) -> np.ndarray:
    """(size, size, 3) BGR top view of ``path`` (module docstring); ``highlight``: index of the frame marked,
    ``footprint_world``: (V, 3) that frame's mesh vertices, drawn as their convex hull."""
    import cv2

    level = ground.to_level(path.world_trans)
    canvas = _Canvas(level[:, :2], size_px, MARGIN_M)
    image = np.full((size_px, size_px, 3), 250, np.uint8)
    step = 1.0 if canvas.span <= 15 else 5.0
    for axis in (0, 1):                     # level x = const: an image row; level y = const: a column
        first = np.floor((canvas.centre[axis] - canvas.span / 2) / step) * step
        for k in range(int(canvas.span / step) + 2):
            point = canvas.centre.copy()
            point[axis] = first + k * step
            pixel = int(round(canvas.px(point)[1 - axis]))
            ends = ((0, pixel), (size_px, pixel)) if axis == 0 else ((pixel, 0), (pixel, size_px))
            cv2.line(image, ends[0], ends[1], (225, 225, 225), 1)
    colour = path.colour_bgr
    if footprint_world is not None and highlight is not None:
        foot = canvas.px(ground.to_level(footprint_world)[:, :2]).astype(np.float32)
        hull = cv2.convexHull(foot).round().astype(np.int32)
        cv2.fillConvexPoly(image, hull, tuple(int(0.35 * c + 0.65 * 250) for c in colour), cv2.LINE_AA)
    pts = canvas.px(level[:, :2])
    cv2.polylines(image, [np.round(pts * 16).astype(np.int32)], False, colour, 2, cv2.LINE_AA, 4)
    if path.world_trans_cov is not None:
        cov2 = level_covariance(ground, path.world_trans_cov) * canvas.px_per_m ** 2
        for centre, c in zip(pts, cov2):
            axes = ellipse_axes(c[::-1, ::-1], CHI2_2_95)      # (x, y) level -> (v-down, u-left) swap
            if axes is None:
                continue
            (major, minor), angle = axes
            cv2.ellipse(image, tuple(np.round(centre * 16).astype(int)), (int(round(16 * major)),
                        int(round(16 * minor))), angle, 0, 360, (90, 90, 90), 1, cv2.LINE_AA, 4)
    for centre in pts:
        cv2.circle(image, tuple(np.round(centre * 16).astype(int)), 32, colour, -1, cv2.LINE_AA, 4)
    if highlight is not None:
        cv2.circle(image, tuple(np.round(pts[highlight] * 16).astype(int)), 96, (0, 0, 0), 2, cv2.LINE_AA, 4)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for index, name in ((0, "start"), (len(pts) - 1, "end")):
        anchor = tuple(np.round(pts[index]).astype(int) + np.array([6, -6]))
        cv2.putText(image, f"{name} {path.frames[index]}", anchor, font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    sensor = canvas.px(np.zeros(2))
    direction = sensor - canvas.px(canvas.centre)
    if np.linalg.norm(direction) > size_px / 2:                    # the sensor is off the canvas: an arrow
        tip = size_px / 2 + 0.45 * size_px * direction / np.linalg.norm(direction)
        tail = size_px / 2 + 0.33 * size_px * direction / np.linalg.norm(direction)
        cv2.arrowedLine(image, tuple(np.round(tail).astype(int)), tuple(np.round(tip).astype(int)), (0, 0, 0), 1,
                        cv2.LINE_AA, 0, 0.25)
        cv2.putText(image, "sensor", tuple(np.round(tail).astype(int) + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    else:
        cv2.drawMarker(image, tuple(np.round(sensor).astype(int)), (0, 0, 0), cv2.MARKER_TRIANGLE_UP, 14, 2)
    bar_px = int(round(step * canvas.px_per_m))
    y0 = size_px - 16
    cv2.line(image, (12, y0), (12 + bar_px, y0), (0, 0, 0), 2)
    cv2.putText(image, f"{step:g} m", (16 + bar_px, y0 + 4), font, 0.4, (0, 0, 0), 1, cv2.LINE_AA)
    title = f"{path.sequence} {path.tracking_id[:8]}: level frame from above (forward up), 95 % ellipses"
    cv2.putText(image, title, (8, 18), font, 0.42, (0, 0, 0), 1, cv2.LINE_AA)
    return image
