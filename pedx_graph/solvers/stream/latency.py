"""Latency statistics of the streaming updates: per track (at its finalisation) and over a run."""
from __future__ import annotations

import numpy as np

from pedx_graph.solvers.stream.state import ActiveTrack


def track_latencies(state: ActiveTrack) -> tuple[np.ndarray, np.ndarray]:
    """``(whole update, ISAM2 update alone)`` wall times (s) of each of the track's streaming updates (the
    whole update as the estimator timed it, ``FrameEstimate.update_seconds``, when it timed every one)."""
    n_updates = len(state.smoother.updates)
    latencies = np.array(state.frame_seconds if len(state.frame_seconds) == n_updates
                         else [u.seconds for u in state.smoother.updates[:n_updates]])
    isam_only = np.array([u.isam_seconds for u in state.smoother.updates[:n_updates]])
    return latencies, isam_only


def track_latency_fields(latencies: np.ndarray, isam_only: np.ndarray) -> dict:
    """The track's ``stream_update*`` summary fields (ms): count, median, p90, max, ISAM2 update median."""
    return {
        "stream_updates": int(len(latencies)),
        "stream_update_ms_median": float(np.median(latencies) * 1e3),
        "stream_update_ms_p90": float(np.percentile(latencies, 90) * 1e3),
        "stream_update_ms_max": float(latencies.max() * 1e3),
        "stream_isam_update_ms_median": float(np.median(isam_only) * 1e3),
    }


def stream_timings(tracks: list[dict]) -> dict:
    """Whole-run latency figures (``update_ms``: median, p90, max, mean of the updates' wall time; CPU time;
    the ISAM2 update alone) from the tracks' per-update lists, which are then dropped from the entries."""
    lat, cpu, isam = [], [], []
    for entry in tracks:
        lat += entry.pop("update_ms", None) or []
        cpu += entry.pop("cpu_ms", None) or []
        isam += entry.pop("isam_ms", None) or []
    if not lat:
        return {}
    lat, cpu, isam = np.asarray(lat), np.asarray(cpu), np.asarray(isam)
    return {"update_ms": {"median": float(np.median(lat)), "p90": float(np.percentile(lat, 90)),
                          "max": float(lat.max()), "mean": float(lat.mean()),
                          "cpu_median": float(np.median(cpu)) if cpu.size else None,
                          "cpu_p90": float(np.percentile(cpu, 90)) if cpu.size else None,
                          "isam_update_median": float(np.median(isam)) if isam.size else None,
                          "isam_update_p90": float(np.percentile(isam, 90)) if isam.size else None}}
