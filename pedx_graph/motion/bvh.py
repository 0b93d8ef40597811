"""Reading Biovision Hierarchy (BVH) motion files and their forward kinematics.

Conventions (the usual BVH semantics, stated here so the maths can be checked):

* A joint's local rotation is the product of its rotation channels **in the order they are listed**:
  channels ``Zrotation Xrotation Yrotation`` with angles (z, x, y) give
  ``parent_R_joint = Rz(z) @ Rx(x) @ Ry(y)`` (column vectors, angles in degrees in the file).
* Global transforms chain as ``world_T_joint = world_T_parent @ Trans(offset_joint) @ Rot(parent_R_joint)``,
  so ``world_p_joint = world_p_parent + world_R_parent @ offset_joint`` and
  ``world_R_joint = world_R_parent @ parent_R_joint``.
* The root's position channels are added to its OFFSET.
* Units are those of the file (the CMU "Daz-friendly" release is roughly centimetres, Y up).

Frame 0 of every CMU clip is a T-pose reference added by the converter; :func:`read_bvh` removes it from
the motion by default (``drop_first_frame=True``) and keeps it as :attr:`BvhMotion.rest_channels`, which
the retargeting uses as the rest reference.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: Channel names accepted in a CHANNELS line.
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")


class BvhError(ValueError):
    """A BVH file is malformed; the message names the file and the offending field."""


@dataclass(frozen=True)
class BvhSkeleton:
    """The HIERARCHY section of a BVH file.

    Joints are stored in file order (a parent always precedes its children). End Sites are not joints;
    their offsets are kept in :attr:`end_site_offsets` keyed by the joint that owns them.
    """

    names: tuple[str, ...]
    """Joint names, file order."""
    parents: tuple[int, ...]
    """Index of each joint's parent (-1 for the root)."""
    offsets: np.ndarray
    """(J, 3) OFFSET of each joint in its parent's frame, file units."""
    channels: tuple[tuple[str, ...], ...]
    """Channel names of each joint, in file order."""
    end_site_offsets: dict[int, np.ndarray] = field(default_factory=dict)
    """Joint index -> (3,) offset of the End Site attached to it."""

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @property
    def num_channels(self) -> int:
        return sum(len(c) for c in self.channels)

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (KeyError naming the known joints otherwise)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"BVH joint '{name}' not in skeleton (joints: {', '.join(self.names)})") from None

    def channel_slices(self) -> list[slice]:
        """Per joint, the slice of its channels within one frame's value row."""
        out, start = [], 0
        for ch in self.channels:
            out.append(slice(start, start + len(ch)))
            start += len(ch)
        return out


@dataclass(frozen=True)
class BvhMotion:
    """A parsed BVH file: skeleton plus the channel values of every frame."""

    skeleton: BvhSkeleton
    frame_time: float
    """Seconds between frames (``Frame Time:``)."""
    channels: np.ndarray
    """(T, C) channel values of the motion frames (file units, degrees)."""
    rest_channels: np.ndarray | None
    """(C,) values of the dropped first frame (the converter's T-pose) or None if it was kept."""
    source: str = ""
    """File the motion was read from."""

    @property
    def num_frames(self) -> int:
        return int(self.channels.shape[0])

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time


