"""Pedestrians: body shapes, motions and their placement on the crosswalks and sidewalks.

Placement of a motion clip (:class:`pedx_graph.motion.clips.MotionClip`, clip world Y up, floor
``y = floor_y``) in the world (the sim frame: LiDAR at the origin, +z against gravity)::

    world_R_clip = Rz(psi - phi_clip) @ A,      A = [[0, 0, 1], [1, 0, 0], [0, 1, 0]]
    world_R_pelvis(t) = world_R_clip @ clip_R_pelvis(t)          -> pose[t, :3] = Log(world_R_pelvis(t))
    world_pelvis(t) = world_R_clip @ (clip_pelvis(t) - anchor) + (x_a, y_a, ground_z)
    trans(t) = world_pelvis(t) - J_0(betas) + (0, 0, dz(t))

``A`` maps the clip's +Y (up) to sim-frame +z and its +Z to world +x; ``phi_clip`` is the heading (in the world
after ``A``) of the clip's net horizontal displacement and ``psi`` the walking direction on the walkway;
``anchor`` is the clip pelvis at the middle frame, projected to the floor.  ``dz(t)`` puts the lowest
vertex of the body on the ground at every frame (a walker always has a foot down), absorbing differences
between the clip's and the body's leg lengths (clips are first rescaled by the hip-height ratio).

Motions come either from BVH clips (CMU, the hold-out split by default; short clips are looped on their
most similar pair of poses one or more gait cycles apart) or from the procedural gait of
:mod:`pedx_graph.motion`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from pedx_graph.sim.config import SimConfig
from pedx_graph.sim.scene import StaticScene, Walkway

logger = logging.getLogger(__name__)

#: Clip world (Y up, +Z forward) -> sim frame (+z against gravity): clip +Z -> sim +x, clip +Y -> sim +z,
#: clip +X -> sim +y.
WORLD_R_CLIPAXES = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


@dataclass
class Pedestrian:
    """Ground truth of one simulated pedestrian over the sequence (world = the sim frame, +z against gravity)."""

    tracking_id: str
    """32-hex tracking id shared by the 2D, segment and SMPL files."""
    betas: np.ndarray
    """(10,) body shape."""
    pose: np.ndarray
    """(F, 72) axis-angle pose per frame, ``pose[:, :3]`` = world orientation of the pelvis."""
    trans: np.ndarray
    """(F, 3) SMPL ``trans`` per frame (pelvis = J_0(betas) + trans), metres."""
    present: np.ndarray
    """(F,) bool: the person is in the scene at that frame (on its walkway)."""
    walkway: str
    """Name of the walkway walked on."""
    group: int
    """Index of the group (people of one group walk together)."""
    motion: str
    """Motion clip name (or procedural gait description)."""
    rest_pelvis: np.ndarray
    """(3,) J_0(betas), the rest pelvis joint (pelvis = rest_pelvis + trans)."""
    object_id: int = -1
    """Scene object id (set when the pedestrian is added to the scene)."""

    @property
    def world_pelvis_xy(self) -> np.ndarray:
        """(F, 2) horizontal pelvis position per frame."""
        return self.trans[:, :2] + self.rest_pelvis[:2]


# ------------------------------------------------------------------------------------------ motions


def loop_points(body_pose_aa: np.ndarray, min_period: int) -> tuple[int, int]:
    """Frames ``(i, j)``, ``j - i >= min_period``, whose poses (and next-frame poses) are most alike.

    Distance: ``|P_i - P_j|^2 + |P_{i+1} - P_{j+1}|^2`` over the 72-d axis-angle (root included), with
    ``i`` in the first third of the clip.  Looping frames ``[i, j)`` repeats the motion seamlessly up to
    that distance.
    """
    n = len(body_pose_aa)
    if n < min_period + 2:
        raise ValueError(f"clip of {n} frames is too short to loop with a period of >= {min_period} frames")
    best, best_ij = np.inf, (0, n - 2)
    for i in range(0, max(1, min(n // 3, n - min_period - 1))):
        js = np.arange(i + min_period, n - 1)
        if len(js) == 0:
            break
        d = (np.sum((body_pose_aa[js] - body_pose_aa[i]) ** 2, axis=1)
             + np.sum((body_pose_aa[js + 1] - body_pose_aa[i + 1]) ** 2, axis=1))
        k = int(np.argmin(d))
        if d[k] < best:
            best, best_ij = float(d[k]), (i, int(js[k]))
    return best_ij


def loop_clip(clip, n_frames: int, start: int = 0):
    """A clip of ``n_frames`` frames repeating the clip's loop ``[i, j)`` (:func:`loop_points`).

    Repetition ``c`` is shifted horizontally by ``c`` times the loop's pelvis displacement; ``start``
    offsets the phase (frames into the loop).
    """
    i, j = loop_points(clip.body_pose_aa, min_period=max(2, int(round(0.8 * clip.fps))))
    period = j - i
    k = np.arange(n_frames) + start
    cycle, phase = k // period, k % period
    delta = clip.pelvis_world[j] - clip.pelvis_world[i]
    delta[1] = 0.0
    pose = clip.body_pose_aa[i + phase]
    pelvis = clip.pelvis_world[i + phase] + cycle[:, None] * delta
    return clip.with_updates(body_pose_aa=pose, pelvis_world=pelvis,
                             meta={**clip.meta, "loop": [int(i), int(j)], "loop_start": int(start)})


class BvhClipSource:
    """Walking motions from a folder of CMU BVH clips (``clips.csv`` index), retargeted per body."""

    def __init__(self, motion_dir: str | Path, split: str = "holdout", categories: tuple[str, ...] = ("walk",)):
        from pedx_graph.motion.clips import list_clips

        infos = [c for c in list_clips(motion_dir, split=split) if c.category in categories]
        if not infos:
            raise FileNotFoundError(f"{motion_dir}: no clips of categories {list(categories)} in split {split!r}")
        self.infos = sorted(infos, key=lambda c: c.name)
        self._parsed: dict[str, object] = {}

    def draw(self, rng: np.random.Generator, n_frames: int, fps: float, rest_joints: np.ndarray,
             hip_height_m: float, speed_mps: float):
        """A clip at ``fps`` with ``n_frames`` frames, fitted to a body (rest joints, hip height)."""
        from pedx_graph.motion.bvh import read_bvh
        from pedx_graph.motion.resample import resample_clip
        from pedx_graph.motion.retarget import retarget_bvh

        info = self.infos[int(rng.integers(len(self.infos)))]
        mirror = bool(rng.random() < 0.5)
        phase = rng.random()
        if info.name not in self._parsed:
            self._parsed[info.name] = read_bvh(info.path, drop_first_frame=True)
        clip = retarget_bvh(self._parsed[info.name], rest_joints=rest_joints)
        clip = clip.rescaled(hip_height_m / clip.meta["hip_height_rest_m"])
        if mirror:
            clip = clip.mirrored()
        duration = (n_frames - 1) / fps
        n_src = int(np.ceil(duration * clip.fps)) + 2
        i, j = loop_points(clip.body_pose_aa, min_period=max(2, int(round(0.8 * clip.fps))))
        looped = loop_clip(clip, n_src, start=int(phase * (j - i)))
        out = resample_clip(looped, fps, duration=duration, drop_repeated=False)
        return out.with_updates(name=clip.name)


class GaitClipSource:
    """Procedural walking from :func:`pedx_graph.motion.gait.procedural_gait` (any duration and speed)."""

    def draw(self, rng: np.random.Generator, n_frames: int, fps: float, rest_joints: np.ndarray,
             hip_height_m: float, speed_mps: float):
        from pedx_graph.motion.gait import procedural_gait

        seed = int(rng.integers(2**31))
        speed = float(np.clip(speed_mps, 0.3, 2.2))
        return procedural_gait("walk", speed, duration=(n_frames - 1) / fps, fps=fps, rest_joints=rest_joints,
                               seed=seed, name=f"gait-walk-{speed:.2f}-{seed}")


def make_clip_source(config: SimConfig):
    """The motion source of a config: BVH clips when ``motion.motion_dir`` is set, else the procedural gait."""
    if config.motion.motion_dir:
        return BvhClipSource(config.motion.motion_dir, config.motion.split, tuple(config.motion.categories))
    return GaitClipSource()


# ---------------------------------------------------------------------------------------- placement


def _rot_z(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def place_clip(clip_pose: np.ndarray, clip_pelvis: np.ndarray, floor_y: float, heading_rad: float,
               anchor_xy: np.ndarray, ground_z: float, rest_pelvis: np.ndarray,
               anchor_frame: int) -> tuple[np.ndarray, np.ndarray]:
    """World ``(pose (F, 72), trans (F, 3))`` of a clip walking along ``heading_rad`` (see module docstring).

    The pelvis at ``anchor_frame`` lands above ``anchor_xy`` at its clip height above the floor.
    """
    disp = WORLD_R_CLIPAXES @ (clip_pelvis[-1] - clip_pelvis[0])
    phi_clip = float(np.arctan2(disp[1], disp[0])) if np.hypot(disp[0], disp[1]) > 0.2 else 0.0
    world_R_clip = _rot_z(heading_rad - phi_clip) @ WORLD_R_CLIPAXES
    pose = clip_pose.copy()
    clip_R_pelvis = Rotation.from_rotvec(clip_pose[:, :3]).as_matrix()
    pose[:, :3] = Rotation.from_matrix(world_R_clip @ clip_R_pelvis).as_rotvec()
    anchor = clip_pelvis[anchor_frame].copy()
    anchor[1] = floor_y
    world_pelvis = (clip_pelvis - anchor) @ world_R_clip.T + np.array([anchor_xy[0], anchor_xy[1], ground_z])
    return pose, world_pelvis - rest_pelvis


def _walkway_coords(walkway: Walkway, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(along, across) coordinates of (..., 2) points relative to a walkway's centre line."""
    d = walkway.direction
    rel = xy - walkway.start_xy
    return rel @ d, rel @ np.array([-d[1], d[0]])


