"""The in-memory type of one detected person in one image, shared by the readers, the tracker and the import."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Keypoint sets a detection may carry (each a data file in ``pedx_graph/body/data/keypoint_sets/``).
KEYPOINT_SET_NAMES: tuple[str, ...] = ("pedx18", "coco17", "body25", "body25b", "coco18")


@dataclass
class Detection:
    """One person's 2D keypoints in one image, as a detector or annotation tool wrote them."""

    camera: str
    """Camera name as in the calibration (e.g. ``'blu79CF'``)."""
    frame: int
    """Frame index (the synchronised sample)."""
    keypoint_set: str
    """Which keypoints, in which order: one of :data:`KEYPOINT_SET_NAMES`."""
    image_uv: np.ndarray
    """(K, 2) float coordinates in the image the detector saw (raw or rectified, at the calibration's size or
    resized, pixels or normalised: :mod:`pedx_graph.detections.pixel_scale` brings them to the calibration's
    pixels on import); NaN where absent."""
    confidence: np.ndarray
    """(K,) in [0, 1]; 0 where absent.  COCO annotations: visibility v = 0 -> 0, 1 -> 1 with
    :attr:`occluded` set, 2 -> 1."""
    score: float
    """Detection score (the mean confidence of the present keypoints when the file has none)."""
    source: str
    """The file (and the index in it) the detection came from, for error messages."""
    track_id: str | None = None
    """An id given by the file (OpenPose ``person_id`` >= 0, a COCO track id), else None."""
    bbox: np.ndarray | None = None
    """(4,) ``x, y, w, h`` in the image the detector saw, in its coordinates, if the file gives one."""
    occluded: np.ndarray | None = None
    """(K,) bool: labelled but marked not visible (COCO ``v = 1``); None when the file has no such flag."""
    sequence: str | None = None
    """The sequence named by the file (e.g. a PedX image name's ``<sequence>_`` prefix), else None."""
    image: str | None = None
    """Stem of the image the detector saw (its file name without folder and extension) when the file names
    it (an OpenPose file's name, a COCO image's ``file_name``), else None."""
    image_size: tuple[int, int] | None = None
    """``(width, height)`` of the image the detector saw, pixels, when the file gives it (a COCO image's
    ``width`` and ``height``), else None; :mod:`pedx_graph.detections.pixel_scale` compares it with the
    calibration's."""

    @property
    def present(self) -> np.ndarray:
        """(K,) bool: the keypoint has a finite position and a positive confidence."""
        return np.all(np.isfinite(self.image_uv), axis=-1) & (self.confidence > 0)

    def box(self) -> np.ndarray:
        """(4,) ``x, y, w, h``: :attr:`bbox` when given, else the box of the present keypoints (zeros if none)."""
        if self.bbox is not None:
            return np.asarray(self.bbox, dtype=float)
        uv = self.image_uv[self.present]
        if len(uv) == 0:
            return np.zeros(4)
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]], dtype=float)