def _elementary(axis: str, angle_rad: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotation about a coordinate axis ('X', 'Y' or 'Z') by ``angle_rad``."""
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    out = np.zeros(angle_rad.shape + (3, 3))
    i = "XYZ".index(axis)
    j, k = (i + 1) % 3, (i + 2) % 3
    out[..., i, i] = 1.0
    out[..., j, j] = c
    out[..., k, k] = c
    out[..., k, j] = s
    out[..., j, k] = -s
    return out


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices from Euler angles applied in BVH order.

    ``angles_deg`` is (..., len(order)) degrees, ``order`` a string such as ``"ZXY"``; the result is
    ``R_order[0](a0) @ R_order[1](a1) @ ...`` with shape (..., 3, 3).
    """
    angles = np.deg2rad(np.asarray(angles_deg, dtype=float))
    if angles.shape[-1] != len(order):
        raise ValueError(f"euler_to_matrix: {angles.shape[-1]} angles for order {order!r}")
    rot = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for n, axis in enumerate(order):
        rot = rot @ _elementary(axis.upper(), angles[..., n])
    return rot


def _tokens(text: str):
    for line_no, line in enumerate(text.splitlines(), start=1):
        for tok in line.split():
            yield line_no, tok


def read_bvh(path: str | os.PathLike, *, drop_first_frame: bool = True) -> BvhMotion:
    """Parse a BVH file.

    ``drop_first_frame``: remove frame 0 from :attr:`BvhMotion.channels` and keep it as
    :attr:`BvhMotion.rest_channels` (right for the CMU clips, whose frame 0 is a T-pose).
    Raises :class:`BvhError` naming the file, line and field on malformed input.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        raise BvhError(f"{path}: BVH file not found") from None
    return parse_bvh(text, source=str(path), drop_first_frame=drop_first_frame)


def parse_bvh(text: str, *, source: str = "<string>", drop_first_frame: bool = True) -> BvhMotion:
    """Parse BVH text (see :func:`read_bvh`)."""
    toks = list(_tokens(text))
    pos = 0

    def fail(msg: str, at: int | None = None) -> BvhError:
        line = toks[min(at if at is not None else pos, len(toks) - 1)][0] if toks else 0
        return BvhError(f"{source}: line {line}: {msg}")

    def take(expected: str | None = None) -> str:
        nonlocal pos
        if pos >= len(toks):
            raise fail(f"unexpected end of file (expected {expected or 'more data'})")
        tok = toks[pos][1]
        if expected is not None and tok != expected:
            raise fail(f"expected '{expected}', found '{tok}'")
        pos += 1
        return tok

    def take_float(what: str) -> float:
        tok = take()
        try:
            return float(tok)
        except ValueError:
            raise fail(f"{what}: '{tok}' is not a number", pos - 1) from None

    names: list[str] = []
    parents: list[int] = []
    offsets: list[np.ndarray] = []
    channels: list[tuple[str, ...]] = []
    end_sites: dict[int, np.ndarray] = {}

    take("HIERARCHY")

    def parse_joint(parent: int) -> None:
        name = take()
        index = len(names)
        names.append(name)
        parents.append(parent)
        take("{")
        take("OFFSET")
        offsets.append(np.array([take_float(f"OFFSET of joint '{name}'") for _ in range(3)]))
        take("CHANNELS")
        count_tok = take()
        try:
            count = int(count_tok)
        except ValueError:
            raise fail(f"CHANNELS count of joint '{name}': '{count_tok}' is not an integer", pos - 1) from None
        chans = tuple(take() for _ in range(count))
        for ch in chans:
            if ch not in ROTATION_CHANNELS + POSITION_CHANNELS:
                raise fail(f"joint '{name}': unknown channel '{ch}'")
        channels.append(chans)
        while True:
            tok = take()
            if tok == "}":
                return
            if tok == "JOINT":
                parse_joint(index)
            elif tok == "End":
                take("Site")
                take("{")
                take("OFFSET")
                end_sites[index] = np.array([take_float(f"End Site OFFSET of joint '{name}'") for _ in range(3)])
                take("}")
            else:
                raise fail(f"joint '{name}': unexpected token '{tok}'", pos - 1)

    take("ROOT")
    parse_joint(-1)
    if pos < len(toks) and toks[pos][1] == "ROOT":
        raise fail("more than one ROOT is not supported")
    take("MOTION")
    take("Frames:")
    n_tok = take()
    try:
        n_frames = int(n_tok)
    except ValueError:
        raise fail(f"Frames: '{n_tok}' is not an integer", pos - 1) from None
    take("Frame")
    take("Time:")
    frame_time = take_float("Frame Time")
    if not frame_time > 0:
        raise fail(f"Frame Time must be > 0, got {frame_time}")
    n_chan = sum(len(c) for c in channels)
    rest = toks[pos:]
    if len(rest) != n_frames * n_chan:
        raise BvhError(f"{source}: MOTION holds {len(rest)} values, expected Frames ({n_frames}) x "
                       f"channels ({n_chan}) = {n_frames * n_chan}")
    try:
        values = np.array([float(t) for _, t in rest], dtype=float).reshape(n_frames, n_chan)
    except ValueError as exc:
        raise BvhError(f"{source}: MOTION contains a non-numeric value ({exc})") from None
    if not np.all(np.isfinite(values)):
        raise BvhError(f"{source}: MOTION contains non-finite values")

    skeleton = BvhSkeleton(tuple(names), tuple(parents), np.array(offsets, dtype=float),
                           tuple(channels), end_sites)
    rest_channels = None
    if drop_first_frame:
        if n_frames < 2:
            raise BvhError(f"{source}: drop_first_frame needs at least 2 frames, file has {n_frames}")
        rest_channels, values = values[0].copy(), values[1:]
    return BvhMotion(skeleton, float(frame_time), values, rest_channels, source)


def local_transforms(skeleton: BvhSkeleton, channels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint local rotation and root translation from channel values.

    ``channels`` (T, C) or (C,). Returns ``parent_R_joint`` (T, J, 3, 3) and ``root_position`` (T, 3)
    (root OFFSET plus its position channels; file units). Position channels on non-root joints are
    added to their OFFSET as well and returned in ``offsets`` by :func:`forward_kinematics`.
    """
    values = np.atleast_2d(np.asarray(channels, dtype=float))
    if values.shape[1] != skeleton.num_channels:
        raise ValueError(f"expected {skeleton.num_channels} channels per frame, got {values.shape[1]}")
    n = values.shape[0]
    rots = np.broadcast_to(np.eye(3), (n, skeleton.num_joints, 3, 3)).copy()
    for j, (chans, sl) in enumerate(zip(skeleton.channels, skeleton.channel_slices())):
        rot_idx = [i for i, c in enumerate(chans) if c in ROTATION_CHANNELS]
        if rot_idx:
            order = "".join(chans[i][0] for i in rot_idx)
            rots[:, j] = euler_to_matrix(values[:, sl][:, rot_idx], order)
    root_sl = skeleton.channel_slices()[0]
    root_pos = np.broadcast_to(skeleton.offsets[0], (n, 3)).copy()
    for i, c in enumerate(skeleton.channels[0]):
        if c in POSITION_CHANNELS:
            root_pos[:, POSITION_CHANNELS.index(c)] += values[:, root_sl][:, i]
    return rots, root_pos


def forward_kinematics(skeleton: BvhSkeleton, channels: np.ndarray, *,
                       with_end_sites: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """World rotations and positions of every joint.

    Returns ``world_R_joint`` (T, J, 3, 3) and ``world_p_joint`` (T, J, 3) in file units. With
    ``with_end_sites`` the positions array gets one extra row per End Site (in the order of
    ``sorted(skeleton.end_site_offsets)``), appended after the joints.
    """
    local_rot, root_pos = local_transforms(skeleton, channels)
    n, n_j = local_rot.shape[:2]
    world_rot = np.empty_like(local_rot)
    world_pos = np.empty((n, n_j, 3))
    slices = skeleton.channel_slices()
    values = np.atleast_2d(np.asarray(channels, dtype=float))
    for j, parent in enumerate(skeleton.parents):
        if parent < 0:
            world_rot[:, j] = local_rot[:, j]
            world_pos[:, j] = root_pos
            continue
        offset = np.broadcast_to(skeleton.offsets[j], (n, 3)).copy()
        for i, c in enumerate(skeleton.channels[j]):
            if c in POSITION_CHANNELS:
                offset[:, POSITION_CHANNELS.index(c)] += values[:, slices[j]][:, i]
        world_rot[:, j] = world_rot[:, parent] @ local_rot[:, j]
        world_pos[:, j] = world_pos[:, parent] + np.einsum("nab,nb->na", world_rot[:, parent], offset)
    if with_end_sites and skeleton.end_site_offsets:
        ends = [world_pos[:, j] + world_rot[:, j] @ skeleton.end_site_offsets[j]
                for j in sorted(skeleton.end_site_offsets)]
        world_pos = np.concatenate([world_pos, np.stack(ends, axis=1)], axis=1)
    return world_rot, world_pos
