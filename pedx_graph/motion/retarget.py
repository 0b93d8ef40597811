"""Retargeting the CMU "Daz-friendly" BVH skeleton onto SMPL's 24-joint tree.

Rest-relative transfer
----------------------
Frame 0 of the CMU files is the converter's T-pose, close to SMPL's rest pose. For every SMPL joint j that
has a BVH counterpart b(j) (:data:`CMU_TO_SMPL`)::

    world_R_j(t) = C @ bvhworld_R_b(t) @ bvhworld_R_b(0)^T @ C^T @ A_j

where ``C`` is the yaw (rotation about Y) that turns the figure's rest facing direction onto +Z (SMPL's
forward) and ``A_j`` (identity unless ``align_bones``) the smallest rotation turning the body's rest limb
bone onto the BVH's rest bone (:func:`rest_alignment`). Joints without a counterpart inherit their parent's world rotation (local identity), except
spine2/spine3, which split the chest rotation relative to spine1 in two equal halves
(``spine1_R_spine2 = spine2_R_spine3 = Exp(0.5 Log(world_R_spine1^T world_R_chest))``). Local rotations are
``parent_R_j = world_R_parent^T world_R_j``; the 72-d pose is their axis-angle (joint 0: ``world_R_pelvis``).

World frame: the BVH world (Y up, floor y = 0) turned by ``C`` and scaled to metres; the pelvis trajectory
puts the body's hip joints on the BVH thigh joints (see :func:`retarget_bvh`). The scale is 0.01 m per file unit: checked on the data,
this gives a walking hip height of 0.82-0.87 m and a walk ratio (step length / cadence) of
0.0058-0.0066 m/(steps/min) on the normal walks, the adult norm.

Left/right and facing are checked on the rest frame: the figure's left (lThigh - rThigh) crossed with up
must point the same way as its eyes (head End Sites); otherwise :class:`RetargetError`.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.keypoints import SMPL_JOINTS, SMPL_PARENTS
from pedx_graph.motion.bvh import BvhMotion, forward_kinematics, read_bvh
from pedx_graph.motion.clips import MotionClip

#: SMPL joint name -> CMU Daz-skeleton joint whose rotation it takes (rest-relative).
CMU_TO_SMPL: dict[str, str] = {
    "pelvis": "hip", "spine1": "abdomen", "spine3": "chest", "neck": "neck", "head": "head",
    "left_hip": "lThigh", "left_knee": "lShin", "left_ankle": "lFoot",
    "right_hip": "rThigh", "right_knee": "rShin", "right_ankle": "rFoot",
    "left_shoulder": "lShldr", "left_elbow": "lForeArm", "left_wrist": "lHand",
    "right_shoulder": "rShldr", "right_elbow": "rForeArm", "right_wrist": "rHand",
}

#: SMPL joints whose *position* corresponds anatomically to a CMU joint's origin (used for the error).
CMU_POSITION_PAIRS: dict[str, str] = {
    "pelvis": "hip", "neck": "neck", "head": "head",
    "left_hip": "lThigh", "left_knee": "lShin", "left_ankle": "lFoot",
    "right_hip": "rThigh", "right_knee": "rShin", "right_ankle": "rFoot",
    "left_shoulder": "lShldr", "left_elbow": "lForeArm", "left_wrist": "lHand",
    "right_shoulder": "rShldr", "right_elbow": "rForeArm", "right_wrist": "rHand",
}

#: Metres per CMU Daz-BVH unit (see module docstring).
CMU_BVH_SCALE = 0.01


class RetargetError(ValueError):
    """The source skeleton cannot be retargeted (missing joints, mirrored figure...)."""


def _yaw_matrix(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rest_facing_yaw(motion: BvhMotion) -> float:
    """Yaw angle (radians, about +Y) that turns the rest frame's facing direction onto +Z.

    Facing = horizontal part of ``(p_lThigh - p_rThigh) x Y``; confirmed against the eyes (head End Sites),
    which must lie in front of the head. Raises :class:`RetargetError` if they disagree (a mirrored figure).
    """
    sk = motion.skeleton
    rest = motion.rest_channels if motion.rest_channels is not None else motion.channels[0]
    _, pos = forward_kinematics(sk, rest[None], with_end_sites=True)
    pos = pos[0]
    left = pos[sk.index("lThigh")] - pos[sk.index("rThigh")]
    facing = np.cross(left, [0.0, 1.0, 0.0])
    facing[1] = 0.0
    norm = np.linalg.norm(facing)
    if norm < 1e-9:
        raise RetargetError(f"{motion.source}: cannot find the rest facing direction (hips coincide)")
    facing /= norm
    eyes = [sk.index(n) for n in ("leftEye", "rightEye") if n in sk.names]
    if eyes:
        eye_mid = np.mean([pos[e] for e in eyes], axis=0)
        if np.dot(eye_mid - pos[sk.index("head")], facing) <= 0:
            raise RetargetError(f"{motion.source}: eyes are behind the head for the facing given by "
                                "left/right hips; left and right may be swapped (mirrored skeleton)")
    # yaw psi with Ry(psi) @ facing = +Z  ->  psi = -atan2(fx, fz)
    return float(-np.arctan2(facing[0], facing[2]))


def _log(rot: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(rot.reshape(-1, 3, 3)).as_rotvec().reshape(rot.shape[:-2] + (3,))


def _exp(vec: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(vec.reshape(-1, 3)).as_matrix().reshape(vec.shape[:-1] + (3, 3))


#: Bones aligned at rest by :func:`smpl_world_rotations`: SMPL joint -> (BVH joint, BVH child joint or
#: ``"<joint>:end"`` for its End Site), the bone from the SMPL joint to its only child.
ALIGNED_BONES: dict[str, tuple[str, str]] = {
    "left_hip": ("lThigh", "lShin"), "left_knee": ("lShin", "lFoot"), "left_ankle": ("lFoot", "lFoot:end"),
    "right_hip": ("rThigh", "rShin"), "right_knee": ("rShin", "rFoot"), "right_ankle": ("rFoot", "rFoot:end"),
    "left_shoulder": ("lShldr", "lForeArm"), "left_elbow": ("lForeArm", "lHand"),
    "right_shoulder": ("rShldr", "rForeArm"), "right_elbow": ("rForeArm", "rHand"),
    "neck": ("neck", "head"),
}
_SMPL_CHILD = {"left_hip": "left_knee", "left_knee": "left_ankle", "left_ankle": "left_foot",
               "right_hip": "right_knee", "right_knee": "right_ankle", "right_ankle": "right_foot",
               "left_shoulder": "left_elbow", "left_elbow": "left_wrist",
               "right_shoulder": "right_elbow", "right_elbow": "right_wrist", "neck": "head"}


def _align(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """Smallest rotation (3, 3) turning direction ``src`` onto direction ``dst``."""
    a, b = src / np.linalg.norm(src), dst / np.linalg.norm(dst)
    axis = np.cross(a, b)
    sin_t, cos_t = np.linalg.norm(axis), float(a @ b)
    if sin_t < 1e-12:
        if cos_t > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0, 0] if abs(a[0]) < 0.9 else [0, 1.0, 0])
        return _exp(np.pi * perp / np.linalg.norm(perp))
    return _exp(axis / sin_t * np.arctan2(sin_t, cos_t))


def rest_alignment(motion: BvhMotion, rest_joints: np.ndarray, axes_R_bvh: np.ndarray,
                   scale: float = CMU_BVH_SCALE) -> dict[int, np.ndarray]:
    """Per SMPL joint of :data:`ALIGNED_BONES`, the rotation ``A_j`` turning the body's rest bone
    (``J_child - J_j``) onto the BVH rest bone (clip axes). Only the direction matters."""
    sk = motion.skeleton
    rest = motion.rest_channels if motion.rest_channels is not None else motion.channels[0]
    rot, pos = forward_kinematics(sk, rest[None])
    rot, pos = rot[0], pos[0]
    out = {}
    for name, (b, child) in ALIGNED_BONES.items():
        if child.endswith(":end"):
            owner = sk.index(child[:-4])
            if owner not in sk.end_site_offsets:
                continue
            child_pos = pos[owner] + rot[owner] @ sk.end_site_offsets[owner]
        else:
            child_pos = pos[sk.index(child)]
        bvh_dir = axes_R_bvh @ (child_pos - pos[sk.index(b)])
        j, c = SMPL_JOINTS.index(name), SMPL_JOINTS.index(_SMPL_CHILD[name])
        out[j] = _align(rest_joints[c] - rest_joints[j], bvh_dir)
    return out


def smpl_world_rotations(motion: BvhMotion, axes_R_bvh: np.ndarray,
                         alignment: dict[int, np.ndarray] | None = None) -> np.ndarray:
    """(T, 24, 3, 3) SMPL world rotations by the rest-relative transfer (module docstring).

    ``alignment`` (from :func:`rest_alignment`) right-multiplies the transferred rotation of those joints,
    ``world_R_j(t) = C bvhworld_R_b(t) bvhworld_R_b(0)^T C^T A_j``, so the body's bone points exactly
    along the BVH bone even where the two rest poses differ (e.g. the Daz forearms point 17 deg forward).
    """
    sk = motion.skeleton
    missing = [b for b in CMU_TO_SMPL.values() if b not in sk.names]
    if missing:
        raise RetargetError(f"{motion.source}: BVH lacks joint(s) {missing} needed for the CMU->SMPL map")
    rest = motion.rest_channels if motion.rest_channels is not None else motion.channels[0]
    bvh_rot, _ = forward_kinematics(sk, motion.channels)
    bvh_rest, _ = forward_kinematics(sk, rest[None])
    n = motion.num_frames
    world = np.empty((n, 24, 3, 3))
    done = [False] * 24
    for j, name in enumerate(SMPL_JOINTS):
        if name in CMU_TO_SMPL:
            b = sk.index(CMU_TO_SMPL[name])
            world[:, j] = axes_R_bvh @ bvh_rot[:, b] @ bvh_rest[0, b].T @ axes_R_bvh.T
            if alignment and j in alignment:
                world[:, j] = world[:, j] @ alignment[j]
            done[j] = True
    # spine2: half-way between spine1 and the chest (spine3)
    s1, s2, s3 = (SMPL_JOINTS.index(n) for n in ("spine1", "spine2", "spine3"))
    rel = np.swapaxes(world[:, s1], -1, -2) @ world[:, s3]
    world[:, s2] = world[:, s1] @ _exp(0.5 * _log(rel))
    done[s2] = True
    for j, parent in enumerate(SMPL_PARENTS):
        if not done[j]:
            world[:, j] = world[:, parent]
            done[j] = True
    return world


def local_from_world(world_R_joint: np.ndarray) -> np.ndarray:
    """(T, 24, 3, 3) ``parent_R_joint = world_R_parent^T world_R_joint`` (joint 0 keeps its world rotation)."""
    local = world_R_joint.copy()
    for j, parent in enumerate(SMPL_PARENTS):
        if parent >= 0:
            local[:, j] = np.swapaxes(world_R_joint[:, parent], -1, -2) @ world_R_joint[:, j]
    return local


def retarget_bvh(motion: BvhMotion, *, scale: float = CMU_BVH_SCALE, rest_joints: np.ndarray | None = None,
                 align_bones: bool = True, name: str | None = None, meta: dict | None = None) -> MotionClip:
    """Retarget a parsed CMU BVH motion to a :class:`MotionClip` (SMPL tree, metres, Y up).

    Pelvis placement: the Daz root ``hip`` is not where SMPL's pelvis joint is (it sits 2.6 cm *below*
    the thigh joints, SMPL's pelvis ~8 cm above the hip joints), so the pelvis is placed to put the body's
    hip joints on the BVH thigh joints::

        pelvis_world(t) = scale * C @ mid(p_lThigh, p_rThigh)(t) + world_R_pelvis(t) @ (J_pelvis - mid(J_lhip, J_rhip))

    with ``J = rest_joints`` (24, 3), e.g. ``J(betas)`` of the body that will play the clip (default
    :func:`generic_rest_joints`). ``meta["hip_height_rest_m"]`` is the BVH figure's rest height of the hip
    joints above its lowest foot point: ``clip.rescaled(body_hip_height / meta["hip_height_rest_m"])`` fits the
    motion to a body of another leg length.

    ``align_bones``: also turn each limb bone of the body's rest pose onto the BVH rest bone
    (:func:`rest_alignment`), so the poses are right for *this* rest skeleton, not only for the Daz one.
    """
    if motion.rest_channels is None:
        raise RetargetError(f"{motion.source}: the rest-relative transfer needs the T-pose frame; "
                            "read the file with drop_first_frame=True")
    yaw = rest_facing_yaw(motion)
    axes_R_bvh = _yaw_matrix(yaw)
    sk = motion.skeleton
    rest_j = generic_rest_joints() if rest_joints is None else np.asarray(rest_joints, dtype=float)
    if rest_j.shape != (24, 3):
        raise ValueError(f"rest_joints must be (24, 3), got {rest_j.shape}")
    alignment = rest_alignment(motion, rest_j, axes_R_bvh, scale) if align_bones else None
    world = smpl_world_rotations(motion, axes_R_bvh, alignment)
    local = local_from_world(world)
    pose = _log(local).reshape(motion.num_frames, 72)
    i_lh, i_rh = SMPL_JOINTS.index("left_hip"), SMPL_JOINTS.index("right_hip")
    pelvis_from_hips = rest_j[0] - 0.5 * (rest_j[i_lh] + rest_j[i_rh])
    _, bvh_pos = forward_kinematics(sk, motion.channels)
    hips_mid = 0.5 * (bvh_pos[:, sk.index("lThigh")] + bvh_pos[:, sk.index("rThigh")])
    pelvis = scale * hips_mid @ axes_R_bvh.T + world[:, 0] @ pelvis_from_hips
    _, rest_pos = forward_kinematics(sk, motion.rest_channels[None], with_end_sites=True)
    feet = [sk.num_joints + k for k, j in enumerate(sorted(sk.end_site_offsets)) if "Foot" in sk.names[j]]
    sole = min([rest_pos[0, f, 1] for f in feet] + [rest_pos[0, sk.index("lFoot"), 1], rest_pos[0, sk.index("rFoot"), 1]])
    hip_height = scale * (0.5 * (rest_pos[0, sk.index("lThigh"), 1] + rest_pos[0, sk.index("rThigh"), 1]) - sole)
    clip_name = name or Path(motion.source).name.removesuffix(".bvh")
    return MotionClip(name=clip_name, fps=motion.fps, body_pose_aa=pose, pelvis_world=pelvis,
                      source=Path(motion.source).name, floor_y=0.0,
                      meta={"scale_m_per_unit": scale, "rest_yaw_rad": yaw,
                            "hip_height_rest_m": float(hip_height), **(meta or {})})


#: Motion frames skipped at the start of every CMU clip: after the T-pose frame 0, the converter blends
#: from the T-pose into the motion over ~8 frames at 120 fps (arms swing down by 60-90 degrees, up to
#: 25 degrees per frame, with an overshoot); this is not motion.
CMU_SETTLE_FRAMES = 10


def load_cmu_clip(path: str | os.PathLike, *, skip_start: int = CMU_SETTLE_FRAMES, **kwargs) -> MotionClip:
    """Read a CMU BVH file, retarget it (:func:`retarget_bvh`) and drop the converter's transient.

    Frame 0 (T-pose) is removed by :func:`read_bvh` and used as the rest reference; then the first
    ``skip_start`` motion frames (:data:`CMU_SETTLE_FRAMES`) are dropped.
    """
    clip = retarget_bvh(read_bvh(path, drop_first_frame=True), **kwargs)
    if skip_start >= clip.num_frames - 1:
        raise RetargetError(f"{path}: clip has {clip.num_frames} frames, cannot skip {skip_start}")
    return clip.slice(skip_start).with_updates(meta={**clip.meta, "skipped_start_frames": skip_start})


# ----------------------------------------------------------------------------------------------------
# Joint forward kinematics on SMPL's tree (for checks and the procedural gait; no mesh needed)
# ----------------------------------------------------------------------------------------------------

def generic_rest_joints(height: float = 1.70) -> np.ndarray:
    """(24, 3) rest (T-pose) joint positions of a generic adult, pelvis at the origin, SMPL axes, metres.

    Hand-made from textbook segment proportions of stature (not from any body-model file); used when no
    body model is given. The soles are at ``y = -0.53 * height`` (pelvis height 0.53 * stature).
    """
    s = height / 1.70
    left = {
        "left_hip": (0.085, -0.075, 0.0), "left_knee": (0.095, -0.47, 0.01),
        "left_ankle": (0.085, -0.83, -0.03), "left_foot": (0.10, -0.88, 0.10),
        "left_collar": (0.07, 0.43, -0.01), "left_shoulder": (0.175, 0.455, -0.02),
        "left_elbow": (0.44, 0.455, -0.03), "left_wrist": (0.69, 0.455, -0.03),
        "left_hand": (0.77, 0.455, -0.03),
    }
    mid = {"pelvis": (0.0, 0.0, 0.0), "spine1": (0.0, 0.11, -0.01), "spine2": (0.0, 0.235, 0.0),
           "spine3": (0.0, 0.29, 0.0), "neck": (0.0, 0.52, -0.02), "head": (0.0, 0.60, 0.03)}
    out = np.zeros((24, 3))
    for j, name in enumerate(SMPL_JOINTS):
        if name in mid:
            out[j] = mid[name]
        elif name.startswith("left_"):
            out[j] = left[name]
        else:
            x, y, z = left["left_" + name[len("right_"):]]
            out[j] = (-x, y, z)
    return out * s


#: Sole height below the pelvis for :func:`generic_rest_joints`, as a fraction of the stature.
GENERIC_PELVIS_HEIGHT_FRACTION = 0.53


def smpl_joint_positions(rest_joints: np.ndarray, body_pose_aa: np.ndarray,
                         pelvis_world: np.ndarray) -> np.ndarray:
    """World joint positions by forward kinematics of SMPL's tree (no skinning, no pose blend shapes).

    ``world_p_j = world_p_parent + world_R_parent @ (J_j - J_parent)``, ``world_p_0 = pelvis_world``,
    ``world_R_j = world_R_parent @ Exp(pose_j)``. ``rest_joints`` (24, 3), ``body_pose_aa`` (T, 72),
    ``pelvis_world`` (T, 3) -> (T, 24, 3). Same joints as LBS evaluated with ``trans = pelvis_world - J_0``.
    """
    rest = np.asarray(rest_joints, dtype=float)
    aa = np.asarray(body_pose_aa, dtype=float).reshape(-1, 24, 3)
    local = _exp(aa)
    n = aa.shape[0]
    world_R = np.empty((n, 24, 3, 3))
    world_p = np.empty((n, 24, 3))
    for j, parent in enumerate(SMPL_PARENTS):
        if parent < 0:
            world_R[:, j] = local[:, j]
            world_p[:, j] = pelvis_world
        else:
            world_R[:, j] = world_R[:, parent] @ local[:, j]
            world_p[:, j] = world_p[:, parent] + world_R[:, parent] @ (rest[j] - rest[parent])
    return world_p


# ----------------------------------------------------------------------------------------------------
# Retargeting error
# ----------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class RetargetErrorReport:
    """Per-clip joint position error of a retargeted clip (see :func:`retarget_joint_error`)."""

    mean_mm: float
    """Mean over frames and compared joints (pelvis excluded: equal by construction), millimetres."""
    max_mm: float
    """Largest single joint error, millimetres."""
    per_joint_mm: dict[str, float]
    """Mean error per compared SMPL joint, millimetres."""
    local_mean_mm: float = float("nan")
    """Mean error of each joint's offset from its nearest compared ancestor (``|(p_j - p_a) - (q_j - q_a)|``),
    millimetres: the pose transfer bone by bone, without the rest-geometry offsets that accumulate along
    the chain (e.g. a different shoulder width moves the whole arm)."""


def _bvh_rest_positions(motion: BvhMotion, scale: float) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """BVH rest-frame joint positions (clip axes, metres) keyed by BVH name, plus all (J, 3)."""
    sk = motion.skeleton
    rest = motion.rest_channels if motion.rest_channels is not None else motion.channels[0]
    _, pos = forward_kinematics(sk, rest[None])
    pos = scale * pos[0] @ _yaw_matrix(rest_facing_yaw(motion)).T
    return pos, {n: pos[i] for i, n in enumerate(sk.names)}


def scaled_rest_joints(rest_joints: np.ndarray, motion: BvhMotion, scale: float = CMU_BVH_SCALE) -> np.ndarray:
    """Rest joints whose bone lengths match the BVH rest frame, bone directions kept from ``rest_joints``.

    The hip offsets (pelvis -> left/right hip) are scaled so the hip width equals the BVH thigh-joint
    distance; the BVH figure then gets a virtual pelvis at ``mid(thighs) + (J_pelvis - mid(J_hips))``.
    For every other SMPL joint with a position counterpart (:data:`CMU_POSITION_PAIRS`), the chain of rest
    offsets from its nearest corresponding ancestor is scaled so the chain's end-to-end distance equals
    the BVH distance; offsets already fixed by an earlier chain keep their scale (the remaining factor
    solves ``|A + s B| = D``). Other offsets keep the scale of their parent's offset. Pelvis at the origin.
    """
    rest_joints = np.asarray(rest_joints, dtype=float)
    _, bvh = _bvh_rest_positions(motion, scale)
    offsets = np.zeros((24, 3))
    for j, parent in enumerate(SMPL_PARENTS):
        if parent >= 0:
            offsets[j] = rest_joints[j] - rest_joints[parent]
    i_lh, i_rh = SMPL_JOINTS.index("left_hip"), SMPL_JOINTS.index("right_hip")
    factor = np.full(24, np.nan)
    factor[0] = 1.0
    width = np.linalg.norm(rest_joints[i_lh] - rest_joints[i_rh])
    factor[[i_lh, i_rh]] = np.linalg.norm(bvh["lThigh"] - bvh["rThigh"]) / max(width, 1e-9)
    target_pos = {name: bvh[b] for name, b in CMU_POSITION_PAIRS.items()}
    target_pos["pelvis"] = 0.5 * (bvh["lThigh"] + bvh["rThigh"]) - 0.5 * factor[i_lh] * (offsets[i_lh] + offsets[i_rh])
    for j in range(24):
        name = SMPL_JOINTS[j]
        if j == 0 or name not in CMU_POSITION_PAIRS or np.isfinite(factor[j]):
            continue
        chain = [j]
        while SMPL_JOINTS[SMPL_PARENTS[chain[-1]]] not in CMU_POSITION_PAIRS:
            chain.append(SMPL_PARENTS[chain[-1]])
        anc = SMPL_JOINTS[SMPL_PARENTS[chain[-1]]]
        target = np.linalg.norm(target_pos[name] - target_pos[anc])
        fixed = sum((factor[k] * offsets[k] for k in chain if np.isfinite(factor[k])), np.zeros(3))
        free = sum((offsets[k] for k in chain if not np.isfinite(factor[k])), np.zeros(3))
        a, b, c = free @ free, 2 * fixed @ free, fixed @ fixed - target ** 2
        if a < 1e-12:
            continue
        s = (-b + np.sqrt(max(b * b - 4 * a * c, 0.0))) / (2 * a)
        for k in chain:
            if not np.isfinite(factor[k]):
                factor[k] = s
    for j, parent in enumerate(SMPL_PARENTS):
        if not np.isfinite(factor[j]):
            factor[j] = factor[parent] if parent >= 0 else 1.0
    out = np.zeros((24, 3))
    for j, parent in enumerate(SMPL_PARENTS):
        if parent >= 0:
            out[j] = out[parent] + factor[j] * offsets[j]
    return out


def bvh_rest_joints(motion: BvhMotion, scale: float = CMU_BVH_SCALE) -> np.ndarray:
    """(24, 3) SMPL rest joints taken from the BVH rest frame itself (clip axes, metres).

    Mapped joints sit at their BVH counterparts, the pelvis at the Daz ``hip`` node, spine1 at the
    abdomen, spine2 and spine3 at the chest (so the split spine reproduces the chest position), collars
    at the BVH collars, hands/feet a few cm beyond the wrists/ankles. With these rest joints,
    :func:`smpl_joint_positions` of the retargeted clip reproduces the BVH joints exactly: a consistency
    check of the transfer.
    """
    _, bvh = _bvh_rest_positions(motion, scale)
    out = np.zeros((24, 3))
    for j, name in enumerate(SMPL_JOINTS):
        if name in CMU_POSITION_PAIRS:
            out[j] = bvh[CMU_POSITION_PAIRS[name]]
    out[SMPL_JOINTS.index("spine1")] = bvh["abdomen"]
    out[SMPL_JOINTS.index("spine2")] = bvh["chest"]
    out[SMPL_JOINTS.index("spine3")] = bvh["chest"]
    for side, s in (("left", "l"), ("right", "r")):
        wrist = out[SMPL_JOINTS.index(f"{side}_wrist")]
        out[SMPL_JOINTS.index(f"{side}_collar")] = bvh[f"{s}Collar"]
        out[SMPL_JOINTS.index(f"{side}_hand")] = wrist + np.array([0.08 * np.sign(wrist[0] - out[0, 0]), 0, 0])
        out[SMPL_JOINTS.index(f"{side}_foot")] = out[SMPL_JOINTS.index(f"{side}_ankle")] + np.array([0, -0.03, 0.12])
    return out - out[0]


def retarget_joint_error(motion: BvhMotion, rest_joints: np.ndarray, *, scale: float = CMU_BVH_SCALE,
                         scale_bones: bool = True, align_bones: bool = True) -> RetargetErrorReport:
    """Joint position error between FK of the retargeted clip and the BVH's own joints.

    ``rest_joints`` (24, 3): the body's rest joints (e.g. ``J(betas)`` of a body model); with
    ``scale_bones`` they are first given the BVH bone lengths (:func:`scaled_rest_joints`), so the error
    measures the pose transfer (rest-pose mismatch, merged/split joints), not body size. Both sides are
    in the clip world (the clip is retargeted here with these rest joints); pairs are
    :data:`CMU_POSITION_PAIRS` without the pelvis.
    """
    rest = scaled_rest_joints(rest_joints, motion, scale) if scale_bones else np.asarray(rest_joints, float)
    clip = retarget_bvh(motion, scale=scale, rest_joints=rest, align_bones=align_bones)
    smpl_pos = smpl_joint_positions(rest, clip.body_pose_aa, clip.pelvis_world)
    _, bvh_pos = forward_kinematics(motion.skeleton, motion.channels)
    axes_R_bvh = _yaw_matrix(clip.meta.get("rest_yaw_rad", rest_facing_yaw(motion)))
    bvh_pos = scale * bvh_pos @ axes_R_bvh.T
    per_joint, worst, local = {}, 0.0, []
    for name, bname in CMU_POSITION_PAIRS.items():
        if name == "pelvis":
            continue
        j, b = SMPL_JOINTS.index(name), motion.skeleton.index(bname)
        d = np.linalg.norm(smpl_pos[:, j] - bvh_pos[:, b], axis=-1)
        per_joint[name] = 1000.0 * float(d.mean())
        worst = max(worst, 1000.0 * float(d.max()))
        a = SMPL_PARENTS[j]
        while SMPL_JOINTS[a] not in CMU_POSITION_PAIRS:
            a = SMPL_PARENTS[a]
        ab = motion.skeleton.index(CMU_POSITION_PAIRS[SMPL_JOINTS[a]])
        rel = (smpl_pos[:, j] - smpl_pos[:, a]) - (bvh_pos[:, b] - bvh_pos[:, ab])
        if SMPL_JOINTS[a] != "pelvis":      # the pelvis is not a BVH joint (placed from the hips)
            local.append(1000.0 * float(np.linalg.norm(rel, axis=-1).mean()))
    return RetargetErrorReport(float(np.mean(list(per_joint.values()))), worst, per_joint, float(np.mean(local)))
