"""Rendered camera images of a simulated frame: ground and sky, the scene's objects and the true bodies.

Written when ``SimConfig.images.enabled`` as the release's ``images/<seq>/<cam>/<seq>_<cam>_<frame:07d>.jpg``
(rectified images: the calibration's projection applies), ``ImageConfig.scale`` times the calibration's image
size, so that overlays of a fit can be tested on images.  Everything is drawn in the sim frame (its +z
against gravity, the ground at ``z = ground_z``): each pixel's ray meets the ground plane (grey asphalt with
a 1 m checker, fading with distance) or the sky; the scene's meshes (buildings, cars) and the true posed
bodies are painted over it with :func:`pedx_graph.export.raster.paint_meshes` (painter's order, Lambert
shading; one colour per object; the objects' large faces split to at most :data:`MAX_EDGE_M` first, so that
ordering faces by their centroid's depth does not put a wall in front of a person standing before it).  No randomness: the same frame gives the same bytes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from pedx_graph.data.images import image_path
from pedx_graph.export.raster import PaintedMesh, outward_faces, paint_meshes
from pedx_graph.utils import atomic_write_bytes

#: Body colours (BGR), by the person's object id.
BODY_COLOURS = ((60, 80, 170), (150, 100, 50), (70, 140, 90), (40, 150, 200), (140, 70, 140), (110, 110, 30))
#: Colour (BGR) of buildings / cars / anything else.
OBJECT_COLOURS = {"building": (170, 175, 180), "parked_car": (120, 60, 40), "moving_car": (40, 60, 140),
                  "pole": (60, 60, 60)}
#: Faces of scene objects (buildings, cars) are split until no edge is longer than this, metres.
MAX_EDGE_M = 1.0
#: Farthest ground drawn, metres (beyond: the sky colour at the horizon).
GROUND_RANGE_M = 200.0


@dataclass
class ImageConfig:
    """Rendered camera images of the simulator (off by default)."""

    enabled: bool = False
    """Write ``images/<seq>/<cam>/<seq>_<cam>_<frame:07d>.jpg`` for every camera and frame."""
    scale: float = 1.0
    """Image size relative to the calibration's (e.g. 0.25 for quick tests); overlays scale the projection."""
    jpeg_quality: int = 90
    """JPEG quality, 1-100."""


def background(view, ground_z: float, scale: float) -> np.ndarray:
    """(H, W, 3) BGR ground and sky of one camera (``view``: a :class:`pedx_graph.sim.cameras.CameraView` in
    the sim frame), ``scale`` times its calibration's size."""
    width, height = (max(1, int(round(v * scale))) for v in view.calib.image_size)
    u, v = np.meshgrid((np.arange(width) + 0.5) / scale - 0.5, (np.arange(height) + 0.5) / scale - 0.5)
    rays = view.pixel_rays(np.stack([u.ravel(), v.ravel()], axis=1))
    centre = view.world_center
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (ground_z - centre[2]) / rays[:, 2]
    hit = np.isfinite(t) & (t > 0) & (t < GROUND_RANGE_M)
    image = np.empty((len(rays), 3))
    sky = np.clip(rays[:, 2], 0.0, 1.0)[:, None]
    image[:] = (235, 215, 200) * (1 - sky) + np.array([230, 170, 120]) * sky
    ground = centre[None, :2] + t[hit, None] * rays[hit, :2]
    checker = (np.floor(ground[:, 0]).astype(int) + np.floor(ground[:, 1]).astype(int)) % 2
    grey = 95.0 + 18.0 * checker
    fade = np.clip(t[hit] / GROUND_RANGE_M, 0.0, 1.0)[:, None]
    image[hit] = grey[:, None] * (1 - fade) + np.array([200, 195, 190]) * fade
    return image.reshape(height, width, 3).round().astype(np.uint8)


def render_view(view, ground_z: float, meshes: list[tuple[int, np.ndarray, np.ndarray]], kinds: dict[int, str],
                scale: float) -> np.ndarray:
    """One camera's image: :func:`background` with ``meshes`` ((object id, (V, 3) sim-frame vertices, faces))
    painted over it; ``kinds``: object id -> kind (``pedestrian`` bodies get :data:`BODY_COLOURS`)."""
    painted = []
    for object_id, vertices, faces in meshes:
        kind = kinds.get(object_id, "")
        if kind == "ground":                                   # drawn by the background
            continue
        colour = (BODY_COLOURS[object_id % len(BODY_COLOURS)] if kind == "pedestrian"
                  else OBJECT_COLOURS.get(kind, (150, 150, 150)))
        faces = outward_faces(vertices, faces)
        if kind != "pedestrian":          # big faces split so that painter's order by face depth holds near people
            vertices, faces = trimesh.remesh.subdivide_to_size(vertices, faces, MAX_EDGE_M)
        painted.append(PaintedMesh(vertices, faces, colour))
    return paint_meshes(background(view, ground_z, scale), _Scaled(view), painted, scale)


class _Scaled:
    """A sim camera view seen through the export's camera interface (``project(world_p, scale)``)."""

    def __init__(self, view):
        self.view = view
        self.world_center = view.world_center

    def project(self, world_p: np.ndarray, scale: float = 1.0):
        uv, depth = self.view.project(world_p)
        return (uv if scale == 1.0 else (uv + 0.5) * scale - 0.5), depth


def write_frame_images(out: Path, sequence: str, frame: int, views: list, ground_z: float,
                       meshes: list[tuple[int, np.ndarray, np.ndarray]], kinds: dict[int, str],
                       config: ImageConfig) -> list[Path]:
    """Render every view of one frame and write its JPEG (module docstring); returns the paths."""
    import cv2

    written = []
    for view in views:
        image = render_view(view, ground_z, meshes, kinds, config.scale)
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(config.jpeg_quality)])
        if not ok:
            raise OSError(f"OpenCV could not encode the image of {view.camera}, frame {frame}")
        written.append(atomic_write_bytes(image_path(out, sequence, view.camera, frame), buf.tobytes()))
    return written
