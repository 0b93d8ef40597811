"""The open body model's standing template, loaded once per process, for the checks that compare a detection
with a standing person's proportions (:mod:`pedx_graph.detections.association`, :mod:`pedx_graph.detections.flips`)."""
from __future__ import annotations

import functools

import numpy as np

from pedx_graph.body.keypoint_defs import standing_keypoints_3d
from pedx_graph.body.model import BodyModel


@functools.lru_cache(maxsize=None)
def open_standing_keypoints_3d(set_name: str) -> np.ndarray:
    """:func:`~pedx_graph.body.keypoint_defs.standing_keypoints_3d` on the shipped open model (read-only):
    (K, 3) in the model's frame (x the body's left, y up, z forward), metres."""
    out = standing_keypoints_3d(BodyModel.load(), set_name)
    out.flags.writeable = False
    return out
