"""A procedural gait model: walk, jog and stand on SMPL's 24-joint tree, with no data files.

The output is a :class:`~pedx_graph.motion.clips.MotionClip` (72-d axis-angle poses + pelvis path, Y up,
floor at y = 0), the same type the CMU retargeting produces, at any frame rate. Deterministic by seed.

Model (angles in degrees; gait phase ``phi`` in [0, 1) counts strides from a left heel strike; the right
leg uses ``phi + 0.5``):

* Cadence and step length from speed ``v``. Walking keeps the adult *walk ratio* (step length / cadence)
  ``W = 0.0065 m/(steps/min)`` scaled by leg length: ``f_step = sqrt(v / (60 W))``, ``step = v / f_step``
  (1.3 m/s -> 109 steps/min, 0.71 m steps). Jogging: ``f_step = 2.5 + 0.15 (v - 2.5)`` steps/s.
* Sagittal joint curves (textbook shapes: cosine + Gaussian bumps on the circle): hip flexion with a
  range of ``2 asin(step / (2 leg))`` when walking; knee flexion with a loading bump (~15 deg at 15 %)
  and a swing peak (~50-65 deg at 73 % walking, 80-105 deg jogging); ankle dorsi/plantar flexion with
  push-off plantarflexion. Knees only flex (rotation about +X, shank swings backwards).
* Pelvis: vertical bob (2 per stride; lowest at heel strike when walking, at mid-stance when jogging),
  lateral sway towards the stance leg, axial rotation and obliquity; thorax counter-rotation; legs
  compensate pelvis obliquity/rotation so the feet keep pointing forward.
* Arms: lowered from the T-pose by ~80 deg, swing opposite to the same-side leg, elbows flexed
  (~20 deg walking, ~85 deg jogging).
* Path: the pelvis follows a 2-D path (world x, z) at constant speed; the path is smoothed (Gaussian,
  0.3 m along arc length) and the heading is its tangent; a lean into turns of ``atan(v * yaw_rate / g)``.
* Stand: weight shifts, breathing, slow looking around.
* Seeded style: amplitudes, arm swing, arm abduction, trunk lean and start phase vary a little per seed.

SMPL axis conventions used: body +X left, +Y up, +Z forward. Hip flexion ``Rx(-a)``, knee flexion
``Rx(+a)``, ankle dorsiflexion ``Rx(-a)``, trunk forward lean ``Rx(+a)``; heading ``Ry(psi)`` faces
``(sin psi, 0, cos psi)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation

from pedx_graph.keypoints import SMPL_JOINTS
from pedx_graph.motion.clips import MotionClip
from pedx_graph.motion.retarget import generic_rest_joints
from pedx_graph.utils import make_rng

GAIT_KINDS = ("walk", "jog", "stand")
_J = {n: i for i, n in enumerate(SMPL_JOINTS)}
_G = 9.81


@dataclass(frozen=True)
class GaitParams:
    """Derived parameters of one procedural gait (returned in ``clip.meta["gait"]``)."""

    kind: str
    """walk, jog or stand."""
    speed: float
    """Pelvis speed along the path, m/s."""
    cadence: float
    """Steps per second (0 when standing)."""
    step_length: float
    """Metres per step (0 when standing)."""
    leg_length: float
    """Hip-joint height above the sole when standing straight, metres."""
    pelvis_height: float
    """Standing pelvis-joint height above the floor, metres."""


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _power(rot: np.ndarray, frac: float) -> np.ndarray:
    """rot ** frac = Exp(frac * Log(rot)), (N, 3, 3)."""
    return Rotation.from_rotvec(frac * Rotation.from_matrix(rot).as_rotvec()).as_matrix()


def _bump(phi: np.ndarray, centre: float, width: float) -> np.ndarray:
    """Gaussian bump on the unit circle of phase (distance wrapped to [-0.5, 0.5])."""
    d = (phi - centre + 0.5) % 1.0 - 0.5
    return np.exp(-0.5 * (d / width) ** 2)


def _leg_geometry(rest_joints: np.ndarray) -> tuple[float, float]:
    """(leg length hip->sole, standing pelvis height) from rest joints (sole 7 % of leg below the ankle)."""
    hip_y = 0.5 * (rest_joints[_J["left_hip"], 1] + rest_joints[_J["right_hip"], 1])
    ankle_y = 0.5 * (rest_joints[_J["left_ankle"], 1] + rest_joints[_J["right_ankle"], 1])
    thigh_shank = hip_y - ankle_y
    sole_y = ankle_y - 0.085 * thigh_shank
    return float(hip_y - sole_y), float(rest_joints[0, 1] - sole_y)


def gait_parameters(kind: str, speed: float, leg_length: float) -> tuple[float, float]:
    """(cadence steps/s, step length m) for ``kind`` at ``speed`` m/s (module docstring)."""
    if kind == "stand" or speed <= 0:
        return 0.0, 0.0
    if kind == "walk":
        walk_ratio = 0.0065 * leg_length / 0.85
        cadence = float(np.sqrt(speed / (60.0 * walk_ratio)))
    elif kind == "jog":
        cadence = 2.5 + 0.15 * (speed - 2.5)
    else:
        raise ValueError(f"gait kind must be one of {GAIT_KINDS}, got {kind!r}")
    return cadence, speed / cadence


def _path_samples(path_xz: np.ndarray | None, heading: float, length: float, smooth: float = 0.3):
    """Dense smoothed path: arc lengths (M,), points (M, 2), headings (M,)."""
    step = 0.01
    if path_xz is None:
        pts = np.array([[0.0, 0.0], [np.sin(heading), np.cos(heading)]]) * np.array([[1.0], [max(length, 1e-3) + 1.0]])
    else:
        pts = np.asarray(path_xz, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise ValueError(f"path_xz must be (N >= 2, 2) world (x, z) points, got shape {pts.shape}")
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        pts = pts[np.concatenate([[True], seg > 1e-9])]
        if len(pts) < 2:
            raise ValueError("path_xz has no two distinct points")
        total = np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1))
        if total < length + 1.0:     # extend straight along the last segment
            d = pts[-1] - pts[-2]
            pts = np.vstack([pts, pts[-1] + d / np.linalg.norm(d) * (length + 1.0 - total)])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.arange(0.0, cum[-1], step)
    dense = np.stack([np.interp(s, cum, pts[:, 0]), np.interp(s, cum, pts[:, 1])], axis=1)
    if smooth > 0 and len(dense) > 3:
        dense = gaussian_filter1d(dense, smooth / step, axis=0, mode="nearest")
    seg = np.linalg.norm(np.diff(dense, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    tangent = np.gradient(dense, axis=0)
    headings = np.unwrap(np.arctan2(tangent[:, 0], tangent[:, 1]))
    return arc, dense, headings


def procedural_gait(kind: str = "walk", speed: float = 1.3, *, duration: float = 8.0, fps: float = 10.0,
                    path_xz: np.ndarray | None = None, heading: float = 0.0,
                    start_xz: tuple[float, float] = (0.0, 0.0), rest_joints: np.ndarray | None = None,
                    seed: int = 0, name: str | None = None) -> MotionClip:
    """Generate a procedural gait clip (see module docstring for the model).

    ``kind``: walk, jog or stand. ``speed`` m/s along the path (ignored for stand; walk 0.3-2.2,
    jog 1.8-5 m/s). ``path_xz`` (N, 2) world (x, z) waypoints; None walks straight from ``start_xz``
    along ``heading`` (radians about +Y, 0 faces +Z). A path shorter than ``speed * duration`` is
    extended straight. ``rest_joints`` (24, 3): rest joints of the body that will play the clip (e.g.
    ``J(betas)``), used for leg length and pelvis height; default :func:`generic_rest_joints` (1.70 m).
    Returns frames at ``k / fps`` for ``k = 0 .. floor(duration * fps)``.
    """
    if kind not in GAIT_KINDS:
        raise ValueError(f"gait kind must be one of {GAIT_KINDS}, got {kind!r}")
    if not fps > 0 or not duration > 0:
        raise ValueError(f"fps and duration must be > 0, got fps={fps}, duration={duration}")
    if kind == "walk" and not 0.3 <= speed <= 2.2:
        raise ValueError(f"walking speed must be in [0.3, 2.2] m/s, got {speed}")
    if kind == "jog" and not 1.8 <= speed <= 5.0:
        raise ValueError(f"jogging speed must be in [1.8, 5.0] m/s, got {speed}")
    rest = generic_rest_joints() if rest_joints is None else np.asarray(rest_joints, dtype=float)
    if rest.shape != (24, 3):
        raise ValueError(f"rest_joints must be (24, 3), got {rest.shape}")
    rng = make_rng(seed)
    leg, pelvis_h = _leg_geometry(rest)
    v = 0.0 if kind == "stand" else float(speed)
    cadence, step_len = gait_parameters(kind, v, leg)
    n = int(np.floor(duration * fps + 1e-9)) + 1
    t = np.arange(n) / fps

    # seeded style
    style = lambda sd: float(np.clip(1.0 + sd * rng.standard_normal(), 1.0 - 2 * sd, 1.0 + 2 * sd))  # noqa: E731
    amp, arm_amp, bob_amp = style(0.08), style(0.25), style(0.15)
    arm_down = np.deg2rad(80.0 + 3.0 * rng.standard_normal())
    lean_extra = 1.5 * rng.standard_normal()
    phi0 = rng.uniform()
    phi = (phi0 + 0.5 * cadence * t) % 1.0
    two_pi = 2.0 * np.pi
    d2r = np.deg2rad

    def legs(p):
        """hip flexion, knee flexion, ankle dorsiflexion, hip abduction (degrees) at phase p."""
        if kind == "walk":
            a = np.clip(v / 1.3, 0.3, 1.5)
            hip_range = np.rad2deg(2.0 * np.arcsin(min(step_len / (2.0 * leg), 0.9))) * amp
            hip = 8.0 + 2.0 * a + 0.5 * hip_range * np.cos(two_pi * (p - 0.02))
            knee = 4.0 + 15.0 * a * amp * _bump(p, 0.15, 0.07) + (50.0 + 10.0 * (a - 1.0)) * amp * _bump(p, 0.73, 0.11)
            ankle = (-5.0 * _bump(p, 0.06, 0.04) + 10.0 * _bump(p, 0.42, 0.12)
                     - (12.0 + 6.0 * a) * _bump(p, 0.62, 0.05) + 2.0 * _bump(p, 0.85, 0.1))
            abd = -3.0 * _bump(p, 0.25, 0.15) + 2.0 * _bump(p, 0.75, 0.15)
        elif kind == "jog":
            e = np.clip(v - 2.5, -0.7, 2.5)
            hip = 18.0 + (22.0 + 5.0 * e) * amp * np.cos(two_pi * (p - 0.9))
            knee = 15.0 + 25.0 * amp * _bump(p, 0.18, 0.07) + (70.0 + 12.0 * e) * amp * _bump(p, 0.72, 0.13)
            ankle = 3.0 + 15.0 * _bump(p, 0.2, 0.07) - 22.0 * _bump(p, 0.42, 0.05)
            abd = -3.0 * _bump(p, 0.2, 0.1) + 2.0 * _bump(p, 0.7, 0.15)
        else:
            hip, knee, ankle, abd = 2.0 + 0 * p, 4.0 + 0 * p, 2.0 + 0 * p, 0 * p
        return hip, knee, ankle, abd

    hip_l, knee_l, ankle_l, abd_l = legs(phi)
    hip_r, knee_r, ankle_r, abd_r = legs((phi + 0.5) % 1.0)

    # pelvis oscillation (body frame) and trunk
    if kind == "walk":
        a = np.clip(v / 1.3, 0.3, 1.5)
        bob = -(0.010 + 0.010 * a) * bob_amp * np.cos(2 * two_pi * phi)
        sway = (0.030 - 0.008 * a) * np.sin(two_pi * phi)
        p_yaw = -d2r(4.0 * a * amp) * np.cos(two_pi * phi)
        p_roll = d2r(4.0 * amp) * np.sin(two_pi * phi)
        lean = d2r(2.0 + 1.5 * a + lean_extra)
        base = pelvis_h - 0.01 - 0.01 * a
        arm_swing = (6.0 + 12.0 * a) * arm_amp
        elbow_mean, elbow_amp = 18.0, 8.0
    elif kind == "jog":
        bob = -0.035 * bob_amp * np.cos(2 * two_pi * (phi - 0.18))
        sway = 0.012 * np.sin(two_pi * (phi - 0.05))
        p_yaw = -d2r(6.0 * amp) * np.cos(two_pi * (phi - 0.1))
        p_roll = d2r(3.0 * amp) * np.sin(two_pi * phi)
        lean = d2r(7.0 + lean_extra)
        base = pelvis_h - 0.05
        arm_swing = (25.0 + 5.0 * np.clip(v - 2.5, -0.7, 2.5)) * arm_amp
        elbow_mean, elbow_amp = 85.0, 15.0
    else:
        shift_f = 0.12 + 0.05 * rng.uniform()
        bob = 0.003 * np.sin(two_pi * 0.25 * t)
        sway = 0.015 * np.sin(two_pi * shift_f * t + two_pi * phi0)
        p_yaw = d2r(2.0) * np.sin(two_pi * 0.5 * shift_f * t)
        p_roll = d2r(1.5) * np.sin(two_pi * shift_f * t + two_pi * phi0)
        lean = d2r(1.0 + 0.5 * np.sin(two_pi * 0.25 * t) + 0.5 * lean_extra)
        base = pelvis_h - 0.005
        arm_swing, elbow_mean, elbow_amp = 0.0, 10.0, 0.0

    # path, heading and lean into turns
    length = v * t[-1]
    arc, dense, headings = _path_samples(path_xz, heading, length)
    s_t = v * t
    path_pt = np.stack([np.interp(s_t, arc, dense[:, 0]), np.interp(s_t, arc, dense[:, 1])], axis=1)
    psi = np.interp(s_t, arc, headings)
    if path_xz is None:
        path_pt = path_pt + np.asarray(start_xz, dtype=float)
    yaw_rate = np.gradient(psi, t) if n > 1 else np.zeros(n)
    turn_lean = np.arctan(v * yaw_rate / _G)     # positive yaw rate = turning left -> lean left
    if kind == "stand":
        look = np.zeros(n)
        for k in range(3):          # slow looking around: a few seeded sinusoids
            look += d2r(12.0 / (k + 1)) * np.sin(two_pi * (0.05 * (k + 1) + 0.03 * rng.uniform()) * t
                                                  + two_pi * rng.uniform())
    else:
        look = np.zeros(n)

    world_R_heading = _ry(psi) @ _rz(-turn_lean)
    pelvis_osc = _ry(p_yaw) @ _rz(p_roll)
    world_R_pelvis = world_R_heading @ pelvis_osc
    osc_T = np.swapaxes(pelvis_osc, -1, -2)

    local = np.broadcast_to(np.eye(3), (n, 24, 3, 3)).copy()
    local[:, 0] = world_R_pelvis
    for side, hip, knee, ankle, abd, sign in (("left", hip_l, knee_l, ankle_l, abd_l, 1.0),
                                              ("right", hip_r, knee_r, ankle_r, abd_r, -1.0)):
        local[:, _J[f"{side}_hip"]] = osc_T @ _rz(sign * d2r(abd + 2.0)) @ _rx(-d2r(hip))
        local[:, _J[f"{side}_knee"]] = _rx(d2r(np.maximum(knee, 0.0)))
        local[:, _J[f"{side}_ankle"]] = _rx(-d2r(ankle))
    thorax_rel = _ry(-0.6 * p_yaw) @ _rx(lean)
    spine_each = _power(osc_T @ thorax_rel, 1.0 / 3.0)
    for j in ("spine1", "spine2", "spine3"):
        local[:, _J[j]] = spine_each
    head_rel = _power(np.swapaxes(thorax_rel, -1, -2) @ _rz(turn_lean * 0.5) @ _ry(look), 0.5)
    local[:, _J["neck"]] = head_rel
    local[:, _J["head"]] = head_rel
    # arms: swing opposite to the same-side leg
    for side, sign, leg_phase in (("left", 1.0, phi), ("right", -1.0, (phi + 0.5) % 1.0)):
        swing = 3.0 - arm_swing * np.cos(two_pi * (leg_phase - 0.05))
        elbow = elbow_mean + elbow_amp * (-np.cos(two_pi * (leg_phase - 0.05)))
        local[:, _J[f"{side}_shoulder"]] = _rx(-d2r(swing)) @ _rz(-sign * arm_down * np.ones(n))
        local[:, _J[f"{side}_elbow"]] = _ry(-sign * d2r(elbow))

    pose = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_rotvec().reshape(n, 72)
    offset_body = np.stack([sway, base + bob, np.zeros(n)], axis=1)
    offset_world = np.einsum("nab,nb->na", world_R_heading, offset_body)
    pelvis = np.stack([path_pt[:, 0], np.zeros(n), path_pt[:, 1]], axis=1) + offset_world
    params = GaitParams(kind, v, cadence, step_len, leg, pelvis_h)
    clip_name = name or (f"gait-{kind}" if kind == "stand" else f"gait-{kind}-{v:.2f}")
    return MotionClip(name=clip_name, fps=float(fps), body_pose_aa=pose, pelvis_world=pelvis,
                      source="procedural", floor_y=0.0,
                      meta={"gait": params.__dict__, "seed": seed})
