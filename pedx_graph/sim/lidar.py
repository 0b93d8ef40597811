"""Spinning multi-beam LiDAR (HDL-32E-like) by ray casting against every mesh of the scene.

The sensor sits at the world origin (the world *is* the LiDAR frame).  One sweep fires ``n_beams`` lasers
at elevations evenly spaced in ``[elevation_min, elevation_max]`` at every azimuth step over 360 deg:

    d(e, a) = (cos e cos a, cos e sin a, sin e),   world_p = r_noisy * d,   r_noisy = r_true + N(0, sigma^2)

where ``r_true`` is the distance to the first surface hit (people, cars, buildings and ground occlude each
other).  Each return is independently lost with probability ``dropout_prob``; returns outside
``[min_range, max_range]`` are discarded.  Simplification: the whole sweep is taken at the frame time (no
rolling-scan motion distortion; at 1.3 m/s a pedestrian moves 13 cm during a 0.1 s sweep).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pedx_graph.sim.config import LidarConfig
from pedx_graph.sim.scene import RayScene


@dataclass
class LidarSweep:
    """One simulated sweep (world frame, metres)."""

    world_points: np.ndarray
    """(N, 3) returned points (noise included), in firing order (beam-major within each azimuth)."""
    object_id: np.ndarray
    """(N,) object id of the surface each point came from (ground truth)."""
    true_range_m: np.ndarray
    """(N,) noise-free range of each point."""
    n_dropped: int
    """Rays that hit a surface within range but whose return was lost (dropout)."""


def beam_directions(config: LidarConfig) -> np.ndarray:
    """(A * B, 3) unit ray directions, azimuth-major (all beams of azimuth 0 first), world frame."""
    elevation = np.deg2rad(np.linspace(config.elevation_min_deg, config.elevation_max_deg, config.n_beams))
    n_az = int(round(360.0 / config.azimuth_step_deg))
    azimuth = np.deg2rad(np.arange(n_az) * (360.0 / n_az))
    az, el = np.meshgrid(azimuth, elevation, indexing="ij")
    return np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=-1).reshape(-1, 3)


def sweep(ray_scene: RayScene, config: LidarConfig, rng: np.random.Generator,
          directions: np.ndarray | None = None) -> LidarSweep:
    """Cast one sweep through ``ray_scene``; noise and dropouts drawn from ``rng`` (fixed draw order)."""
    if directions is None:
        directions = beam_directions(config)
    dist, object_id = ray_scene.cast(np.zeros(3), directions)
    noise = rng.normal(0.0, config.range_noise_m, size=len(directions))
    lost = rng.random(len(directions)) < config.dropout_prob
    in_range = np.isfinite(dist) & (dist >= config.min_range_m) & (dist <= config.max_range_m)
    keep = in_range & ~lost
    noisy = dist[keep] + noise[keep]
    return LidarSweep(world_points=directions[keep] * noisy[:, None], object_id=object_id[keep],
                      true_range_m=dist[keep], n_dropped=int((in_range & lost).sum()))
