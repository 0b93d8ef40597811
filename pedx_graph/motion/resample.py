"""Resampling motion clips to another frame rate.

Rotations are interpolated on SO(3) (quaternion slerp per joint, shortest arc), never on Euler angles or
axis-angle components, so wraps of +-180 degrees in the source's Euler channels cause no jumps. Positions
are interpolated linearly. Times outside the key range are clamped to the first/last key.

Repeated frames (a mocap system holding the last pose while markers drop out, e.g. CMU 03_02 and 08_07)
are exact copies of the previous frame; with ``drop_repeated=True`` they are treated as missing samples and
the interpolation bridges them.
"""
from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.motion.clips import MotionClip


def _quat_from_rotvec(rotvec: np.ndarray) -> np.ndarray:
    """(..., 3) rotation vectors -> (..., 4) unit quaternions (x, y, z, w)."""
    flat = Rotation.from_rotvec(rotvec.reshape(-1, 3)).as_quat()
    return flat.reshape(rotvec.shape[:-1] + (4,))


def _rotvec_from_quat(quat: np.ndarray) -> np.ndarray:
    flat = Rotation.from_quat(quat.reshape(-1, 4)).as_rotvec()
    return flat.reshape(quat.shape[:-1] + (3,))


def _segments(key_times: np.ndarray, new_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Segment index i (key i .. i+1) and fraction u in [0, 1] of each new time (clamped)."""
    if key_times.ndim != 1 or key_times.size < 1:
        raise ValueError("key_times must be a non-empty 1-d array")
    if np.any(np.diff(key_times) <= 0):
        raise ValueError("key_times must be strictly increasing")
    if key_times.size == 1:
        return np.zeros(new_times.shape, dtype=int), np.zeros(new_times.shape)
    t = np.clip(new_times, key_times[0], key_times[-1])
    idx = np.clip(np.searchsorted(key_times, t, side="right") - 1, 0, key_times.size - 2)
    u = (t - key_times[idx]) / (key_times[idx + 1] - key_times[idx])
    return idx, np.clip(u, 0.0, 1.0)


def slerp_quaternions(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shortest arc.

    ``q0``, ``q1`` (..., 4); ``u`` broadcastable to (...,). Returns (..., 4) unit quaternions:
    ``q(u) = sin((1-u) w)/sin(w) q0 + sin(u w)/sin(w) q1`` with ``cos w = |<q0, q1>|`` (q1 negated when the
    dot product is negative); for ``w < 1e-6`` rad a normalised linear blend is used (same to first order).
    """
    q0 = np.asarray(q0, dtype=float)
    q1 = np.asarray(q1, dtype=float).copy()
    u = np.asarray(u, dtype=float)[..., None]
    dot = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(dot < 0, -q1, q1)
    dot = np.abs(dot).clip(max=1.0)
    omega = np.arccos(dot)
    small = omega < 1e-6
    sin_o = np.where(small, 1.0, np.sin(omega))
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * omega) / sin_o)
    w1 = np.where(small, u, np.sin(u * omega) / sin_o)
    out = w0 * q0 + w1 * q1
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def interpolate_rotvecs(key_times: np.ndarray, key_rotvecs: np.ndarray, new_times: np.ndarray) -> np.ndarray:
    """Slerp rotation vectors (keys (K, ..., 3) at ``key_times`` (K,)) to ``new_times`` (N,) -> (N, ..., 3)."""
    key_times = np.asarray(key_times, dtype=float)
    new_times = np.asarray(new_times, dtype=float)
    quats = _quat_from_rotvec(np.asarray(key_rotvecs, dtype=float))
    if quats.shape[0] != key_times.size:
        raise ValueError(f"{quats.shape[0]} rotation keys for {key_times.size} key times")
    idx, u = _segments(key_times, new_times)
    if key_times.size == 1:
        return np.repeat(np.asarray(key_rotvecs, float)[:1], new_times.size, axis=0)
    u = u.reshape((-1,) + (1,) * (quats.ndim - 2))
    q = slerp_quaternions(quats[idx], quats[idx + 1], np.broadcast_to(u, quats[idx].shape[:-1]))
    return _rotvec_from_quat(q)


def interpolate_linear(key_times: np.ndarray, key_values: np.ndarray, new_times: np.ndarray) -> np.ndarray:
    """Linear interpolation of (K, ...) values to ``new_times`` (N,) -> (N, ...), clamped at the ends."""
    key_times = np.asarray(key_times, dtype=float)
    values = np.asarray(key_values, dtype=float)
    idx, u = _segments(key_times, np.asarray(new_times, dtype=float))
    if key_times.size == 1:
        return np.repeat(values[:1], len(idx), axis=0)
    u = u.reshape((-1,) + (1,) * (values.ndim - 1))
    return (1.0 - u) * values[idx] + u * values[idx + 1]


def repeated_frames(body_pose_aa: np.ndarray, pelvis_world: np.ndarray) -> np.ndarray:
    """(T,) bool: frame t (t >= 1) is an exact copy of frame t-1 (pose and pelvis)."""
    same = np.zeros(len(body_pose_aa), dtype=bool)
    same[1:] = np.all(body_pose_aa[1:] == body_pose_aa[:-1], axis=1) & \
        np.all(pelvis_world[1:] == pelvis_world[:-1], axis=1)
    return same


def resample_clip(clip: MotionClip, fps: float, *, drop_repeated: bool = True,
                  duration: float | None = None) -> MotionClip:
    """The clip sampled at ``fps`` from its first frame: new frame k at time ``k / fps``.

    The number of new frames is ``floor(duration * fps + 1e-9) + 1`` with ``duration`` defaulting to the
    clip's. Rotations (all 24 joints, including the root orientation) by slerp, the pelvis linearly.
    ``drop_repeated``: frames identical to their predecessor are removed from the keys first (see module
    docstring); a trailing run of repeats is then held at the last distinct key.
    """
    if not fps > 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    times = clip.times
    pose = clip.body_pose_aa.reshape(-1, 24, 3)
    pelvis = clip.pelvis_world
    keep = np.ones(clip.num_frames, dtype=bool)
    if drop_repeated:
        keep = ~repeated_frames(clip.body_pose_aa, clip.pelvis_world)
    dur = clip.duration if duration is None else float(duration)
    new_times = np.arange(int(np.floor(dur * fps + 1e-9)) + 1) / fps
    new_pose = interpolate_rotvecs(times[keep], pose[keep], new_times).reshape(-1, 72)
    new_pelvis = interpolate_linear(times[keep], pelvis[keep], new_times)
    return clip.with_updates(fps=float(fps), body_pose_aa=new_pose, pelvis_world=new_pelvis,
                             meta={**clip.meta, "resampled_from_fps": clip.fps,
                                   "dropped_repeats": int((~keep).sum())})
