"""pedx_graph.sim: a PedX-like simulator (the project's ground-truth instrument).

A four-way-stop intersection (ground, buildings, poles, parked and moving cars) with SMPL-format pedestrians
walking on crosswalks and sidewalks at 5-45 m, seen by two rectified stereo pairs (ylw79D0-red707B forward,
blu79CF-grn43E3 left) and a 32-beam spinning LiDAR, all by Embree ray casting.  Writes the PedX release layout
(calib, 2D labels with annotator noise, polygon-assigned LiDAR segments, SMPL labels in the LiDAR frame, full
sweeps, timestamps) plus exact ground truth under ``truth/``.

Public API::

    from pedx_graph.sim import SimConfig, simulate
    summary = simulate(out_dir, SimConfig(), seed=0)          # or load_config(SimConfig, "configs/sim_default.yaml")
    truth = read_truth_frame(out_dir, frame)                 # exact points, ids, keypoints, segment membership
    from pedx_graph.sim.figure import render_frame            # PNG of one frame

Command line: ``pedx-graph simulate OUT --seed S --pedestrians N --frames F [--motion-dir DIR] [--config YAML]``.
"""
from pedx_graph.sim.config import (
    FORWARD_PAIR,
    LEFT_PAIR,
    CamerasConfig,
    LabelConfig,
    LidarConfig,
    MotionConfig,
    SceneConfig,
    SimConfig,
    StereoPairConfig,
)
from pedx_graph.sim.simulate import read_truth_frame, simulate

__all__ = [
    "simulate", "read_truth_frame", "SimConfig", "SceneConfig", "CamerasConfig", "StereoPairConfig", "LidarConfig", "LabelConfig",
    "MotionConfig", "FORWARD_PAIR", "LEFT_PAIR",
]
