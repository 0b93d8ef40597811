"""pedx_graph.data: in-memory types and the PedX release reader / writer.

Main entry points::

    tracks = read_dataset(root)              # list[Track]; iter_tracks(root) is the lazy variant
    truth = read_smpl_labels(root)           # {(sequence, tracking_id): [SmplLabel, ...]}
    write_results(root, labels)              # labels/3d/smpl/<seq>/<seq>_<frame:07d>_<tid>.json
    write_tracks(root, tracks)               # calib, 2D labels, segments, timestamps (simulator)
"""
from pedx_graph.data.calib import (
    discover_pairs,
    read_calibrations,
    read_stereo_calibration,
    write_stereo_calibration,
)
from pedx_graph.data.labels2d import Label2D, label2d_path, read_label2d, write_label2d
from pedx_graph.data.ply import read_ply_points, segment_path, write_ply_points
from pedx_graph.data.reader import (
    ReaderConfig,
    iter_tracks,
    list_sequences,
    read_dataset,
    read_scene_points,
    read_smpl_labels,
    read_timestamps,
    resolve_root,
)
from pedx_graph.data.smpl_labels import read_smpl_label, smpl_label_path, write_smpl_label
from pedx_graph.data.types import (
    EVAL_JOINTS,
    PEDX_KEYPOINTS,
    DataFormatError,
    SmplLabel,
    StereoCalibration,
    Track,
    TrackFrame,
    View2D,
)
from pedx_graph.data.writer import (
    output_root,
    write_calibration,
    write_results,
    write_scene_points,
    write_segment,
    write_timestamps,
    write_tracks,
)

__all__ = [
    "DataFormatError", "EVAL_JOINTS", "PEDX_KEYPOINTS", "Label2D", "ReaderConfig", "SmplLabel",
    "StereoCalibration", "Track", "TrackFrame", "View2D",
    "discover_pairs", "iter_tracks", "label2d_path", "list_sequences", "output_root", "read_calibrations",
    "read_dataset", "read_label2d", "read_ply_points", "read_scene_points", "read_smpl_label",
    "read_smpl_labels", "read_stereo_calibration", "read_timestamps", "resolve_root", "segment_path",
    "smpl_label_path", "write_calibration", "write_label2d", "write_ply_points", "write_results",
    "write_scene_points", "write_segment", "write_smpl_label", "write_stereo_calibration",
    "write_timestamps", "write_tracks",
]
