"""Detector keypoints in: readers of detector / annotation-tool files, undistortion, association, import."""
from pedx_graph.detections.types import KEYPOINT_SET_NAMES, Detection

__all__ = ["Detection", "KEYPOINT_SET_NAMES"]
