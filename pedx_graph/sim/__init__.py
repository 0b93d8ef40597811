"""pedx_graph.sim: a PedX-like simulator (the project's ground-truth instrument).

A four-way-stop intersection (ground, buildings, poles, parked and moving cars) with SMPL-format pedestrians
walking on crosswalks and sidewalks at 5-45 m, seen by two rectified stereo pairs and a 32-beam spinning LiDAR,
all by Embree ray casting.  Two rigs: ``default`` (ylw79D0-red707B forward, blu79CF-grn43E3 left, LiDAR frame with +z
against gravity) and ``pedx`` (the real PedX cameras in the real z-down LiDAR frame, real-label quirks).  Writes the
PedX release layout (calib, 2D labels with annotator noise, polygon-assigned LiDAR segments, SMPL labels in the
LiDAR frame, full sweeps, timestamps) plus exact ground truth under ``truth/``.

Public API::

    from pedx_graph.sim import SimConfig, simulate
    summary = simulate(out_dir, SimConfig(), seed=0)          # or load_sim_config("configs/sim_default.yaml")
    summary = simulate(out_dir, rig_config("pedx"), seed=0)  # the real PedX rig
    truth = read_truth_frame(out_dir, frame)                 # exact points, ids, keypoints, segment membership
    from pedx_graph.sim.figure import render_frame            # PNG of one frame

Command line: ``pedx-graph simulate OUT --seed S --pedestrians N --frames F [--rig default|pedx] [--motion-dir DIR]
[--config YAML]``.
"""
from pedx_graph.sim.config import (
    FORWARD_PAIR,
    LEFT_PAIR,
    RIGS,
    CamerasConfig,
    LabelConfig,
    LidarConfig,
    MotionConfig,
    OutputFrameConfig,
    SceneConfig,
    SimConfig,
    StereoPairConfig,
    load_sim_config,
    pedx_rig_config,
    rig_config,
)
from pedx_graph.sim.simulate import read_truth_frame, simulate

__all__ = [
    "simulate", "read_truth_frame", "SimConfig", "SceneConfig", "CamerasConfig", "StereoPairConfig", "LidarConfig", "LabelConfig",
    "MotionConfig", "OutputFrameConfig", "FORWARD_PAIR", "LEFT_PAIR", "RIGS", "rig_config", "pedx_rig_config",
    "load_sim_config",
]