def _in_some_view(xy: np.ndarray, pair_yaws: list[tuple[float, float]], margin_deg: float = 3.0,
                  every_pair: bool = False) -> bool:
    """The bearing of ``xy`` lies within ``half_fov - margin`` of some pair's yaw (``pair_yaws``: (yaw, half
    horizontal field of view), degrees, sim frame); with ``every_pair``: of every pair's."""
    bearing = np.degrees(np.arctan2(xy[1], xy[0]))
    inside = [abs((bearing - yaw + 180.0) % 360.0 - 180.0) <= half_fov - margin_deg for yaw, half_fov in pair_yaws]
    return all(inside) if every_pair else any(inside)


def _pair_yaws(config: SimConfig) -> list[tuple[float, float]]:
    """(yaw, half horizontal field of view) of each pair's left camera, degrees, in the sim frame."""
    from pedx_graph.sim.cameras import rig_calibrations, sim_yaw_deg

    out = []
    for pair, calib in zip(config.cameras.pairs(), rig_calibrations(config).values()):
        yaw = pair.yaw_deg if pair.optical_axis is None else sim_yaw_deg(calib)
        out.append((yaw, float(np.degrees(np.arctan2(pair.image_size[0] / 2.0, pair.focal_px)))))
    return out


def _random_tracking_id(rng: np.random.Generator) -> str:
    return rng.bytes(16).hex()


def plan_pedestrians(config: SimConfig, scene: StaticScene, body_model, rng: np.random.Generator,
                     clip_source=None) -> list[Pedestrian]:
    """Draw ``scene.n_pedestrians`` pedestrians (shapes, motions, walkways, groups) for the sequence.

    ``body_model`` is a :class:`pedx_graph.body.BodyModel`; the returned poses/trans are in the world frame
    with the feet on the ground at every frame.
    """
    sc, lab = config.scene, config.labels
    n_frames = sc.n_frames
    if clip_source is None:
        clip_source = make_clip_source(config)
    walkways = scene.walkways
    crosswalks = [w for w in walkways if w.kind == "crosswalk"]
    sidewalks = [w for w in walkways if w.kind == "sidewalk"]
    anchor_frame = n_frames // 2
    pair_yaws = _pair_yaws(config)
    people: list[Pedestrian] = []
    group = -1
    lead = None   # (walkway, sign, along, across, speed) of the current group's first member
    n_in_group = 0
    group_size = 1
    for _ in range(sc.n_pedestrians):
        betas = np.clip(rng.standard_normal(body_model.num_betas), -sc.beta_clip, sc.beta_clip)
        tracking_id = _random_tracking_id(rng)
        rest = body_model.forward(np.zeros(72), betas)
        rest_joints = rest.joints
        sole_y = float(rest.vertices[:, 1].min())
        hip_height = float(0.5 * (rest_joints[1, 1] + rest_joints[2, 1]) - sole_y)
        new_group = lead is None or n_in_group >= group_size
        if new_group and sc.all_views_prob > 0:      # no draw when off: the default stream is unchanged
            every_pair = bool(rng.random() < sc.all_views_prob)
        elif new_group:
            every_pair = False
        if new_group:
            group += 1
            n_in_group = 0
            group_size = int(rng.choice([2, 3])) if rng.random() < sc.group_prob else 1
            speed = float(np.clip(rng.normal(sc.speed_mean_mps, sc.speed_std_mps), 0.6, 2.0))
        else:
            speed = lead[4] * float(rng.uniform(0.97, 1.03))
        clip = clip_source.draw(rng, n_frames, sc.fps, rest_joints, hip_height, speed)
        pose_c, pelvis_c = clip.body_pose_aa[:n_frames], clip.pelvis_world[:n_frames]
        if len(pose_c) < n_frames:
            raise ValueError(f"motion clip {clip.name} gave {len(pose_c)} frames, {n_frames} needed")

        for attempt in range(200):
            if new_group:
                pool = crosswalks if rng.random() < sc.crosswalk_prob else sidewalks
                walkway = pool[int(rng.integers(len(pool)))]
                sign = 1.0 if rng.random() < 0.5 else -1.0
                # keep the whole path on the walkway when it fits (the anchor is the middle frame)
                half_path = 0.5 * speed * (n_frames - 1) / sc.fps + 0.5
                if walkway.length_m > 2 * half_path:
                    along = rng.uniform(half_path, walkway.length_m - half_path)
                else:
                    along = rng.uniform(0.0, walkway.length_m)
                across = rng.uniform(-0.6, 0.6) * walkway.half_width_m
            else:
                walkway, sign = lead[0], lead[1]
                along = lead[2] + rng.uniform(-1.5, 1.5)
                across = float(np.clip(lead[3] + rng.choice([-1, 1]) * rng.uniform(0.55, 0.8),
                                       -walkway.half_width_m, walkway.half_width_m))
            d = walkway.direction
            anchor_xy = walkway.start_xy + along * d + across * np.array([-d[1], d[0]])
            dist = float(np.hypot(*anchor_xy))
            ok_range = lab.min_distance_m + 1.0 <= dist <= lab.max_distance_m - 1.0
            if new_group and sc.distance_std_m > 0:
                accept = np.exp(-0.5 * ((dist - sc.distance_mean_m) / sc.distance_std_m) ** 2)
                ok_range &= bool(rng.random() < accept)
            if not (ok_range and _in_some_view(anchor_xy, pair_yaws, every_pair=every_pair)) and attempt < 199:
                continue
            heading = float(np.arctan2(sign * d[1], sign * d[0]))
            rest_pelvis = rest_joints[0]
            pose, trans = place_clip(pose_c, pelvis_c, clip.floor_y, heading, anchor_xy, scene.ground_z,
                                     rest_pelvis, anchor_frame)
            xy = trans[:, :2] + rest_pelvis[:2]   # pelvis xy (J_0 = rest pelvis, unaffected by the root rotation)
            a_along, _ = _walkway_coords(walkway, xy)
            present = (a_along >= -1.0) & (a_along <= walkway.length_m + 1.0)
            if _collides(xy, present, people) and attempt < 199:
                continue
            break
        # feet on the ground at every frame (lowest foot vertex; walking always has a foot down)
        trans = trans.copy()
        trans[:, 2] += scene.ground_z - _lowest_foot_z(body_model, pose, betas, trans)
        if new_group:
            lead = (walkway, sign, along, across, speed)
        n_in_group += 1
        people.append(Pedestrian(tracking_id=tracking_id, betas=betas, pose=pose, trans=trans, present=present,
                                 walkway=walkway.name, group=group, motion=clip.name,
                                 rest_pelvis=np.asarray(rest_joints[0], dtype=float)))
    return people


#: SMPL joints whose skinning marks a vertex as part of a foot: ankles and feet.
_FOOT_JOINTS = (7, 8, 10, 11)


def _lowest_foot_z(body_model, pose: np.ndarray, betas: np.ndarray, trans: np.ndarray) -> np.ndarray:
    """(F,) lowest z of the foot vertices (skinning weight > 0.5 on ankles/feet), else of the whole mesh."""
    weights = getattr(getattr(body_model, "data", None), "weights", None)
    if weights is not None:
        foot = np.flatnonzero(np.asarray(weights)[:, _FOOT_JOINTS].sum(axis=1) > 0.5)
        if len(foot) >= 8:
            return body_model.vertices_subset(pose, betas, trans, foot)[..., 2].min(axis=-1)
    return body_model.forward(pose, betas, trans).vertices[..., 2].min(axis=-1)


def _collides(xy: np.ndarray, present: np.ndarray, people: list[Pedestrian], min_gap_m: float = 0.55) -> bool:
    """True when the path comes within ``min_gap_m`` of an already placed pedestrian at a shared frame."""
    for other in people:
        both = present & other.present
        if both.any():
            gap = np.linalg.norm(xy[both] - other.world_pelvis_xy[both], axis=-1)
            if gap.min() < min_gap_m:
                return True
    return False
